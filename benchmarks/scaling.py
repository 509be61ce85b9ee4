"""How training time per epoch grows with the sequence length T, the number of taxels N and the batch size, and where
X-Tacformer's attention over taxels overtakes the rest of its epoch.

Synthetic 0/1 events with Ev-Objects' density on Ev-Objects' sensor, three parts (each can run alone: ``parts``):

* ``TN`` (axes ``T`` and ``N``, sgnet and x_tacformer): T in (50, 125, 250, 500) at N = 39, and N in (39, 78, 156)
  at T = 250 through ``Sensor.tiled(k)`` (k side-by-side NeuTouch copies, one graph). Each point trains the model
  (seed 0, registered recipe, engine ``fit``) for one epoch over a few batches (``samples_timed``) after an untimed
  warm-up batch; all points of a model are timed in interleaved rounds, and scaled to a 576-sample epoch.
  ``loglog_slope`` (one value per model and axis) is the least-squares slope of log time against log T (or N): 1 is
  linear, 2 quadratic. ``relative`` is time / time at the smallest point, divided by value / smallest value: 1.0
  means exactly proportional (above 1 grows faster than linear; below 1 the fixed per-batch costs still dominate).
* ``batch`` (axis ``batch``; sgnet, x_tacformer, tacformer, cnn_lstm): the Ev-Objects-shaped epoch (T = 250, N = 39)
  at batch sizes 1, 2, 4, 8, 16, 32, 64 (and the recipe's own), all sizes of a model in interleaved rounds, each over
  ``max(batch, batch_samples)`` samples, scaled to 576. ``per_sample_s`` is the training time per sample and
  ``ratio_to_recipe`` its ratio to the time per sample at the recipe's batch size (below 1: cheaper per sample).
  Another batch size is another training recipe (other steps, other noise, other results), so this is a cost
  curve, not a recommendation. At batch 1 the engine puts the lone last sample into the previous batch, so an epoch
  of n samples takes n - 1 steps there.
* ``breakdown`` (axis ``breakdown``, x_tacformer): at N in (39, 78, 156, 312) (624 too with ``--slow``), T = 250 and
  the recipe's batch 16, one training batch (``fit``, part ``total``) is timed side by side with, separately, the
  forward + backward of the self-attention over taxel tokens at that batch's shapes (part ``attention``:
  ``scaled_dot_product_attention`` on ``(T' * B, heads, N, d_k)`` for each block: the scores, softmax and weighted
  sum, the only work quadratic in N) and of the model's two graph convolutions (part ``graph_conv``, informational:
  the dense backend multiplies by ``N x N`` hop matrices, so it too is quadratic in N, with a small coefficient).
  ``rest`` = total - attention, round by round (graph_conv included). ``share`` is a part's fraction of the total.
  Fits over N: attention ``a N^2 + a0`` and rest ``b N + b0`` (least squares on relative residuals; ``fit_coef`` is
  a or b, ``fit_const`` a0 or b0, ``fit_power`` 2 or 1), and ``crossover_N``, the N where the two fits are equal;
  ``crossover_N_loglog`` is the same from power laws ``c N^p`` through the two largest N (the growth measured at
  the top of the range; ``loglog_slope`` is the slope over all N). ``profiled_share`` (attention rows) cross-checks
  the isolated timing inside the training step: the share of ``scaled_dot_product_attention`` (forward and
  backward) in the op time of one batch under ``torch.profiler``.

Running only some parts (``python -m benchmarks.scaling --parts batch,breakdown``) keeps the committed rows of the
others verbatim, environment columns included, so every row still says when and where it was measured.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from .common import (
    EV_TRAIN_SAMPLES,
    Context,
    Timing,
    ev_spec,
    loglog_slope,
    model_recipe,
    synthetic_events,
    time_interleaved,
    write_csv,
)

NAME = "scaling"
TITLE = ("Training time per epoch vs T (50-500), N (39-156 taxels) and batch size (1-64); X-Tacformer's attention "
         "vs the rest over N (39-312)")
COLUMNS = ("model", "axis", "part", "T", "N", "batch_size", "samples_timed", "epoch_median_s", "epoch_min_s",
           "epoch_cpu_s", "repeats", "relative", "loglog_slope", "per_sample_s", "ratio_to_recipe", "share",
           "fit_coef", "fit_const", "fit_power", "crossover_N", "crossover_N_loglog", "profiled_share", "basis",
           "data")

STEPS = (50, 125, 250, 500)
COPIES = (1, 2, 4)
BATCH_SIZES = (1, 2, 4, 8, 16, 32, 64)
BATCH_MODELS = ("sgnet", "x_tacformer", "tacformer", "cnn_lstm")
#: samples timed per batch-size point (at least one whole batch, so batch 32 and 64 time 32 and 64)
BATCH_SAMPLES = 16
BREAKDOWN_COPIES = (1, 2, 4, 8)  # N = 39, 78, 156, 312; 16 (N = 624) is added with --slow
PARTS = ("TN", "batch", "breakdown")
#: the part that measures each axis (for keeping the rows of parts that did not run)
AXIS_PART = {"T": "TN", "N": "TN", "batch": "batch", "breakdown": "breakdown"}


def run(ctx: Context, models: tuple[str, ...] = ("sgnet", "x_tacformer"), steps: tuple[int, ...] = STEPS,
        copies: tuple[int, ...] = COPIES, batches: int | None = None, *, parts: Sequence[str] = PARTS,
        batch_models: tuple[str, ...] = BATCH_MODELS, batch_sizes: tuple[int, ...] = BATCH_SIZES,
        batch_samples: int | None = None, breakdown_copies: tuple[int, ...] | None = None, num_steps: int = 250,
        basis: str = "wall") -> Path:
    """Measure ``parts`` (of :data:`PARTS`) and write ``scaling.csv``; the committed rows of the other parts stay.

    ``num_steps`` is the T of the batch and breakdown parts (250, Ev-Objects'; smaller only for the smoke test).
    ``basis``: the seconds that ``relative``, ``loglog_slope``, ``per_sample_s``, ``ratio_to_recipe``, ``share`` and
    the fits are computed from: ``"wall"`` (wall-clock medians, ``epoch_median_s``) or ``"cpu"`` (process CPU-time
    medians, ``epoch_cpu_s``: on one thread the work itself, the measure to use when other jobs saturate the cores;
    with several threads it also counts their spin-waiting, so use it only with ``--threads 1``)."""
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise ValueError(f"scaling: unknown parts {sorted(unknown)}; choose from {PARTS}")
    if basis not in ("wall", "cpu"):
        raise ValueError(f"scaling: basis must be 'wall' or 'cpu', got {basis!r}")
    rows: list[dict[str, Any]] = []
    if "TN" in parts:
        rows += _tn_rows(ctx, models, steps, copies, batches, basis)
    if "batch" in parts:
        rows += _batch_rows(ctx, batch_models, batch_sizes, batch_samples, num_steps, basis)
    if "breakdown" in parts:
        if breakdown_copies is None:
            breakdown_copies = (1, 2) if ctx.quick else BREAKDOWN_COPIES + ((16,) if ctx.slow else ())
        rows += _breakdown_rows(ctx, breakdown_copies, batches, num_steps, basis)
    kept = _kept_rows(ctx.out / f"{NAME}.csv", parts)
    order = {axis: i for i, axis in enumerate(AXIS_PART)}  # T, N, batch, breakdown: the CSV reads in that order
    rows = sorted(kept + rows, key=lambda r: order.get(str(r.get("axis")), len(order)))  # stable within an axis
    return write_csv(ctx, NAME, COLUMNS, rows)


def _kept_rows(path: Path, parts: Sequence[str]) -> list[dict[str, Any]]:
    """The rows of ``path`` whose axis belongs to a part not measured now, as written (their own environment)."""
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        old = list(csv.DictReader(fh))
    # a column the CSV no longer declares is dropped; one it did not have yet stays empty, except ``basis``: rows
    # from before that column derived everything from wall-clock medians
    return [{k: v for k, v in row.items() if k is not None} | {"basis": row.get("basis") or "wall"} for row in old
            if AXIS_PART.get(row.get("axis", "")) not in parts]


def _scaled_rows(name: str, axis: str, keys: list[Any], values: list[int], timings: dict[Any, Timing],
                 samples: dict[Any, int], extra: dict[Any, dict[str, Any]], basis: str) -> list[dict[str, Any]]:
    """Rows of one model along one axis (``extra``: each key's own columns): times scaled to a 576-sample epoch, and
    on the ``basis`` seconds the time per sample, ``relative`` and the log-log slope."""
    def seconds(t: Timing) -> float:
        return t.median if basis == "wall" else t.cpu_median

    secs = [seconds(timings[k]) * EV_TRAIN_SAMPLES / samples[k] for k in keys]
    slope = loglog_slope(values, secs)
    rows = []
    for key, value, sec in zip(keys, values, secs):
        t, scale = timings[key], EV_TRAIN_SAMPLES / samples[key]
        rows.append({"model": name, "axis": axis, "samples_timed": samples[key], "epoch_median_s": t.median * scale,
                     "epoch_min_s": t.min * scale, "epoch_cpu_s": t.cpu_median * scale, "repeats": len(t),
                     "relative": (sec / secs[0]) / (value / values[0]), "loglog_slope": slope,
                     "per_sample_s": sec / EV_TRAIN_SAMPLES, "basis": basis, "data": "synthetic",
                     "note": f"{samples[key]} samples timed, scaled to {EV_TRAIN_SAMPLES}",
                     **extra[key]})
    return rows


# ------------------------------------------------------------------------------------------------------ T and N
def _tn_rows(ctx: Context, models: tuple[str, ...], steps: tuple[int, ...], copies: tuple[int, ...],
             batches: int | None, basis: str) -> list[dict[str, Any]]:
    from tactile_zoo.engine import fit, seed_everything
    from tactile_zoo.registry import instantiate_model

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
            model = instantiate_model(name, spec).to(ctx.device)
            fit(model, synthetic_events(spec, recipe.batch_size, seed=1), recipe=recipe, device=ctx.device,
                epochs=1)  # warm-up
            split = synthetic_events(spec, n, seed=0)
            fns[(t, c)] = lambda m=model, s=split, r=recipe: fit(m, s, recipe=r, device=ctx.device, epochs=1)
            nodes[(t, c)] = spec.num_nodes
        timings = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
        for axis, keys in axes.items():
            values = [t if axis == "T" else nodes[(t, c)] for t, c in keys]
            extra = {k: {"case": f"{name}_{axis}{v}", "T": k[0], "N": nodes[k], "batch_size": recipe.batch_size}
                     for k, v in zip(keys, values)}
            new = _scaled_rows(name, axis, keys, values, timings, dict.fromkeys(keys, n), extra, basis)
            rows += new
            ctx.log(f"  {name} vs {axis} ({basis}): " + ", ".join(f"{v}: {576 * r['per_sample_s']:.1f} s"
                                                                  for v, r in zip(values, new))
                    + f"; log-log slope {new[0]['loglog_slope']:.2f}")
    return rows


# --------------------------------------------------------------------------------------------------- batch size
def _batch_rows(ctx: Context, models: tuple[str, ...], sizes: tuple[int, ...], samples: int | None,
                num_steps: int, basis: str) -> list[dict[str, Any]]:
    from tactile_zoo.engine import fit, seed_everything
    from tactile_zoo.registry import instantiate_model

    base = samples or (8 if ctx.quick else BATCH_SAMPLES)
    spec = ev_spec(num_steps, 1)
    rows = []
    for name in models:
        recipe = model_recipe(name)
        # the recipe's own batch size is always measured: it is what every ratio is taken against
        keys = sorted(set(sizes) | {recipe.batch_size})
        fns, counts = {}, {}
        for b in keys:
            r = recipe.replace(batch_size=b)
            seed_everything(0)
            model = instantiate_model(name, spec).to(ctx.device)
            # warm-up on a small batch (lazy buffers, allocator): a whole batch of 64 would cost as much as a round
            fit(model, synthetic_events(spec, min(b, 8), seed=1), recipe=r, device=ctx.device, epochs=1)
            counts[b] = max(b, base)
            split = synthetic_events(spec, counts[b], seed=0)
            fns[b] = lambda m=model, s=split, r=r: fit(m, s, recipe=r, device=ctx.device, epochs=1)
        timings = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
        extra = {b: {"case": f"{name}_batch{b}", "T": spec.num_steps, "N": spec.num_nodes, "batch_size": b}
                 for b in keys}
        new = _scaled_rows(name, "batch", keys, keys, timings, counts, extra, basis)
        at_recipe = new[keys.index(recipe.batch_size)]["per_sample_s"]
        for row in new:
            row["ratio_to_recipe"] = row["per_sample_s"] / at_recipe
            row["relative"] = ""  # time / batch size means nothing here: per_sample_s and ratio_to_recipe do
            row["note"] += (f"; recipe batch {recipe.batch_size}: a cost curve, another batch size is another "
                            f"training recipe")
        rows += new
        ctx.log(f"  {name} per sample ({basis}) vs batch (recipe {recipe.batch_size}): "
                + ", ".join(f"{r['batch_size']}: {1e3 * r['per_sample_s']:.1f} ms ({r['ratio_to_recipe']:.2f})"
                            for r in new))
    return rows


# ------------------------------------------------------------------------------------- attention vs the rest
def _sdpa_step(model: Any, batch: int, bins: int, device: torch.device) -> Callable[[], None]:
    """Forward + backward of the taxel self-attention core of every block of ``model`` at one batch's shapes:
    ``scaled_dot_product_attention`` on Q, K, V laid out as the model lays them out (a transposed view of
    ``(T' * B, N, heads, d_k)``), values like LayerNorm outputs (the work does not depend on them)."""
    blocks = list(model.spatial.attn)
    n = model.spec.num_nodes
    gen = torch.Generator().manual_seed(0)
    tensors = []
    for blk in blocks:
        h, dh = blk.num_heads, blk.dim // blk.num_heads
        qkv = [torch.randn(bins * batch, n, h, dh, generator=gen).to(device).transpose(1, 2).requires_grad_()
               for _ in range(3)]
        grad = torch.randn(bins * batch, h, n, dh, generator=gen).to(device)
        tensors.append((qkv, grad))

    def step() -> None:
        for (q, k, v), grad in tensors:
            out = torch.nn.functional.scaled_dot_product_attention(q, k, v)
            q.grad = k.grad = v.grad = None
            out.backward(grad)

    return step


def _graph_conv_step(model: Any, split: Any, batch: int, device: torch.device) -> Callable[[], None]:
    """Forward + backward of the model's graph convolutions (spatial TAGConv, temporal GCN) on one batch of binned
    frames ``(T', B, N, C)``, gradients to their weights (the input is data, as in training)."""
    from tactile_zoo.models._binned import bin_frames

    xb = bin_frames(split.x[:batch], model.bin_size, "sum").transpose(0, 1).contiguous().to(device)
    convs = [model.spatial.gc] + ([model.temporal.cell.gc] if hasattr(model.temporal.cell, "gc") else [])
    gen = torch.Generator().manual_seed(0)
    grads = [torch.randn(*xb.shape[:-1], conv.out_channels, generator=gen).to(device) for conv in convs]

    def step() -> None:
        for conv, grad in zip(convs, grads):
            conv.zero_grad(set_to_none=True)
            conv(xb).backward(grad)

    return step


def _breakdown_rows(ctx: Context, copies: tuple[int, ...], batches: int | None, num_steps: int, basis: str
                    ) -> list[dict[str, Any]]:
    from tactile_zoo.engine import fit, seed_everything
    from tactile_zoo.registry import instantiate_model

    name = "x_tacformer"
    recipe = model_recipe(name)
    b = recipe.batch_size
    nb = batches or 1  # one batch per point: N = 312 (624) costs seconds per batch
    n = b * nb
    fns: dict[tuple[int, str], Callable[[], object]] = {}
    nodes = {}
    for c in copies:
        spec = ev_spec(num_steps, c)
        nodes[c] = spec.num_nodes
        seed_everything(0)
        # the breakdown is of scaled_dot_product_attention: revision 2's fused attention (revision 3, the default
        # since issue 53, computes the product as explicit matmuls, which this profile would not find)
        model = instantiate_model(name, spec, revision=2).to(ctx.device)
        fit(model, synthetic_events(spec, 2, seed=1), recipe=recipe, device=ctx.device, epochs=1)  # warm-up
        split = synthetic_events(spec, n, seed=0)
        bins = -(-num_steps // model.bin_size)
        sdpa, gconv = _sdpa_step(model, b, bins, ctx.device), _graph_conv_step(model, split, b, ctx.device)
        sdpa(), gconv()  # their warm-up
        fns[(c, "total")] = lambda m=model, s=split: fit(m, s, recipe=recipe, device=ctx.device, epochs=1)
        # nb batches per epoch: the parts run once per batch
        fns[(c, "attention")] = lambda f=sdpa: [f() for _ in range(nb)]
        fns[(c, "graph_conv")] = lambda f=gconv: [f() for _ in range(nb)]
    timings = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
    # cross-check of the isolated attention timing inside the real training step: one profiled batch per N
    profiled = {c: _profiled_attention_share(fns[(c, "total")]) for c in copies}
    for c in copies:  # rest = total - attention in the same round: the load of that round cancels
        tot, att = timings[(c, "total")], timings[(c, "attention")]
        timings[(c, "rest")] = Timing([t - a for t, a in zip(tot.times, att.times)],
                                      [t - a for t, a in zip(tot.cpu, att.cpu)])

    values = [nodes[c] for c in copies]
    part_rows: dict[str, list[dict[str, Any]]] = {}
    for part in ("total", "attention", "rest", "graph_conv"):
        keys = [(c, part) for c in copies]
        extra = {k: {"case": f"{name}_{part}_N{nodes[k[0]]}", "part": part, "T": num_steps, "N": nodes[k[0]],
                     "batch_size": b} for k in keys}
        part_rows[part] = _scaled_rows(name, "breakdown", keys, values, timings, dict.fromkeys(keys, n), extra,
                                       basis)
    secs = {part: [EV_TRAIN_SAMPLES * r["per_sample_s"] for r in rs] for part, rs in part_rows.items()}
    fits = {"attention": _fit(values, secs["attention"], 2), "rest": _fit(values, secs["rest"], 1),
            "graph_conv": _fit(values, secs["graph_conv"], 2)}
    cross = _crossover(fits["attention"], fits["rest"])
    # the growth measured at the top of the range: attention's slope still climbs towards 2 there, so a power law
    # over all N (slope well below 2) would put the crossover absurdly far out
    power = {p: _power_law(values[-2:], secs[p][-2:]) for p in ("attention", "rest")}
    cross_log = _power_crossover(power["attention"], power["rest"])
    for part, rs in part_rows.items():
        for row, total in zip(rs, part_rows["total"]):
            row["share"] = row["per_sample_s"] / total["per_sample_s"]
            row["crossover_N"], row["crossover_N_loglog"] = cross, cross_log
            if part in fits:
                row["fit_coef"], row["fit_const"], row["fit_power"] = *fits[part], 2 if part != "rest" else 1
            if part == "attention":
                row["profiled_share"] = profiled[copies[values.index(row["N"])]]
            row["note"] += "; rest = total - attention (graph_conv is part of the rest)"
    ctx.log(f"  {name} at N = {values} ({basis}): attention {_list(secs['attention'])} s, rest {_list(secs['rest'])} s "
            f"(of which graph conv {_list(secs['graph_conv'])} s) per 576-sample epoch, attention share in a profiled "
            f"batch {_list(list(profiled.values()))}; attention "
            f"{fits['attention'][0]:.3g} N^2 + {fits['attention'][1]:.3g}, rest {fits['rest'][0]:.3g} N + "
            f"{fits['rest'][1]:.3g}: equal at N = {cross:.0f} (power laws N^{power['attention'][1]:.2f} and "
            f"N^{power['rest'][1]:.2f} over the two largest N: N = {cross_log:.0f})")
    return [row for rs in part_rows.values() for row in rs]


def _list(values: Sequence[float]) -> str:
    return "/".join(f"{v:.3g}" for v in values)


def _fit(xs: Sequence[float], ys: Sequence[float], power: int) -> tuple[float, float]:
    """``y = coef * x**power + const`` by least squares on relative residuals ``(fit - y) / y``, so the small sizes,
    where the fixed per-call costs show, count as much as the large ones. Returns ``(coef, const)``."""
    # weighted normal equations of the 2-parameter linear model, weights 1 / y^2
    w = [1.0 / (y * y) for y in ys]
    u = [x ** power for x in xs]
    s_uu = sum(wi * ui * ui for wi, ui in zip(w, u))
    s_u = sum(wi * ui for wi, ui in zip(w, u))
    s_1 = sum(w)
    s_uy = sum(wi * ui * yi for wi, ui, yi in zip(w, u, ys))
    s_y = sum(wi * yi for wi, yi in zip(w, ys))
    det = s_uu * s_1 - s_u * s_u
    if not det:
        return float("nan"), float("nan")
    return (s_uy * s_1 - s_u * s_y) / det, (s_uu * s_y - s_u * s_uy) / det


def _crossover(att: tuple[float, float], rest: tuple[float, float]) -> float:
    """The N > 0 where ``a N^2 + a0 = b N + b0`` (the larger root: beyond it attention stays the larger part);
    inf when the fitted attention never catches up."""
    (a, a0), (b, b0) = att, rest
    if not a > 0:
        return math.inf
    disc = b * b - 4 * a * (a0 - b0)
    return (b + math.sqrt(disc)) / (2 * a) if disc >= 0 else 0.0  # no real root: attention is larger everywhere


def _profiled_attention_share(step: Callable[[], object]) -> float:
    """Fraction of the op time of one ``step`` (torch.profiler, self CPU time summed over all ops) spent in
    ``scaled_dot_product_attention``, forward and backward. Time between ops (the interpreter) is not op time, so
    this slightly overstates the share of the whole step; it checks the isolated timing, it does not replace it."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        step()
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    # forward op, its backward op and the autograd node (CamelCase) around the backward
    att = sum(e.self_cpu_time_total for e in events if "scaleddotproduct" in e.key.lower().replace("_", ""))
    return att / total if total else float("nan")


def _power_law(xs: Sequence[float], ys: Sequence[float]) -> tuple[float, float]:
    """``y = c x^p`` fitted on log-log axes: ``(c, p)``."""
    p = loglog_slope(xs, ys)
    lc = sum(math.log(y) - p * math.log(x) for x, y in zip(xs, ys)) / len(xs)
    return math.exp(lc), p


def _power_crossover(att: tuple[float, float], rest: tuple[float, float]) -> float:
    (ca, pa), (cr, pr) = att, rest
    return math.exp(math.log(cr / ca) / (pa - pr)) if pa > pr else math.inf


# ----------------------------------------------------------------------------------------------------------- CLI
def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.scaling --parts batch,breakdown``: some parts only, the committed rows of the others
    kept. The suite's runner (``python -m benchmarks.run --only scaling``) runs all three."""
    from tactile_zoo.engine.runtime import flush_denormals

    p = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=main.__doc__)
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma list of {', '.join(PARTS)} (default all)")
    p.add_argument("--quick", action="store_true", help="few repeats, small sizes: checks that it runs")
    p.add_argument("--slow", action="store_true", help="breakdown also at N = 624")
    p.add_argument("--threads", type=int, default=2, help="torch threads (default 2, as benchmarks.run)")
    p.add_argument("--repeats", type=int, default=None, help="interleaved rounds (default 3, 1 with --quick)")
    p.add_argument("--basis", choices=("wall", "cpu"), default="wall",
                   help="seconds the derived columns use: wall (default) or process CPU time (with --threads 1, "
                        "on a machine whose cores other jobs keep busy)")
    p.add_argument("--batch-models", default=",".join(BATCH_MODELS), help="models of the batch part")
    p.add_argument("--batch-sizes", default=",".join(map(str, BATCH_SIZES)), help="batch sizes of the batch part")
    p.add_argument("--batch-samples", type=int, default=None,
                   help=f"samples timed per batch size, at least one batch (default {BATCH_SAMPLES})")
    p.add_argument("--copies", default=None,
                   help="sensor copies of the breakdown part (default 1,2,4,8, N = 39..312; 16 with --slow)")
    p.add_argument("--out", type=Path, default=None, help="folder of scaling.csv (default benchmarks/results)")
    args = p.parse_args(argv)
    parts = tuple(s.strip() for s in args.parts.split(",") if s.strip())
    copies = tuple(int(c) for c in args.copies.split(",")) if args.copies else None
    with flush_denormals() as flushing:  # as benchmarks.run does: flush-to-zero before torch starts its threads
        torch.set_num_threads(args.threads)
        ctx = Context(threads=args.threads, quick=args.quick, repeats=args.repeats, slow=args.slow,
                      flush_denormals=flushing, **({"out": args.out} if args.out else {}))
        path = run(ctx, parts=parts, batch_models=tuple(m for m in args.batch_models.split(",") if m),
                   batch_sizes=tuple(int(b) for b in args.batch_sizes.split(",")), batch_samples=args.batch_samples,
                   breakdown_copies=copies, basis=args.basis)
    print(f"wrote {path}")
    return 0


__all__ = ["run", "NAME", "TITLE", "main"]

if __name__ == "__main__":
    sys.exit(main())
