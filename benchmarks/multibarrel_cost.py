"""The cost of an Ev-Objects ``zoo`` cell of the multi-barrel SNN, from measured epochs (issue 53).

A cell of the ``zoo`` recipe trains 200 epochs of one optimiser step each: the batch of 600 holds Ev-Objects' 468
training recordings whole, run as micro-batches of 120 (``micro_batch_size``), then scores the 108 validation
recordings. Every epoch does the same work, so a cell costs about ``max_epochs`` times one epoch; the first epoch
carries the allocator's warm-up, so the estimate takes the last measured epoch (``cpu_hours`` in the ``cell`` row),
and the CSV keeps every epoch.

One fresh child process on 1 torch thread, with the bench workers' malloc settings (as the bench cells run:
``tactile_zoo.engine.malloc.tune_malloc``; before 2026-12-07 20:55 UTC the child ran with glibc's defaults, which cost
this model about 1.4x in page faults) builds the model with seed 0 and runs
``tz.fit(..., recipe="zoo", epochs=N)`` on the real train and validation splits: ``cpu_s`` are the child's CPU
seconds between two epochs' ends (training and validation), ``wall_s`` the epoch's wall seconds as ``fit`` records
them, and ``peak_rss_mb`` the child's resident-set high-water mark over its life. Targets (issue 53): a cell at most
4 CPU-hours, a peak of at most 16 GB. CPU seconds are only a cost on quiet cores: the ``load`` column is the 1-minute
load average before and after the child ran.

Needs Ev-Objects (``--root``, or ``../shared/data``): the cost of the model's columns depends on the spikes, so
synthetic events would measure something else. Run it alone: ``python -m benchmarks.multibarrel_cost [--epochs N]``
(about 3 minutes of one core for 2 epochs, 11-12 GB); it writes ``results/multibarrel_cost.csv``.

``--revision N`` (repeatable) measures those revisions of the model side by side, one child each per round, in
alternating order over ``--rounds R`` rounds (ABBA...); each revision's ``cell`` row takes the median over the rounds
of their last epochs. The default is the registered revision, one round.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from .common import REPO, BenchmarkSkipped, Context, data_root, model_recipe, write_csv

NAME = "multibarrel_cost"
TITLE = "multi-barrel SNN: CPU seconds per `zoo` epoch on Ev-Objects and the cell's CPU-hours; peak RSS"
COLUMNS = ("revision", "round", "epoch", "wall_s", "cpu_s", "cpu_hours", "max_epochs", "batch_size",
           "micro_batch_size", "n_train", "n_val", "peak_rss_mb", "load", "target", "cpu_capability")
TARGET = "a cell <= 4 CPU-hours, peak <= 16 GB (issue 53)"


def _child(root: str, epochs: int, revision: int) -> dict[str, Any]:
    """Train ``epochs`` epochs of the ``zoo`` recipe at ``revision`` in this (fresh) process; per epoch its wall and
    CPU seconds."""
    import resource
    import time

    import torch

    torch.set_num_threads(1)
    import tactile_zoo as tz
    from tactile_zoo import registry
    from tactile_zoo.engine.malloc import tune_malloc
    from tactile_zoo.registry.lookup import load_dataset

    tune_malloc()  # as every bench worker starts (tactile_zoo.bench.worker): the cell's allocator, not glibc's defaults

    train = load_dataset("ev_objects", root=root, split="train")
    val = load_dataset("ev_objects", root=root, split="val")
    ends: list[tuple[int, float, float]] = []  # (epoch, fit's wall seconds, process CPU seconds at its end)
    start = time.process_time()
    path = registry.revision_keywords(registry.get_model_entry("multibarrel"), revision)  # the revision's compute path
    result = tz.fit("multibarrel", train, val_dataset=val, recipe="zoo", epochs=epochs, seed=0, device="cpu",
                    hparams=path, progress=False, callback=lambda row: ends.append((row["epoch"], row["seconds"],
                                                                      time.process_time())))
    cpu = [end - before for (_, _, end), before in zip(ends, [start, *(e for _, _, e in ends)])]
    return {"epochs": [{"epoch": epoch, "wall_s": wall, "cpu_s": c} for (epoch, wall, _), c in zip(ends, cpu)],
            "max_epochs": model_recipe("multibarrel").max_epochs,  # the registered cell's (fit's is ``epochs``)
            "batch_size": result.recipe.batch_size,
            "micro_batch_size": result.recipe.micro_batch_size, "n_train": result.n_train, "n_val": result.n_val,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "cpu_capability": torch.backends.cpu.get_cpu_capability()}  # ATen's SIMD level: epochs differ by it


def _load() -> str:
    return f"{os.getloadavg()[0]:.2f}" if hasattr(os, "getloadavg") else ""


def _registered_revision() -> int:
    from tactile_zoo import registry

    return registry.revision_of(registry.get_model_entry("multibarrel"))


def run(ctx: Context, epochs: int | None = None, revisions: list[int] | None = None, rounds: int = 1) -> Path:
    root = data_root(ctx)
    if root is None or not (root / "ev_objects" / "raw" / "Ev-Objects.zip").exists():
        raise BenchmarkSkipped("needs Ev-Objects (--root DATA holding ev_objects/raw/Ev-Objects.zip): the columns' "
                               "cost depends on the recordings' spikes")
    epochs = epochs if epochs is not None else (1 if ctx.quick else 2)
    revisions = revisions or [_registered_revision()]
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    rows: list[dict[str, Any]] = []
    last: dict[int, list[float]] = {r: [] for r in revisions}
    peak: dict[int, float] = {r: 0.0 for r in revisions}
    for round_ in range(rounds):
        for revision in (revisions if round_ % 2 == 0 else revisions[::-1]):  # ABBA: drift falls on both alike
            before = _load()
            job = {"root": str(root), "epochs": epochs, "revision": revision}
            proc = subprocess.run([sys.executable, "-m", "benchmarks.multibarrel_cost", "--child", json.dumps(job)],
                                  cwd=REPO, env=env, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                raise RuntimeError(f"the child failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
            out = json.loads(proc.stdout.strip().splitlines()[-1])
            load = f"{before} -> {_load()}"
            shared = {k: out[k] for k in ("max_epochs", "batch_size", "micro_batch_size", "n_train", "n_val")}
            isa = out["cpu_capability"]
            rows += [{"case": "epoch", "revision": revision, "round": round_, **e, **shared, "load": load,
                      "cpu_capability": isa}
                     for e in out["epochs"]]
            last[revision].append(out["epochs"][-1]["cpu_s"])
            peak[revision] = max(peak[revision], out["peak_rss_mb"])
            ctx.log(f"  revision {revision}, round {round_}: CPU s {[round(e['cpu_s'], 1) for e in out['epochs']]}; "
                    f"peak {out['peak_rss_mb']:.0f} MB; load {load}")
    for revision in revisions:
        cpu = statistics.median(last[revision])
        rows.append({"case": "cell", "revision": revision, "epoch": epochs, "cpu_s": cpu,
                     "cpu_hours": cpu * shared["max_epochs"] / 3600, **shared, "peak_rss_mb": peak[revision],
                     "target": TARGET, "cpu_capability": isa,
                     "note": f"max_epochs x the median over {rounds} round(s) of the last of {epochs} measured epochs"})
        ctx.log(f"  revision {revision}: a cell {rows[-1]['cpu_hours']:.2f} CPU-hours; peak {peak[revision]:.0f} MB")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--root", type=Path, default=None)
    parser.add_argument("--epochs", type=int, default=None, help="epochs to measure (default 2; --quick 1)")
    parser.add_argument("--quick", action="store_true", help="1 epoch")
    parser.add_argument("--revision", type=int, action="append", default=None,
                        help="a revision of the model to measure (repeatable; default the registered one)")
    parser.add_argument("--rounds", type=int, default=1, help="alternating rounds of every revision (default 1)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        job = json.loads(args.child)
        print(json.dumps(_child(job["root"], job["epochs"], job["revision"])))
        return
    ctx = Context(threads=1, quick=args.quick, root=args.root, **({"out": args.out} if args.out else {}))
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    print(run(ctx, epochs=args.epochs, revisions=args.revision, rounds=args.rounds).read_text())


if __name__ == "__main__":
    main()
