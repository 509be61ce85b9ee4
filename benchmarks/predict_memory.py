"""Peak memory of ``predict`` over many small recording files (issue 38, item 15): bounded, whatever their number.

``tactile-zoo predict x_tacformer --pretrained ev_objects many/*.npy`` used about 8 MB per input file (2.5 GB for
300 files of 78 KB): every recording was read, then all were classified in batches of 256, whose activations
(X-Tacformer on 250 event frames: about 7 MB per recording) dominated. Predict now reads, classifies and answers the
files ``DEFAULT_BATCH`` (32) at a time and drops each batch before reading the next.

Each case runs in a fresh child process (1 thread, as the bench cells run) that writes nothing but its answers
(to ``/dev/null``) and reports its own peak resident set (``VmHWM``, as ``bench_wall`` reads it: the interpreter,
torch, the model and everything predict held). Cases:

- ``cli_<n>``: ``tactile-zoo predict`` (in-process ``main``) on ``n`` files;
- ``api_<n>``: ``tactile_zoo.predict(model, files)``, the list of answers kept (one small :class:`Prediction` each).

``n`` is 3000 and 30 (300 and 30 with ``--quick``); ``mb_per_file`` is the growth of the peak from 30 files to ``n``
per added file (about 0 when memory is bounded). The files are synthetic 0/1 events of Ev-Objects' shape
``(250, 78)`` float32 (78 KB each, 12.8 % density); the weights are the pack's
``plugins/tactile-zoo-weights/tactile_zoo_weights/x_tacformer.full_ev_objects.safetensors``, read through the
manifest beside them (no install needed). Target: the 3000-file peak under 1 GB.

Run it alone: ``python -m benchmarks.predict_memory [--quick]``; it writes ``results/predict_memory.csv``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .common import EV_EVENT_DENSITY, REPO, Context, write_csv

NAME = "predict_memory"
TITLE = "predict: peak RSS over 3000 small recording files (bounded batches)"
COLUMNS = ("interface", "files", "batch_size", "peak_rss_mb", "mb_per_file", "wall_s", "answered", "target")
WEIGHTS = REPO / "plugins" / "tactile-zoo-weights" / "tactile_zoo_weights" / "x_tacformer.full_ev_objects.safetensors"
TARGET_MB = 1024


def _write_files(folder: Path, count: int) -> list[Path]:
    rng = np.random.default_rng(0)
    files = []
    for i in range(count):
        files.append(folder / f"grasp{i:05d}.npy")
        np.save(files[-1], (rng.random((250, 78)) < EV_EVENT_DENSITY).astype(np.float32))
    return files


def _child(interface: str, listing: Path) -> dict[str, Any]:
    """Run one case in this (fresh) process; returns its row's measurements."""
    import contextlib
    import time

    import torch

    torch.set_num_threads(1)
    files = listing.read_text().split("\n")
    start = time.perf_counter()
    with open(os.devnull, "w") as sink, contextlib.redirect_stdout(sink):
        if interface == "cli":
            from tactile_zoo.cli import main

            code = main(["predict", "x_tacformer", "--weights", str(WEIGHTS), *files, "--top-k", "1"])
            answered = len(files) if code == 0 else -1
        else:
            import tactile_zoo as tz

            model = tz.create_model("x_tacformer", pretrained=WEIGHTS)
            answered = len(tz.predict(model, files, top_k=1))
    wall = time.perf_counter() - start
    return {"peak_rss_mb": _peak_kb() / 1024, "wall_s": wall, "answered": answered}


def _peak_kb() -> float:
    """This process's resident-set high-water mark in kB: ``VmHWM``, which belongs to this process's own memory map.
    Not ``ru_maxrss``, which Linux carries over ``exec`` from the process that spawned this one (the benchmark
    runner, torch loaded), as bench_wall explains."""
    import resource

    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1])
    except OSError:
        pass
    return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)  # kB on Linux; an upper bound


def _measure(interface: str, files: list[Path], folder: Path) -> dict[str, Any]:
    listing = folder / f"{interface}_{len(files)}.txt"
    listing.write_text("\n".join(map(str, files)))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(
        [str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.run([sys.executable, "-m", "benchmarks.predict_memory", "--child", interface, str(listing)],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(f"predict_memory child ({interface}, {len(files)} files) failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(ctx: Context, counts: tuple[int, ...] | None = None) -> Path:
    from tactile_zoo.weights import DEFAULT_BATCH

    counts = counts or ((30, 300) if ctx.quick else (30, 3000))
    rows = []
    with tempfile.TemporaryDirectory(prefix="tz-predict-memory-") as tmp:
        folder = Path(tmp)
        files = _write_files(folder, max(counts))
        for interface in ("cli", "api"):
            measured = {n: _measure(interface, files[:n], folder) for n in counts}
            small = min(counts)
            for n, m in measured.items():
                grown = (m["peak_rss_mb"] - measured[small]["peak_rss_mb"]) / (n - small) if n != small else None
                rows.append({"case": f"{interface}_{n}", "interface": interface, "files": n,
                             "batch_size": DEFAULT_BATCH, **m, "mb_per_file": grown,
                             "target": f"< {TARGET_MB} MB at 3000 files",
                             "note": "synthetic Ev-Objects-shaped events, 78 KB per file; 1 thread; fresh process"})
                ctx.log(f"  predict_memory {interface} {n} files: peak {m['peak_rss_mb']:.0f} MB, {m['wall_s']:.1f} s")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--quick", action="store_true", help="300 files instead of 3000: checks that it runs")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--child", nargs=2, metavar=("INTERFACE", "LISTING"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(_child(args.child[0], Path(args.child[1]))))
        return 0
    ctx = Context(threads=1, quick=args.quick, **({"out": args.out} if args.out else {}))
    print(run(ctx))
    return 0


if __name__ == "__main__":
    sys.exit(main())
