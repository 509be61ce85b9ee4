"""Overhead of progress reporting: a short cell with and without the per-epoch progress file.

The harness's workers write ``--out/progress/<cell id>.json`` after every epoch
(:class:`tactile_zoo.bench.progress.ProgressWriter`, passed to ``train_cell`` as its callback). Two measurements:

- ``cell``: one short cell (``dcnn`` on ``sim_biotac_slip``, ``--quick`` subset, 10 epochs: short epochs are where
  a per-epoch cost weighs most) trained by ``train_cell`` with the writer (``fast`` column) and without it
  (``naive``), interleaved; ``ratio`` = without / with (1.0: no overhead; the noise of a shared machine is a few
  percent either way), and ``overhead_ms_per_epoch`` = the difference of the medians per epoch.
- ``writer``: the writer's own cost per epoch, timed over 200 calls (what one epoch of any cell pays: a JSON dump
  of at most 32 epochs and an atomic replace, no fsync), in wall and in process CPU time (the wall time is mostly
  waiting for the file system's rename, which other processes' I/O slows down).

Run it alone with ``python -m benchmarks.progress_overhead [--quick]``; it writes ``results/progress_overhead.csv``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import torch

from .common import PAIR_COLUMNS, Context, pair_row, time_interleaved, write_csv

NAME = "progress_overhead"
TITLE = "Progress: a short cell with and without the per-epoch progress file"
COLUMNS = (*PAIR_COLUMNS, "model", "dataset", "epochs", "overhead_ms_per_epoch", "writer_us_per_epoch",
           "writer_cpu_us_per_epoch")
MODEL, DATASET, EPOCHS = "dcnn", "sim_biotac_slip", 10


def run(ctx: Context) -> Path:
    from tactile_zoo.bench.progress import ProgressWriter
    from tactile_zoo.engine.cell import train_cell
    from tactile_zoo.engine.config import QUICK_SUBSET, resolve_cell
    config = resolve_cell(MODEL, DATASET, epochs=EPOCHS, subset=QUICK_SUBSET)
    cell = {"cell_id": "bench", "model": MODEL, "dataset": DATASET, "fold": 0, "seed": 0}
    rows = []
    with tempfile.TemporaryDirectory(prefix="tz-progress-") as folder, ctx.threads_scope(1):
        def plain() -> None:
            train_cell(config, device=ctx.device, measure=False)

        def reporting() -> None:
            train_cell(config, device=ctx.device, measure=False, callback=ProgressWriter(folder, cell, EPOCHS))

        timings = time_interleaved({"plain": plain, "progress": reporting}, ctx.reps(9, 2), ctx)
        t_plain, t_progress = timings["plain"], timings["progress"]
        epochs_run = train_cell(config, device=ctx.device, measure=False).fit.epochs_run  # patience may stop early
        calls = 50 if ctx.quick else 200  # the recipes' longest epoch budgets; not --repeats
        writer = ProgressWriter(folder, cell, calls)
        row = {"epoch": 0, "val_accuracy": 0.5, "train_loss": 1.0, "seconds": 0.05}
        cpu, start = time.process_time(), time.perf_counter()
        for epoch in range(1, calls + 1):
            writer({**row, "epoch": epoch})
        per_call = (time.perf_counter() - start) / calls
        cpu_per_call = (time.process_time() - cpu) / calls
        note = "ratio = without / with: 1.0 = no overhead (a shared machine: a few percent of noise either way)"
        rows.append(pair_row("cell", "progress file per epoch", "no progress", t_progress, t_plain,
                             model=MODEL, dataset=DATASET, epochs=epochs_run,
                             overhead_ms_per_epoch=(t_progress.median - t_plain.median) / epochs_run * 1e3,
                             writer_us_per_epoch=per_call * 1e6, writer_cpu_us_per_epoch=cpu_per_call * 1e6,
                             note=note))
        rows.append({"case": "writer", "fast": "ProgressWriter call", "repeats": calls,
                     "overhead_ms_per_epoch": per_call * 1e3, "writer_us_per_epoch": per_call * 1e6,
                     "writer_cpu_us_per_epoch": cpu_per_call * 1e6,
                     "note": f"mean over {calls} calls (epochs)"})
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--quick", action="store_true", help="2 repeats: checks that it runs")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    ctx = Context(quick=args.quick, repeats=args.repeats, threads=1, **({"out": args.out} if args.out else {}))
    torch.set_num_threads(1)
    path = run(ctx)
    print(path.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
