"""Training seconds per epoch and peak memory of every registered model on Ev-Objects at its registered recipe.

Each model is built with seed 0 and trained by the engine (``fit``, one epoch, no validation) on the 576 samples of
Ev-Objects' released train folder at its recipe's batch size, after one untimed warm-up batch. ``--quick`` times a
class-balanced subset of 64 samples and scales to 576 (the ``samples_timed`` column says which).

Peak memory: the process's resident-set high-water mark during the timed epochs (``VmHWM`` reset at the start
through ``/proc/self/clear_refs``, else ``ru_maxrss`` since the process started, an upper bound: ``rss_source``
says which). It includes the Python interpreter, torch and the loaded dataset (about 45 MB of Ev-Objects): what
a bench cell on Ev-Objects holds while it trains (the issue's target is under 3 GB). On CUDA the peak of allocated
GPU memory too.
"""

from __future__ import annotations

from pathlib import Path

import torch

from .common import EV_TRAIN_SAMPLES, Context, ev_objects, model_recipe, time_interleaved, write_csv

NAME = "epoch_all_models"
TITLE = "Training seconds per Ev-Objects epoch and peak RSS, every registered model at its recipe"
COLUMNS = ("model", "batch_size", "params", "data", "samples_timed", "epoch_median_s", "epoch_min_s", "epoch_cpu_s",
           "repeats", "peak_rss_mb", "rss_source", "gpu_peak_mb", "target")


def run(ctx: Context, models: list[str] | None = None, samples: int | None = None) -> Path:
    from tactile_zoo.engine import PeakMemory, count_parameters, fit, seed_everything, take
    from tactile_zoo.registry import create_model, list_models

    data = ev_objects(ctx)
    split = data.train
    n = min(len(split), samples or (64 if ctx.quick else len(split)))
    timed = take(split, n, seed=0) if n < len(split) else split
    scale = EV_TRAIN_SAMPLES / n
    rows = []
    for name in models or list_models():
        recipe = model_recipe(name)
        seed_everything(0)
        model = create_model(name, split.spec).to(ctx.device)
        fit(model, take(split, recipe.batch_size, seed=1), recipe=recipe, device=ctx.device, epochs=1)  # warm-up
        with PeakMemory(ctx.device) as peak:
            t = time_interleaved({name: lambda m=model, r=recipe: fit(m, timed, recipe=r, device=ctx.device,
                                                                       epochs=1)},
                                 ctx.reps(1, 1), ctx, warmup=0)[name]
        rows.append({"case": name, "model": name, "batch_size": recipe.batch_size, "params": count_parameters(model),
                     "data": data.source, "samples_timed": n, "epoch_median_s": t.median * scale,
                     "epoch_min_s": t.min * scale, "epoch_cpu_s": t.cpu_median * scale, "repeats": len(t),
                     "peak_rss_mb": peak.mb, "rss_source": peak.source, "gpu_peak_mb": peak.gpu_mb,
                     "target": "<= 60 s per epoch; peak < 3 GB",
                     "note": "one whole epoch" if n == EV_TRAIN_SAMPLES else
                             f"{n} samples timed, scaled to {EV_TRAIN_SAMPLES}"})
        ctx.log(f"  {name}: {rows[-1]['epoch_median_s']:.1f} s/epoch (batch {recipe.batch_size}, "
                f"{'whole epoch' if n == EV_TRAIN_SAMPLES else f'{n} samples scaled'}), peak RSS {peak.mb} MB")
        del model
        if ctx.device.type == "cuda":
            torch.cuda.empty_cache()
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE"]
