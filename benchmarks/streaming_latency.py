"""Per-step streaming latency at batch 1 on 1 thread: ``step()`` vs re-running ``forward`` on the prefix.

For every registered model with ``streaming=True`` metadata: one Ev-Objects test sample is fed frame by frame through
``init_state(1)`` / ``step(x_t, g_t, state)`` in eval mode under ``torch.inference_mode``, every step timed (all T
steps, ``repeats`` passes). The naive way to get running scores from a model without a streaming API is to call
``forward`` on the prefix ``x[:, :t+1]`` at every step ``t``: its cost grows with ``t``, so it is timed at evenly
spaced prefix lengths and averaged, which estimates its mean cost per step over the whole sequence
(``naive_median_s`` is that mean; ``prefix_full_ms`` the cost at the last step). ``ratio`` = that mean over the
median step.

A 20 ms sensor frame must be processed well under 20 ms; the goal is under 1 ms per step. ``max_abs_diff`` checks
that the streamed scores equal ``forward`` on the prefix at the timed prefix lengths.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from .common import PAIR_COLUMNS, Context, Timing, ev_objects, pair_row, write_csv

NAME = "streaming_latency"
TITLE = "Streaming: per-step latency of step() at batch 1 on 1 thread vs forward on the prefix"
COLUMNS = (*PAIR_COLUMNS, "model", "data", "steps", "step_p99_ms", "step_max_ms", "prefix_full_ms", "max_abs_diff",
           "target")


def _stream(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, ctx: Context, keep: set[int]
            ) -> tuple[list[float], list[float], dict[int, torch.Tensor]]:
    """Step through ``x (1, T, N, C)``: wall and CPU seconds of every step, and the scores after the steps in
    ``keep``."""
    state = model.init_state(1)
    wall, cpu, kept = [], [], {}
    for t, x_t in enumerate(x.unbind(1)):  # (1, N, C)
        g_t = None if g is None else g[:, t]
        ctx.sync()
        c0, w0 = time.process_time(), time.perf_counter()
        scores, state = model.step(x_t, g_t, state)
        ctx.sync()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
        if t in keep:
            kept[t] = scores.clone()
    return wall, cpu, kept


def run(ctx: Context, models: list[str] | None = None, prefixes: int | None = None, steps: int | None = None
        ) -> Path:
    from tactile_zoo.engine import seed_everything
    from tactile_zoo.registry import get_model_entry, instantiate_model, model_names

    data = ev_objects(ctx)
    test = data.test
    x = test.x[:1].to(ctx.device)  # (1, T, N, C)
    if steps is not None:
        x = x[:, :steps]
    g = test.g[:1, :x.shape[1]].to(ctx.device) if test.g.shape[-1] > 0 else None
    total = x.shape[1]
    k = prefixes or (5 if ctx.quick else 25)
    lengths = sorted({max(1, round(total * (i + 1) / k)) for i in range(k)})  # evenly spaced prefix lengths
    names = [n for n in (models or model_names()) if get_model_entry(n).meta.get("streaming")]
    rows = []
    with ctx.threads_scope(1), torch.inference_mode():
        for name in names:
            seed_everything(0)
            model = instantiate_model(name, test.spec).to(ctx.device).eval()
            _stream(model, x[:, :min(total, 10)], g, ctx, set())  # warm-up
            stream = Timing([], [])
            naive = Timing([], [])
            full = []
            diff = 0.0
            for _ in range(ctx.reps(3, 1)):
                wall, cpu, kept = _stream(model, x, g, ctx, {n - 1 for n in lengths})
                stream.times += wall
                stream.cpu += cpu
                pw, pc = [], []
                for n in lengths:  # the naive way at evenly spaced steps
                    gp = None if g is None else g[:, :n]
                    ctx.sync()
                    c0, w0 = time.process_time(), time.perf_counter()
                    scores = model(x[:, :n], gp)
                    ctx.sync()
                    pw.append(time.perf_counter() - w0)
                    pc.append(time.process_time() - c0)
                    diff = max(diff, float((scores - kept[n - 1]).abs().max()))
                naive.times.append(sum(pw) / len(pw))
                naive.cpu.append(sum(pc) / len(pc))
                full.append(pw[-1])
            ordered = sorted(stream.times)
            p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
            rows.append(pair_row(name, "step() (streaming state)", f"forward on the prefix, mean over {len(lengths)} "
                                 f"prefix lengths", stream, naive, model=name, data=data.source, steps=total,
                                 step_p99_ms=p99 * 1e3, step_max_ms=ordered[-1] * 1e3,
                                 prefix_full_ms=sorted(full)[len(full) // 2] * 1e3, max_abs_diff=diff, threads=1,
                                 target="well under 20 ms per step; goal < 1 ms",
                                 note="fast_*_s: median over all steps of all passes; naive_*_s: mean per step"))
            rows[-1]["repeats"] = len(naive)
            ctx.log(f"  {name}: step {stream.median * 1e3:.2f} ms (p99 {p99 * 1e3:.2f}), prefix forward "
                    f"{naive.median * 1e3:.1f} ms mean -> {rows[-1]['ratio']:.0f}x (max diff {diff:.2g})")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE"]
