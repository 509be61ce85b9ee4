"""A GPU check ready to run: ``python -m benchmarks.gpu_check [--quick] [--timeout SECONDS] [--out DIR]``.

One command for a short session on a machine with a CUDA GPU (issue 18, section 4; issue 31). Run it from the
repository root of a checkout; it needs no network and installs nothing: torch (with CUDA), torch_geometric,
snntorch and pytest must already be importable there (a missing one is named on one line, exit status 2). It only
runs what the project already has, each step as a child process (the checkout on its ``PYTHONPATH``):

``parity``
    ``pytest tests/gpu/test_cuda_parity.py``: every registered model on every simulated dataset, CUDA against the
    CPU (forward, streaming, gradients; tolerances in ``tests/gpu/parity.py``). The JUnit XML, with each check's
    measurements as properties, goes to ``<out>/gpu_check_parity.xml``. Then ``tests/gpu/test_cuda_graph_training.py``:
    each model's training step replayed from CUDA graphs against its eager step (:mod:`tactile_zoo.engine.cuda_graph`).
``gpu_epoch``, ``inference``, ``epoch_all_models``, ``bench_wall``
    ``python -m benchmarks.run --device cuda --only NAME``: the performance suite's own benchmarks, writing
    ``<out>/NAME.csv``. ``bench_wall`` gets ``BENCH_WALL_EPOCHS=3`` (``--bench-epochs``) unless ``--quick``, which
    passes ``--quick`` to every benchmark.

``<out>`` is ``benchmarks/results/cuda/`` unless ``--out`` says otherwise; each step's output is kept in
``<out>/gpu_check_<step>.log`` and the verdict in ``<out>/gpu_check.json``. ``--timeout`` (default 270 s) bounds
the whole command: each step's child is stopped (its whole process group) at the step's share of it
(:data:`STEP_END`), and a step with no time left is not started. Stopped or skipped steps are reported, not failed.

Without CUDA the command prints one line saying so, writes nothing and exits 0 (it asks before importing more than
torch). ``--allow-cpu`` (internal, for the test suite) runs the same steps on the CPU (the parity tests CPU against
CPU), into a fresh temporary folder unless ``--out`` is given. Exit status: 0 when no step failed, 1 when one did,
2 for a missing package or a bad option.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
NAME = "gpu_check"
TITLE = "GPU check: the CUDA parity and graph tests, then gpu_epoch, inference, epoch_all_models and bench_wall on CUDA"
#: what must already be installed on the GPU machine (nothing is installed from the network)
REQUIRED = ("torch", "torch_geometric", "snntorch", "pytest")
PARITY_TESTS = "tests/gpu/test_cuda_parity.py"
#: training from CUDA graphs against eager training, every model (run in the parity step, after the parity tests)
GRAPH_TESTS = "tests/gpu/test_cuda_graph_training.py"
SUITE = ("gpu_epoch", "inference", "epoch_all_models", "bench_wall")
STEPS = ("parity", *SUITE)
#: the part of --timeout by which each step must end (a step that finishes early leaves its time to the next)
STEP_END = {"parity": 0.3, "gpu_epoch": 0.45, "inference": 0.55, "epoch_all_models": 0.75, "bench_wall": 1.0}
DEFAULT_TIMEOUT_S = 270.0
#: bench_wall's epochs unless --quick: the whole grid with full recipes does not fit the budget
BENCH_EPOCHS = 3

__all__ = ["main", "missing_package", "run_step", "parity_command", "parity_nodes", "parity_counts", "suite_command",
           "NAME", "TITLE", "STEPS"]


def missing_package(required: Sequence[str] = REQUIRED, checkout: bool = True) -> str | None:
    """The first package that cannot be imported (``required``, then with ``checkout`` ``tactile_zoo`` and what it
    imports), or ``None``. Puts the checkout on ``sys.path`` first when ``tactile_zoo`` is not installed."""
    if importlib.util.find_spec("tactile_zoo") is None and str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    for name in (*required, *(["tactile_zoo.registry"] if checkout else [])):
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            return exc.name or name
    return None


def run_step(command: list[str], log: Path, timeout: float, env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run ``command`` from the repository root in its own process group, its output into ``log``; stop the whole
    group (a benchmark's own children included) after ``timeout`` seconds. Status ``ok``, ``FAIL`` or ``timeout``."""
    start = time.perf_counter()
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as fh:
        proc = subprocess.Popen(command, cwd=REPO, stdout=fh, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
        try:
            code: int | None = proc.wait(timeout=max(1.0, timeout))
        except BaseException as exc:  # time is up, or interrupted: leave nothing running
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            if not isinstance(exc, subprocess.TimeoutExpired):
                raise
            code = None
    seconds = time.perf_counter() - start
    if code is None:
        status, note = "timeout", f"stopped after {timeout:.0f} s (time budget); see {log.name}"
    elif code:
        status, note = "FAIL", f"exit {code}: {log.read_text()[-600:].strip()}"
    else:
        status, note = "ok", ""
    return {"status": status, "exit_code": code, "seconds": round(seconds, 1), "note": note}


def parity_command(xml: Path, nodes: Sequence[str] = (PARITY_TESTS, GRAPH_TESTS)) -> list[str]:
    """pytest on the parity tests, measurements kept as JUnit properties (xunit1 is the family that holds them)."""
    return [sys.executable, "-m", "pytest", "-q", "-rfEs", "-p", "no:cacheprovider", "-o", "junit_family=xunit1",
            f"--junitxml={xml}", *nodes]


def parity_nodes(models: Sequence[str], datasets: Sequence[str]) -> list[str]:
    """The parity tests' ids of ``models`` x ``datasets``, in the test file's order (datasets outermost), then the
    CUDA-graph tests of ``models``."""
    return [*(f"{PARITY_TESTS}::test_cuda_matches_cpu[{m}-{d}]" for d in datasets for m in models),
            *(f"{GRAPH_TESTS}::test_a_graph_replay_matches_the_eager_step[{m}]" for m in models)]


def parity_counts(xml: Path) -> dict[str, Any]:
    """Tests, failed, skipped and the failed tests' names from pytest's JUnit XML (empty if it was not written)."""
    if not xml.exists():
        return {}
    cases = ET.parse(xml).getroot().iter("testcase")
    outcome = {c.get("name", "?"): next((e.tag for e in c if e.tag in ("failure", "error", "skipped")), "passed")
               for c in cases}
    failed = sorted(n for n, o in outcome.items() if o in ("failure", "error"))
    return {"tests": len(outcome), "failed": len(failed), "skipped": sum(o == "skipped" for o in outcome.values()),
            "failed_tests": failed}


def suite_command(name: str, device: str, out: Path, threads: int, quick: bool) -> list[str]:
    """``python -m benchmarks.run`` for benchmark ``name`` on ``device``, its CSV into ``out``."""
    return [sys.executable, "-m", "benchmarks.run", "--only", name, "--device", device, "--threads", str(threads),
            "--out", str(out), *(["--quick"] if quick else [])]


def _names(arg: str | None, known: list[str], what: str, parser: argparse.ArgumentParser) -> list[str] | None:
    if arg is None:
        return None
    names = [n.strip() for n in arg.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"unknown {what} {', '.join(unknown)}; choose from {', '.join(known)}")
    return names


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.gpu_check", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="steps: " + ", ".join(STEPS) + ". See benchmarks/README.md.")
    p.add_argument("--quick", action="store_true", help="the suite's --quick (few repeats, bench --quick)")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="SECONDS",
                   help=f"time budget of the whole command (default {DEFAULT_TIMEOUT_S:.0f}); what does not fit is "
                        "stopped or skipped with a note")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="results folder (default benchmarks/results/cuda/)")
    p.add_argument("--only", default=None, metavar="STEPS", help="comma list of steps to run (default all)")
    p.add_argument("--skip", default=None, metavar="STEPS", help="comma list of steps to leave out")
    p.add_argument("--models", default=None, metavar="NAMES", help="parity: comma list of models (default all)")
    p.add_argument("--datasets", default=None, metavar="NAMES",
                   help="parity: comma list of simulated datasets (default all)")
    p.add_argument("--device", default="cuda", help="the CUDA device (default cuda)")
    p.add_argument("--threads", type=int, default=None,
                   help="the suite's --threads: torch threads and bench_wall's workers (default min(4, cores))")
    p.add_argument("--bench-epochs", type=int, default=BENCH_EPOCHS,
                   help=f"bench_wall's --epochs without --quick (default {BENCH_EPOCHS})")
    p.add_argument("--allow-cpu", action="store_true",
                   help="internal (test suite): without CUDA, run every step on the CPU")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not args.device.startswith("cuda"):
        parser.error("--device must be a CUDA device (cuda, cuda:N); --allow-cpu runs on the CPU")
    if (args.threads is not None and args.threads < 1) or args.bench_epochs < 1:
        parser.error("--threads and --bench-epochs must be >= 1")
    # torch first, to ask for CUDA; the rest only where the check will run (so the skip stays quick)
    missing = missing_package(("torch",), checkout=False)
    if missing is None:
        import torch

        if not torch.cuda.is_available() and not args.allow_cpu:
            print("gpu_check: CUDA is not available here; skipped (nothing written)", flush=True)
            return 0
        missing = missing_package()
    if missing:
        print(f"gpu_check: missing package {missing!r}: torch (with CUDA), torch_geometric, snntorch and pytest must "
              f"already be installed on this machine (this command installs nothing)", file=sys.stderr, flush=True)
        return 2
    import torch

    from tactile_zoo.registry import get_dataset_entry, list_datasets, model_names

    sims = [d for d in list_datasets() if get_dataset_entry(d).meta.get("simulated")]
    models = _names(args.models, model_names(), "model", parser)
    datasets = _names(args.datasets, sims, "dataset", parser)
    # the whole test file unless a subset was asked for (by test id, so that "tacformer" does not pick x_tacformer)
    nodes = ([PARITY_TESTS, GRAPH_TESTS] if models is None and datasets is None
             else parity_nodes(models or model_names(), datasets or sims))
    steps = [s for s in _names(args.only, list(STEPS), "step", parser) or STEPS
             if s not in (_names(args.skip, list(STEPS), "step", parser) or [])]
    device = args.device if torch.cuda.is_available() else "cpu"
    # a self-test never writes into the committed results
    out = args.out or (REPO / "benchmarks" / "results" / "cuda" if device != "cpu" else
                       Path(tempfile.mkdtemp(prefix="tz-gpu-check-")))
    gpu = torch.cuda.get_device_name(device) if device != "cpu" else "no GPU: --allow-cpu, every step on the CPU"
    print(f"gpu_check on {device} ({gpu}){' (quick)' if args.quick else ''}: steps {', '.join(steps) or 'none'}, "
          f"budget {args.timeout:.0f} s, torch {torch.__version__}; results in {out}", flush=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]),
           "TACTILE_ZOO_PARITY_DEVICE": device}
    if not args.quick:
        env["BENCH_WALL_EPOCHS"] = str(args.bench_epochs)
    threads = args.threads or min(4, os.cpu_count() or 1)
    start = time.monotonic()
    rows: list[dict[str, Any]] = []
    xml = out / f"{NAME}_parity.xml"
    xml.unlink(missing_ok=True)  # a stopped or skipped parity step must not be judged by an older run's results
    for step in steps:
        command = (parity_command(xml, nodes) if step == "parity" else suite_command(step, device, out, threads,
                                                                                     args.quick))
        row: dict[str, Any] = {"step": step, "command": " ".join(["python", *command[1:]])}
        left = args.timeout * STEP_END[step] - (time.monotonic() - start)
        if left < 1:
            row.update(status="skipped", note="time budget spent")
        else:
            row.update(run_step(command, out / f"{NAME}_{step}.log", left, env))
            if step == "parity":
                row.update(parity_counts(xml))
        rows.append(row)
        counts = f", {row['tests']} tests, {row['failed']} failed, {row['skipped']} skipped" if "tests" in row else ""
        print(f"[{step}] {row['status']}{counts} ({row.get('seconds', 0):.0f} s) {row['note'][:300]}", flush=True)
    failed = [r["step"] for r in rows if r["status"] == "FAIL"]
    skipped = [r["step"] for r in rows if r["status"] in ("skipped", "timeout")]
    summary = {"passed": not failed, "failed": failed, "skipped": skipped, "elapsed_s": time.monotonic() - start,
               "budget_s": args.timeout, "device": device, "gpu": gpu, "torch": torch.__version__,
               "quick": args.quick, "argv": sys.argv[1:] if argv is None else list(argv), "steps": rows}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{NAME}.json").write_text(json.dumps(summary, indent=1) + "\n")
    verdict = f"FAILED: {', '.join(failed)}" if failed else "no step failed"
    note = f" ({', '.join(skipped)} stopped or skipped for the time budget)" if skipped else ""
    print(f"gpu_check: {verdict}{note}; {summary['elapsed_s']:.0f} s; {out / (NAME + '.json')}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
