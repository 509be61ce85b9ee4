"""Training seconds per epoch and peak memory of every registered model on Ev-Objects at its registered recipe.

Each model runs in a fresh child process (``python -m benchmarks.epoch_all_models``), as one bench cell would: it
loads Ev-Objects, builds the model with seed 0 and trains it by the engine (``fit``, one epoch, no validation) on the
576 samples of the released train folder at its recipe's batch size, after one untimed warm-up batch. ``--quick``
times a class-balanced subset of 64 samples and scales to 576 (``samples_timed`` says which).

Memory, from the child process alone (so earlier benchmarks' heaps do not count): ``peak_rss_mb`` is the resident-set
high-water mark during the timed epoch(s) (``VmHWM`` reset through ``/proc/self/clear_refs`` at their start, so it
includes what was resident then: Python, torch, the model and the loaded dataset; ``rss_source`` says ``ru_maxrss``
where that reset is impossible, an upper bound), ``process_peak_rss_mb`` the child's peak over its whole life, data
loading included. The issue's target for a bench cell on Ev-Objects is under 3 GB. On CUDA also ``gpu_peak_mb``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import torch

from .common import EV_TRAIN_SAMPLES, REPO, Context, data_root, ev_objects, model_recipe, time_interleaved, write_csv

NAME = "epoch_all_models"
TITLE = "Training seconds per Ev-Objects epoch and peak RSS, every registered model at its recipe"
COLUMNS = ("model", "batch_size", "params", "data", "samples_timed", "epoch_median_s", "epoch_min_s", "epoch_cpu_s",
           "repeats", "peak_rss_mb", "process_peak_rss_mb", "rss_source", "gpu_peak_mb", "target")


__all__ = ["run", "measure", "NAME", "TITLE"]


def measure(ctx: Context, name: str, samples: int | None = None) -> dict[str, Any]:
    """Time ``ctx.reps`` training epochs of model ``name`` in this process; one CSV row."""
    from tactile_zoo.engine import PeakMemory, count_parameters, fit, seed_everything, take
    from tactile_zoo.registry import instantiate_model

    data = ev_objects(ctx)
    split = data.train
    n = min(len(split), samples or (64 if ctx.quick else len(split)))
    timed = take(split, n, seed=0) if n < len(split) else split
    scale = EV_TRAIN_SAMPLES / n
    recipe = model_recipe(name)
    seed_everything(0)
    model = instantiate_model(name, split.spec).to(ctx.device)
    fit(model, take(split, recipe.batch_size, seed=1), recipe=recipe, device=ctx.device, epochs=1)  # warm-up
    with PeakMemory(ctx.device) as peak:
        t = time_interleaved({name: lambda: fit(model, timed, recipe=recipe, device=ctx.device, epochs=1)},
                             ctx.reps(1, 1), ctx, warmup=0)[name]
    return {"case": name, "model": name, "batch_size": recipe.batch_size, "params": count_parameters(model),
            "data": data.source, "samples_timed": n, "epoch_median_s": t.median * scale, "epoch_min_s": t.min * scale,
            "epoch_cpu_s": t.cpu_median * scale, "repeats": len(t), "peak_rss_mb": peak.mb,
            "process_peak_rss_mb": _process_peak_mb(), "rss_source": peak.source, "gpu_peak_mb": peak.gpu_mb,
            "target": "<= 60 s per epoch; peak < 3 GB",
            "note": "one whole epoch" if n == EV_TRAIN_SAMPLES else f"{n} samples timed, scaled to {EV_TRAIN_SAMPLES}"}


def _process_peak_mb() -> float | None:
    import resource

    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return round(kb / (1024 * 1024 if sys.platform == "darwin" else 1024), 1)


def run(ctx: Context, models: list[str] | None = None, samples: int | None = None) -> Path:
    from tactile_zoo.registry import model_names

    ev_objects(ctx)  # log the data source once, here
    root = data_root(ctx)
    rows = []
    for name in models or model_names():
        job = {"model": name, "samples": samples, "device": str(ctx.device), "threads": ctx.threads,
               "quick": ctx.quick, "repeats": ctx.repeats, "root": None if root is None else str(root)}
        proc = subprocess.run([sys.executable, "-m", "benchmarks.epoch_all_models", json.dumps(job)], cwd=REPO,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(
                                  [str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])},
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"measuring {name} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        rows.append(row)
        ctx.log(f"  {name}: {row['epoch_median_s']:.1f} s/epoch (batch {row['batch_size']}, {row['note']}), "
                f"peak RSS {row['peak_rss_mb']} MB (process {row['process_peak_rss_mb']} MB)")
    return write_csv(ctx, NAME, COLUMNS, rows)


def _child(job: dict[str, Any]) -> None:
    torch.set_num_threads(job["threads"])
    ctx = Context(device=torch.device(job["device"]), threads=job["threads"], quick=job["quick"],
                  repeats=job["repeats"], root=None if job["root"] is None else Path(job["root"]),
                  log=lambda msg: print(msg, file=sys.stderr))
    print(json.dumps(measure(ctx, job["model"], job["samples"])))


if __name__ == "__main__":  # one model in a fresh process: python -m benchmarks.epoch_all_models '<job json>'
    _child(json.loads(sys.argv[1]))

