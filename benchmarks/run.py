"""Run the performance suite: ``python -m benchmarks.run [--only NAMES] [--quick] [--device cpu|cuda] [--threads N]``.

Each benchmark writes ``<out>/<name>.csv`` (default ``benchmarks/results/``, ``benchmarks/results/cuda/`` with
``--device cuda``). ``--quick`` checks that everything runs with few repeats and subsets; its numbers are not for
reporting. See benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import traceback
from pathlib import Path

import torch

from tactile_zoo.engine.runtime import flush_denormals

from . import BENCHMARKS
from .common import RESULTS, BenchmarkSkipped, Context


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="benchmarks: " + ", ".join(BENCHMARKS))
    p.add_argument("--only", default=None, metavar="NAMES", help="comma list of benchmarks to run (default: all)")
    p.add_argument("--skip", default=None, metavar="NAMES", help="comma list of benchmarks to leave out")
    p.add_argument("--quick", action="store_true", help="few repeats and small subsets: checks that the suite runs")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=2,
                   help="torch threads for the training benchmarks (default 2; latency is measured at 1)")
    p.add_argument("--repeats", type=int, default=None, help="override every benchmark's repeat count")
    p.add_argument("--out", type=Path, default=None, help="folder of the CSVs (default benchmarks/results[/cuda])")
    p.add_argument("--root", type=Path, default=None,
                   help="data home with ev_objects/raw/Ev-Objects.zip (default $TACTILE_ZOO_DATA, else the "
                        "../shared/data beside the checkout, else ~/.cache/tactile_zoo/data; synthetic events of "
                        "the same shape when absent)")
    p.add_argument("--slow", action="store_true", help="also time the slow optional cases (LIF x[t] anti-pattern)")
    p.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    p.add_argument("--keep-denormals", action="store_true",
                   help="compute with subnormal floats (sets TACTILE_ZOO_KEEP_DENORMALS=1); by default the whole suite "
                        "runs with flush-to-zero, as tactile-zoo's training and inference do")
    return p


def _names(arg: str | None, parser: argparse.ArgumentParser) -> list[str]:
    if arg is None:
        return []
    names = [n.strip() for n in arg.split(",") if n.strip()]
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        parser.error(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)}")
    return names


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.list:
        for name, module in BENCHMARKS.items():
            print(f"{name:18s} {importlib.import_module(f'benchmarks.{module}').TITLE}")
        return 0
    only, skip = _names(args.only, parser), _names(args.skip, parser)
    selected = [n for n in (only or list(BENCHMARKS)) if n not in skip]
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: CUDA is not available here")
    if args.threads < 1:
        parser.error("--threads must be >= 1")
    out = args.out or (RESULTS / "cuda" if device.type == "cuda" else RESULTS)
    before = os.environ.get("TACTILE_ZOO_KEEP_DENORMALS")
    if args.keep_denormals:
        os.environ["TACTILE_ZOO_KEEP_DENORMALS"] = "1"  # read by every flush_denormals block, and by child processes
    try:
        # flush-to-zero for the whole run, fast and naive paths alike, and on before torch starts its thread pool
        with flush_denormals() as flushing:
            torch.set_num_threads(args.threads)
            ctx = Context(device=device, threads=args.threads, quick=args.quick, repeats=args.repeats, out=out,
                          root=args.root, slow=args.slow, flush_denormals=flushing)
            return _run_all(ctx, selected, args.threads)
    finally:
        if args.keep_denormals:
            if before is None:
                os.environ.pop("TACTILE_ZOO_KEEP_DENORMALS", None)
            else:
                os.environ["TACTILE_ZOO_KEEP_DENORMALS"] = before


def _run_all(ctx: Context, selected: list[str], threads: int) -> int:
    print(f"tactile-zoo benchmarks on {ctx.device} with {threads} thread(s){' (quick)' if ctx.quick else ''}, "
          f"flush-to-zero {'on' if ctx.flush_denormals else 'off'}: "
          f"{ctx.env['cpu_model']}, {ctx.env['cpu_cores']} cores, torch {ctx.env['torch']}, commit "
          f"{ctx.env['git_commit'] or '?'}", flush=True)
    failed = []
    for name in selected:
        module = importlib.import_module(f"benchmarks.{BENCHMARKS[name]}")
        print(f"[{name}] {module.TITLE}", flush=True)
        start = time.perf_counter()
        try:
            path = module.run(ctx)
        except BenchmarkSkipped as exc:  # needs something this machine lacks: said, not a failure
            print(f"[{name}] skipped: {exc}", flush=True)
            continue
        except Exception:  # noqa: BLE001 - one broken benchmark must not hide the others' results
            traceback.print_exc()
            failed.append(name)
            continue
        finally:
            torch.set_num_threads(threads)
        print(f"[{name}] wrote {path} ({time.perf_counter() - start:.0f} s)", flush=True)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
