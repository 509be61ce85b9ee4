"""Where a training step's time goes, per model: the top operators of an Ev-Objects step by self CPU time, with shapes.

``python -m benchmarks.run --only profile_models`` (or ``python -m benchmarks.profile_models [--models ...]``).
Each model trains through the engine's ``fit`` on ``--batches`` batches (default 2) of Ev-Objects at its recipe's
batch size under ``torch.profiler``, after one untimed warm-up batch; the CSV lists, per model, the ``TOP``
operators by self CPU time grouped by input shapes, each with its share of the profiled total. Shares survive a
loaded machine far better than absolute times, and they are what says what bounds a model (issue 30, item 5).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import torch

from .common import Context, ev_objects, model_recipe, write_csv

NAME = "profile_models"
TITLE = "Top operators of an Ev-Objects training step by self CPU time, with shapes, per model"
MODELS = ("convlstm", "dcnn", "sgnet", "tacformer", "x_tacformer", "cnn_lstm")
TOP = 12
COLUMNS = ("model", "batch_size", "batches", "rank", "op", "input_shapes", "calls", "self_cpu_ms", "share",
           "total_cpu_ms")

__all__ = ["run", "profile_model", "NAME", "TITLE"]


def profile_model(ctx: Context, name: str, batches: int = 2, top: int = TOP) -> list[dict[str, Any]]:
    """The ``top`` operators of ``batches`` training batches of model ``name``, as CSV rows."""
    from torch.profiler import ProfilerActivity, profile

    from tactile_zoo.engine import fit, seed_everything, take
    from tactile_zoo.registry import instantiate_model

    data = ev_objects(ctx)
    recipe = model_recipe(name)
    bs = recipe.batch_size
    seed_everything(0)
    model = instantiate_model(name, data.train.spec).to(ctx.device)
    fit(model, take(data.train, bs, seed=1), recipe=recipe, device=ctx.device, epochs=1)  # warm-up
    timed = take(data.train, bs * batches, seed=0)
    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        fit(model, timed, recipe=recipe, device=ctx.device, epochs=1)
    events = [e for e in prof.key_averages(group_by_input_shape=True) if e.self_cpu_time_total > 0]
    total = sum(e.self_cpu_time_total for e in events)  # microseconds
    events.sort(key=lambda e: e.self_cpu_time_total, reverse=True)
    return [{"case": f"{name}#{rank}", "model": name, "batch_size": bs, "batches": batches, "rank": rank,
             "op": e.key, "input_shapes": str(e.input_shapes), "calls": e.count,
             "self_cpu_ms": e.self_cpu_time_total / 1e3, "share": e.self_cpu_time_total / total,
             "total_cpu_ms": total / 1e3}
            for rank, e in enumerate(events[:top], start=1)]


def run(ctx: Context, models: tuple[str, ...] = MODELS, batches: int | None = None) -> Path:
    rows = []
    for name in models:
        got = profile_model(ctx, name, batches or ctx.reps(2, 1))
        rows.extend(got)
        lead = got[0]
        ctx.log(f"  {name}: top op {lead['op']} {lead['input_shapes'][:80]} {lead['share']:.0%} of "
                f"{lead['total_cpu_ms']:.0f} ms")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.profile_models", description=TITLE)
    p.add_argument("--models", default=",".join(MODELS), help="comma list of models")
    p.add_argument("--batches", type=int, default=2, help="training batches profiled per model (default 2)")
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    p.add_argument("--root", type=Path, default=None, help="data home with ev_objects/raw/Ev-Objects.zip")
    p.add_argument("--out", type=Path, default=None, help="folder of the CSV (default benchmarks/results/)")
    args = p.parse_args(argv)
    from tactile_zoo.engine.runtime import flush_denormals

    torch.set_num_threads(args.threads)
    with flush_denormals() as flushing:
        ctx = Context(threads=args.threads, root=args.root, flush_denormals=flushing,
                      **({"out": args.out} if args.out else {}))
        print(f"wrote {run(ctx, tuple(m for m in args.models.split(',') if m), args.batches)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
