"""How training time per epoch grows with the sequence length T and the number of taxels N (SGnet, X-Tacformer).

Synthetic 0/1 events with Ev-Objects' density on Ev-Objects' sensor: T in (50, 125, 250, 500) at N = 39, and N in
(39, 78, 156) at T = 250 through ``Sensor.tiled(k)`` (k side-by-side NeuTouch copies, one graph). Each point trains
the model (seed 0, registered recipe, engine ``fit``) for one epoch over a few batches (``samples_timed``) after an
untimed warm-up batch; all points of a model are timed in interleaved rounds, and scaled to a 576-sample epoch.

``loglog_slope`` (one value per model and axis) is the least-squares slope of log time against log T (or N): 1 is
linear, 2 quadratic. ``relative`` is time / time at the smallest point, divided by value / smallest value: 1.0 means
exactly proportional (above 1 grows faster than linear; below 1 the fixed per-batch costs still dominate).
"""

from __future__ import annotations

from pathlib import Path

from .common import (
    EV_TRAIN_SAMPLES,
    Context,
    ev_spec,
    loglog_slope,
    model_recipe,
    synthetic_events,
    time_interleaved,
    write_csv,
)

NAME = "scaling"
TITLE = "Training time per epoch vs T (50-500) and N (39-156 taxels) for sgnet and x_tacformer"
COLUMNS = ("model", "axis", "T", "N", "batch_size", "samples_timed", "epoch_median_s", "epoch_min_s", "epoch_cpu_s",
           "repeats", "relative", "loglog_slope", "data")

STEPS = (50, 125, 250, 500)
COPIES = (1, 2, 4)


def run(ctx: Context, models: tuple[str, ...] = ("sgnet", "x_tacformer"), steps: tuple[int, ...] = STEPS,
        copies: tuple[int, ...] = COPIES, batches: int | None = None) -> Path:
    from tactile_zoo.engine import fit, seed_everything
    from tactile_zoo.registry import create_model

    nb = batches or (1 if ctx.quick else 4)
    base_t = 250 if 250 in steps else steps[len(steps) // 2]
    rows = []
    for name in models:
        recipe = model_recipe(name)
        n = recipe.batch_size * nb
        axes = {"T": [(t, 1) for t in steps], "N": [(base_t, c) for c in copies]}
        fns, nodes = {}, {}
        for t, c in dict.fromkeys(axes["T"] + axes["N"]):  # (T=250, N=39) serves both axes
            spec = ev_spec(t, c)
            seed_everything(0)
            model = create_model(name, spec).to(ctx.device)
            fit(model, synthetic_events(spec, recipe.batch_size, seed=1), recipe=recipe, device=ctx.device,
                epochs=1)  # warm-up
            split = synthetic_events(spec, n, seed=0)
            fns[(t, c)] = lambda m=model, s=split, r=recipe: fit(m, s, recipe=r, device=ctx.device, epochs=1)
            nodes[(t, c)] = spec.num_nodes
        timings = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
        scale = EV_TRAIN_SAMPLES / n
        for axis, keys in axes.items():
            values = [t if axis == "T" else nodes[(t, c)] for t, c in keys]
            secs = [timings[key].median * scale for key in keys]
            slope = loglog_slope(values, secs)
            for key, value, sec in zip(keys, values, secs):
                t = timings[key]
                rows.append({"case": f"{name}_{axis}{value}", "model": name, "axis": axis, "T": key[0],
                             "N": nodes[key], "batch_size": recipe.batch_size, "samples_timed": n,
                             "epoch_median_s": sec, "epoch_min_s": t.min * scale, "epoch_cpu_s": t.cpu_median * scale,
                             "repeats": len(t), "relative": (sec / secs[0]) / (value / values[0]),
                             "loglog_slope": slope, "data": "synthetic",
                             "note": f"{n} samples timed, scaled to {EV_TRAIN_SAMPLES}"})
            ctx.log(f"  {name} vs {axis}: " + ", ".join(f"{v}: {s:.1f} s" for v, s in zip(values, secs))
                    + f"; log-log slope {slope:.2f}")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE"]
