"""Inference latency per sample at batch 1 on 1 thread, and throughput at batch 64, for every registered model.

The robot's use: classify a grasp as it ends. Each model (seed 0, eval mode, ``torch.inference_mode``) scores
Ev-Objects test samples (T=250, 39 taxels, 2 channels): one at a time on 1 thread, each call timed on its own
(``latency`` rows: ms per sample), then 64 at a time on ``--threads`` threads (``throughput`` rows: samples per
second). Untrained weights: the work per sample does not depend on them.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from .common import Context, Timing, ev_objects, time_interleaved, write_csv

NAME = "inference"
TITLE = "Inference latency at batch 1 on 1 thread and throughput at batch 64, every registered model"
COLUMNS = ("model", "data", "batch", "calls", "median_ms_per_call", "min_ms_per_call", "p90_ms_per_call",
           "ms_per_sample", "samples_per_s", "target")


def _latency(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, samples: int, ctx: Context) -> Timing:
    """One call per sample at batch 1, each timed (two untimed warm-up calls first)."""
    times = []
    for i in range(-2, samples):
        j = max(i, 0) % x.shape[0]
        xb, gb = x[j:j + 1], None if g is None else g[j:j + 1]
        ctx.sync()
        start = time.perf_counter()
        model(xb, gb)
        ctx.sync()
        if i >= 0:
            times.append(time.perf_counter() - start)
    return Timing(times)


def run(ctx: Context, models: list[str] | None = None, samples: int | None = None, batch: int = 64) -> Path:
    from tactile_zoo.engine import seed_everything
    from tactile_zoo.registry import instantiate_model, model_names

    data = ev_objects(ctx)
    test = data.test
    x = test.x.to(ctx.device)
    g = test.g.to(ctx.device) if test.g.shape[-1] > 0 else None
    n = samples or (5 if ctx.quick else 30)
    xb = x[:batch] if x.shape[0] >= batch else x[torch.arange(batch) % x.shape[0]]  # (batch, T, N, C)
    gb = None if g is None else (g[:batch] if g.shape[0] >= batch else g[torch.arange(batch) % g.shape[0]])
    rows = []
    for name in models or model_names():
        seed_everything(0)
        model = instantiate_model(name, test.spec).to(ctx.device).eval()
        with torch.inference_mode():
            with ctx.threads_scope(1):
                lat = _latency(model, x, g, n, ctx)
            thr = time_interleaved({"b": lambda m=model: m(xb, gb)}, ctx.reps(5, 2), ctx, warmup=1)["b"]
        p90 = sorted(lat.times)[min(len(lat.times) - 1, int(0.9 * len(lat.times)))]
        rows.append({"case": "latency", "model": name, "data": data.source, "batch": 1, "calls": len(lat),
                     "median_ms_per_call": lat.median * 1e3, "min_ms_per_call": lat.min * 1e3,
                     "p90_ms_per_call": p90 * 1e3, "ms_per_sample": lat.median * 1e3,
                     "samples_per_s": 1.0 / lat.median, "threads": 1, "target": "<= 25 ms per sample"})
        rows.append({"case": "throughput", "model": name, "data": data.source, "batch": batch, "calls": len(thr),
                     "median_ms_per_call": thr.median * 1e3, "min_ms_per_call": thr.min * 1e3,
                     "p90_ms_per_call": "", "ms_per_sample": thr.median * 1e3 / batch,
                     "samples_per_s": batch / thr.median, "threads": ctx.threads, "target": ""})
        ctx.log(f"  {name}: {lat.median * 1e3:.1f} ms/sample at batch 1 (1 thread); "
                f"{batch / thr.median:.0f} samples/s at batch {batch} ({ctx.threads} threads)")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE"]
