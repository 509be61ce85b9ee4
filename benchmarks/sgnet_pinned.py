"""SGnet's Ev-Objects training epoch, this checkout against a pinned copy of the code (before issue 30), alternating.

``python -m benchmarks.sgnet_pinned --pinned /path/to/pinned-checkout [--threads 2] [--rounds 3]``

Each round runs one child process per side (``PYTHONPATH=<checkout>``, the sides in rotating order), and each child:
loads Ev-Objects' 576 training samples (synthetic events of the same shape without the zip, as the suite does),
builds ``sgnet`` from seed 0, trains one batch of a copy untimed (warm-up: the LIF kernel's cache load, oneDNN's
first calls), then times one ``fit`` epoch with the registered recipe under flush-to-zero. The child reports its
wall and CPU seconds and a SHA-256 of the trained weights: equal hashes mean both sides computed the same epoch bit
for bit (the compiled LIF kernel claims exactly that). Writes ``benchmarks/results/sgnet_pinned.csv`` (``--out``)
with the medians, their ratio and ``os.getloadavg()`` at the start and end.

Not part of ``python -m benchmarks.run`` (it needs the pinned checkout); a pinned copy is made with, e.g.,
``git worktree add /tmp/pinned <start commit>``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from .common import PAIR_COLUMNS, REPO, RESULTS, Context, Timing, pair_row, write_csv

NAME = "sgnet_pinned"
COLUMNS = (*PAIR_COLUMNS, "data", "pinned", "same_weights_after_epoch", "load_avg", "target")

#: What each child runs (only APIs both sides have); argv: threads, result file.
CHILD = r"""
import copy, hashlib, json, sys, time
import torch
threads, out = int(sys.argv[1]), sys.argv[2]
torch.set_num_threads(threads)
from benchmarks.common import Context, ev_objects, model_recipe
from tactile_zoo.engine import fit, take
from tactile_zoo.engine.runtime import flush_denormals
from tactile_zoo.registry import instantiate_model
with flush_denormals():
    data = ev_objects(Context(threads=threads, log=lambda _m: None))
    recipe = model_recipe("sgnet")
    torch.manual_seed(0)
    model = instantiate_model("sgnet", data.train.spec)
    fit(copy.deepcopy(model), take(data.train, recipe.batch_size, seed=1), recipe=recipe, device="cpu", epochs=1)
    cpu, start = time.process_time(), time.perf_counter()
    fit(model, data.train, recipe=recipe, device="cpu", epochs=1)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
digest = hashlib.sha256()
for value in model.state_dict().values():
    digest.update(value.detach().contiguous().numpy().tobytes())
json.dump({"wall": wall, "cpu": cpu, "weights": digest.hexdigest(), "data": data.source}, open(out, "w"))
"""


def _data_env(pinned: Path) -> dict[str, str]:
    """Both children read the same Ev-Objects: the shared data home beside either checkout (a worktree of this one
    may have none beside it), unless the environment names one."""
    if os.environ.get("TACTILE_ZOO_DATA") or os.environ.get("TACTILE_ZOO_SHARED_DATA"):
        return {}
    for root in (REPO, pinned):
        shared = root.parent / "shared" / "data"
        if (shared / "ev_objects" / "raw" / "Ev-Objects.zip").exists():
            return {"TACTILE_ZOO_SHARED_DATA": str(shared)}
    return {}


def _child(root: Path, threads: int, out: Path, data_env: dict[str, str]) -> dict:
    env = {**os.environ, **data_env, "PYTHONPATH": str(root), "OMP_NUM_THREADS": str(threads)}
    subprocess.run([sys.executable, "-c", CHILD, str(threads), str(out)], env=env, cwd=root, check=True)
    return json.loads(out.read_text())


def _load() -> str:
    return "/".join(f"{v:.2f}" for v in os.getloadavg())


def run(pinned: Path, threads: int = 2, rounds: int = 3, out: Path = RESULTS,
        log: Callable[[str], None] = print) -> Path:
    sides = {"after": REPO, "before": pinned}
    times = {name: Timing([], []) for name in sides}
    weights: dict[str, set[str]] = {name: set() for name in sides}
    sources = set()
    load_start = _load()
    tmp, data_env = out / f".{NAME}.json", _data_env(pinned)
    out.mkdir(parents=True, exist_ok=True)
    for r in range(rounds):
        order = list(sides) if r % 2 == 0 else list(sides)[::-1]
        for name in order:
            res = _child(sides[name], threads, tmp, data_env)
            times[name].times.append(res["wall"])
            times[name].cpu.append(res["cpu"])
            weights[name].add(res["weights"])
            sources.add(res["data"])
            log(f"  round {r + 1} {name}: {res['wall']:.2f} s (cpu {res['cpu']:.2f} s; load {_load()})")
    tmp.unlink(missing_ok=True)
    same = len(weights["after"] | weights["before"]) == 1
    load = f"{load_start} -> {_load()}"
    row = pair_row("epoch", "sgnet epoch, this checkout (compiled LIF kernel)", f"sgnet epoch, pinned code ({pinned})",
                   times["after"], times["before"], data="/".join(sorted(sources)), pinned=str(pinned),
                   same_weights_after_epoch=same, load_avg=load, target=">= 2x faster than the pinned code (issue 30)",
                   note=f"{rounds} rounds, one child process per side per round, order alternating; seconds of one "
                        f"fit epoch of 576 samples after a one-batch warm-up")
    log(f"  after {times['after'].median:.2f} s, before {times['before'].median:.2f} s -> {row['ratio']:.2f}x; "
        f"same trained weights: {same}; load {load}")
    ctx = Context(threads=threads, out=out, log=log)
    return write_csv(ctx, NAME, COLUMNS, [row])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.sgnet_pinned", description=__doc__.split("\n\n")[0])
    p.add_argument("--pinned", type=Path, required=True, help="checkout of the code before issue 30")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    print(f"wrote {run(args.pinned.resolve(), args.threads, args.rounds, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
