"""SGnet training steps on Ev-Objects: the opt-in event-driven computation against the default dense one.

``python -m benchmarks.sgnet_event [--variant event] [--threads 1] [--batches 4] [--repeats 7] [--quick]`` (also in
``benchmarks.run`` as ``sgnet_event``).

Fast: ``create_model("sgnet", spec, compute=<variant>)`` (``"event"``: the graph convolution as one product over the
input events and the 2496 -> 128 layer over the first LIF's spikes, :mod:`tactile_zoo.nn.event_linear`). Naive: the
default model (``compute="dense"``), from the same initial weights. Each timed call runs ``--batches`` training steps
(forward, MSE-on-rates loss, backward, Adam amsgrad step: the registered recipe's) on consecutive batches of the
recipe's size from the released train folder; both sides see the same batches, interleaved in rotating order.

Rows: ``train_step`` (the whole step), ``graph_conv`` and ``first_linear`` (each product alone, forward + backward,
on the first batch and on its first LIF's spikes), and ``event_scan`` (only the fast side: building the event list
of the first LIF's spikes, what an active-index by-product of the LIF kernel would save). ``same_spikes``: the last
hidden layer's spikes of both models on the first batch are identical; ``grad_rel_diff``: the largest relative
difference of any parameter's gradient on it (max |difference| / max |gradient|, per parameter).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .common import PAIR_COLUMNS, Context, Timing, ev_objects, model_recipe, pair_row, time_interleaved, write_csv

NAME = "sgnet_event"
TITLE = "SGnet training step on Ev-Objects: opt-in event-driven computation vs the default dense one"
COLUMNS = (*PAIR_COLUMNS, "data", "variant", "batch", "steps_per_call", "input_density", "lif_rate", "same_spikes",
           "grad_rel_diff", "load_avg")
#: the opt-in computations of SGnet this benchmark can time against the default ``"dense"``
VARIANTS = ("event",)


def _grads(model: nn.Module, x: Tensor, y: Tensor, recipe: Any) -> tuple[Tensor, dict[str, Tensor]]:
    from tactile_zoo.engine.train import compute_loss

    model.zero_grad(set_to_none=True)
    spikes = model.forward_features(x)
    compute_loss(model.forward_head(spikes), y, recipe).backward()
    return spikes.detach(), {n: p.grad.clone() for n, p in model.named_parameters()}


def _compare(dense: nn.Module, fast: nn.Module, x: Tensor, y: Tensor, recipe: Any) -> tuple[bool, float]:
    spikes_d, grads_d = _grads(dense, x, y, recipe)
    spikes_f, grads_f = _grads(fast, x, y, recipe)
    worst = max(float((grads_f[n] - g).abs().max() / g.abs().max()) for n, g in grads_d.items() if g.abs().max() > 0)
    dense.zero_grad(set_to_none=True), fast.zero_grad(set_to_none=True)
    return bool(torch.equal(spikes_d, spikes_f)), worst


def run(ctx: Context, variant: str = "event", batches: int | None = None) -> Path:
    from tactile_zoo.engine.train import build_optimizer, compute_loss
    from tactile_zoo.nn.event_graph_conv import event_graph_conv
    from tactile_zoo.nn.event_linear import event_linear, events_of
    from tactile_zoo.registry import instantiate_model

    if variant not in VARIANTS:
        raise ValueError(f"--variant must be one of {VARIANTS}, got {variant!r}")
    data = ev_objects(ctx)
    split, recipe = data.train, model_recipe("sgnet")
    size = recipe.batch_size
    n_batches = batches or (1 if ctx.quick else 4)
    xs = [split.x[i * size:(i + 1) * size].float() for i in range(n_batches)]
    ys = [split.y[i * size:(i + 1) * size].long() for i in range(n_batches)]
    torch.manual_seed(0)
    dense = instantiate_model("sgnet", split.spec)
    fast = instantiate_model("sgnet", split.spec, compute=variant)
    fast.load_state_dict(dense.state_dict())
    same, grad_diff = _compare(dense, fast, xs[0], ys[0], recipe)
    ctx.log(f"  compute={variant!r} against dense: same spikes {same}, largest gradient relative difference "
            f"{grad_diff:.2g}")
    opts = {id(m): build_optimizer(m, recipe) for m in (dense, fast)}

    def steps(model: nn.Module) -> None:
        opt = opts[id(model)]
        for x, y in zip(xs, ys):
            opt.zero_grad(set_to_none=True)
            compute_loss(model(x), y, recipe).backward()
            opt.step()

    # the two products alone, at the first batch's shapes: time-major input events and the first LIF's spikes
    frames = xs[0].transpose(0, 1).contiguous()  # (T, B, N, C)
    with torch.no_grad():
        spikes = dense.lifs[0](dense.gc(frames).reshape(*frames.shape[:2], -1))  # (T, B, N * F)
    grad_h = torch.randn(*frames.shape[:3], dense.gc.out_channels)
    grad_s = torch.randn(*spikes.shape[:2], dense.fcs[0].out_features)
    spikes_in = spikes.clone().requires_grad_()  # the LIF below needs this gradient: the dense input gradient too

    def conv(event: bool) -> None:
        (event_graph_conv(dense.gc, frames) if event else dense.gc(frames)).backward(grad_h)

    def linear(event: bool) -> None:
        fc = dense.fcs[0]
        (event_linear(spikes_in, fc.weight, fc.bias) if event else fc(spikes_in)).backward(grad_s)

    flat = spikes.reshape(-1, spikes.shape[-1])
    fns = {"fast": lambda: steps(fast), "dense": lambda: steps(dense), "conv_event": lambda: conv(True),
           "conv_dense": lambda: conv(False), "linear_event": lambda: linear(True),
           "linear_dense": lambda: linear(False), "scan": lambda: events_of(flat)}
    with ctx.threads_scope(ctx.threads):
        load_before = "/".join(f"{v:.2f}" for v in os.getloadavg())
        t = time_interleaved(fns, ctx.reps(7, 2), ctx)
        load = f"{load_before} -> " + "/".join(f"{v:.2f}" for v in os.getloadavg())
    per_step = {k: Timing([v / n_batches for v in t[k].times], [v / n_batches for v in t[k].cpu])
                for k in ("fast", "dense")}
    common = dict(data=data.source, variant=variant, batch=size, input_density=float(split.x[:size * n_batches]
                  .float().mean()), lif_rate=float(spikes.mean()), load_avg=load)
    fast_desc, dense_desc = f"sgnet compute={variant!r}", "sgnet compute='dense' (default)"
    note = "seconds per training step (forward, loss, backward, Adam step) at the recipe's batch"
    rows = [pair_row("train_step", fast_desc, dense_desc, per_step["fast"], per_step["dense"], **common,
                     steps_per_call=n_batches, same_spikes=same, grad_rel_diff=grad_diff, note=note),
            pair_row("graph_conv", "event_graph_conv", "FrameGraphConv (dense backend)", t["conv_event"],
                     t["conv_dense"], **common, steps_per_call=1, note="forward + backward, first batch"),
            pair_row("first_linear", "event_linear", "nn.Linear", t["linear_event"], t["linear_dense"], **common,
                     steps_per_call=1, note="forward + backward (input gradient included), first LIF's spikes"),
            {"case": "event_scan", "fast": "events_of (the event list of the first LIF's spikes)",
             "fast_median_s": t["scan"].median, "fast_min_s": t["scan"].min, "repeats": len(t["scan"]),
             "fast_cpu_s": t["scan"].cpu_median, **common, "steps_per_call": 1,
             "note": "part of the fast side's first_linear; what an active-index by-product of the LIF would save"}]
    ctx.log(f"  train step: {variant} {per_step['fast'].median * 1e3:.0f} ms, dense "
            f"{per_step['dense'].median * 1e3:.0f} ms -> {rows[0]['ratio']:.2f}x; graph conv {rows[1]['ratio']:.2f}x, "
            f"first linear {rows[2]['ratio']:.2f}x, event scan {t['scan'].median * 1e3:.1f} ms; load {load}")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.sgnet_event", description=TITLE)
    parser.add_argument("--variant", choices=VARIANTS, default="event", help="the opt-in computation (default event)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--batches", type=int, default=None, help="training steps per timed call (default 4)")
    parser.add_argument("--repeats", type=int, default=None, help="timed rounds (default 7)")
    parser.add_argument("--quick", action="store_true", help="1 batch, 2 rounds: checks that it runs")
    parser.add_argument("--out", type=Path, default=None, help="folder of the CSV (default benchmarks/results)")
    parser.add_argument("--root", type=Path, default=None, help="data home with Ev-Objects")
    args = parser.parse_args(argv)
    from tactile_zoo.engine.runtime import flush_denormals

    ctx = Context(threads=args.threads, quick=args.quick, repeats=args.repeats, root=args.root,
                  **({"out": args.out} if args.out else {}))
    with flush_denormals():
        path = run(ctx, variant=args.variant, batches=args.batches)
    print(path.read_text())
    return 0


__all__ = ["run", "main", "NAME", "TITLE", "VARIANTS"]

if __name__ == "__main__":
    sys.exit(main())
