"""SGnet training epoch on Ev-Objects: the zoo's batched model vs a batch-1, one-layer-call-per-time-step SGnet.

Fast: ``tactile_zoo`` ``sgnet`` trained by the engine (``fit``, one epoch) with its registered recipe (batch 8, Adam
amsgrad, MSE on output spike rates) on the 576 samples of Ev-Objects' released train folder.

Naive: :class:`StepwiseSGNet` below, the structure of the public TactileSGNet code (Gu et al., IROS 2020): batch
size 1, and for every time step of a sample, PyG ``TAGConv`` on that frame's graph (PyG re-normalises the adjacency
at every call), a LIF update, Linear 128, LIF, Linear 256, LIF, Linear K, LIF, the output spikes summed; rates =
count / T; one optimiser step per sample. Same neuron rule (``mem = 0.2 * mem * (1 - spike) + I``, spike where
``mem > 0.5``, rectangular surrogate of half-width 0.5, reset gradient kept), same loss and optimiser.

The zoo model's LIF layers run the compiled kernel (row ``epoch``, target 60x, issue 30); row ``epoch_fused_torch``
times the same model on the fused torch LIF path (``TACTILE_ZOO_LIF_BACKEND=torch``, what ``epoch`` measured before
the kernel) in the same rounds, and row ``compiled_vs_fused`` compares the two. ``load_avg``: ``os.getloadavg()``
before and after the timed rounds.

Opt-in (row ``graph_weight_grad_fast``): the same zoo model with ``graph_weight_grad="fast"`` (the TAGConv weights'
gradient summed in another order, without copying the layer's output gradient; the same spikes, gradients rounded
differently), from the same initial weights, timed in the same interleaved rounds as the other two.

Same model: before timing, the naive network copies the fast one's weights and both score the same samples; the CSV
reports the largest difference of output rates and of the first layer's weight gradient on one sample (each zoo
variant against the naive network). The naive epoch is too slow to run whole (about 0.8 s per sample on 2 cores): a
subset is timed and scaled to 576 samples (the CSV says how many samples each side timed).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .common import (
    EV_TRAIN_SAMPLES,
    PAIR_COLUMNS,
    Context,
    Timing,
    ev_objects,
    model_recipe,
    pair_row,
    time_interleaved,
    write_csv,
)
from .lif import lif_path

NAME = "sgnet_epoch"
TITLE = "SGnet training epoch on Ev-Objects: batched zoo model vs batch-1 per-time-step reference structure"
COLUMNS = (*PAIR_COLUMNS, "data", "fast_samples_timed", "naive_samples_timed", "naive_s_per_sample",
           "max_rate_diff", "grad_rel_diff", "load_avg", "target")


class _RectSpike(torch.autograd.Function):
    """Heaviside spike ``mem > threshold``; backward passes the gradient where ``|mem - threshold| < half_width``."""

    @staticmethod
    def forward(ctx: Any, mem: Tensor, threshold: float, half_width: float) -> Tensor:
        ctx.save_for_backward(mem)
        ctx.threshold, ctx.half_width = threshold, half_width
        return (mem > threshold).to(mem.dtype)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None]:
        (mem,) = ctx.saved_tensors
        return grad * ((mem - ctx.threshold).abs() < ctx.half_width).to(grad.dtype), None, None


class StepwiseSGNet(nn.Module):
    """SGnet run the way the public reference runs it: one sample, one layer call per time step.

    Args:
        conv: a PyG ``TAGConv`` (channels -> F).
        fcs: the linear layers ``N * F -> 128 -> 256 -> K``.
        edge_index: the taxel graph.
        beta, threshold, half_width: LIF decay, firing threshold and surrogate half-width (0.2, 0.5, 0.5).

    Shapes:
        input ``(T, N, C)`` (one sample) -> output spike rates ``(K,)``.
    """

    def __init__(self, conv: nn.Module, fcs: list[nn.Module], edge_index: Tensor, beta: float = 0.2,
                 threshold: float = 0.5, half_width: float = 0.5) -> None:
        super().__init__()
        self.conv, self.fcs = conv, nn.ModuleList(fcs)
        self.register_buffer("edge_index", edge_index, persistent=False)
        self.beta, self.threshold, self.half_width = beta, threshold, half_width

    @classmethod
    def like(cls, model: nn.Module) -> StepwiseSGNet:
        """A stepwise network holding copies of a ``tactile_zoo`` SGNet's weights (same function)."""
        import copy

        return cls(copy.deepcopy(model.gc.conv), [copy.deepcopy(fc) for fc in model.fcs], model.gc.edge_index.clone(),
                   model.lifs[0].beta, model.lifs[0].threshold, model.lifs[0].surrogate.param / 2)

    def _lif(self, current: Tensor, mem: Tensor, spike: Tensor) -> tuple[Tensor, Tensor]:
        mem = mem * self.beta * (1.0 - spike) + current  # the reset keeps its gradient, as in the reference
        return mem, _RectSpike.apply(mem, self.threshold, self.half_width)

    def forward(self, x: Tensor) -> Tensor:
        layers = len(self.fcs) + 1
        mems: list[Tensor | float] = [0.0] * layers  # every sequence starts at rest
        spikes: list[Tensor | float] = [0.0] * layers
        count: Tensor | float = 0.0
        for frame in x.unbind(0):  # (N, C): one time step
            s = self.conv(frame, self.edge_index)  # (N, F); PyG normalises the graph again at every call
            for i in range(layers):
                if i > 0:
                    s = self.fcs[i - 1](s.reshape(-1))  # (N * F) into the first linear layer
                mems[i], spikes[i] = self._lif(s, mems[i], spikes[i])
                s = spikes[i]
            count = count + s  # output spikes (K,)
        return count / x.shape[0]  # (K,)


def _naive_train(net: StepwiseSGNet, opt: torch.optim.Optimizer, split: Any, n: int, recipe: Any) -> None:
    from tactile_zoo.engine.train import compute_loss

    net.train()
    for i in range(n):  # batch size 1, one optimiser step per sample
        rates = net(split.x[i])
        loss = compute_loss(rates[None], split.y[i:i + 1], recipe)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()


def _same_model(model: nn.Module, net: StepwiseSGNet, split: Any, n: int, recipe: Any) -> tuple[float, float]:
    """(largest |rate difference| over ``n`` samples, relative difference of the first linear layer's weight
    gradient on sample 0) between the zoo model and the stepwise network holding the same weights."""
    from tactile_zoo.engine.train import compute_loss

    with torch.no_grad():
        fast = model.eval()(split.x[:n])  # (n, K)
        naive = torch.stack([net.eval()(split.x[i]) for i in range(n)])
    rate_diff = float((fast - naive).abs().max())
    model.train(), net.train()
    model.zero_grad(set_to_none=True), net.zero_grad(set_to_none=True)
    compute_loss(model(split.x[:1]), split.y[:1], recipe).backward()
    compute_loss(net(split.x[0])[None], split.y[:1], recipe).backward()
    g_fast, g_naive = model.fcs[0].weight.grad, net.fcs[0].weight.grad
    grad_diff = float((g_fast - g_naive).abs().max() / g_naive.abs().max().clamp_min(1e-30))
    model.zero_grad(set_to_none=True), net.zero_grad(set_to_none=True)
    return rate_diff, grad_diff


def _scaled(t: Timing, factor: float) -> Timing:
    return Timing([v * factor for v in t.times], [v * factor for v in t.cpu])


def run(ctx: Context, fast_samples: int | None = None, naive_samples: int | None = None, check_samples: int = 4,
        opt_in: bool = True) -> Path:
    from tactile_zoo.engine import TensorSplit, fit, take
    from tactile_zoo.engine.train import build_optimizer
    from tactile_zoo.registry import instantiate_model

    data = ev_objects(ctx)
    split = data.train
    dev = ctx.device
    full = len(split)
    fast_n = min(full, fast_samples or (64 if ctx.quick else full))
    naive_n = min(full, naive_samples or (4 if ctx.quick else 32))
    recipe = model_recipe("sgnet")
    torch.manual_seed(0)
    model = instantiate_model("sgnet", split.spec).to(dev)
    net = StepwiseSGNet.like(model).to(dev)
    on_dev = TensorSplit(split.x.to(dev), split.g.to(dev), split.y.to(dev), split.spec, split.name)
    rate_diff, grad_diff = _same_model(model, net, on_dev, min(check_samples, full), recipe)
    ctx.log(f"  same model: max |rate difference| {rate_diff:g} over {min(check_samples, full)} samples, "
            f"weight-gradient relative difference {grad_diff:.2g}")
    fast_split = take(split, fast_n, seed=0) if fast_n < full else split
    opt = build_optimizer(net, recipe)
    fused = instantiate_model("sgnet", split.spec).to(dev)  # the same model on the fused torch LIF path
    fused.load_state_dict(model.state_dict())

    def fit_fused() -> None:
        with lif_path("torch"):
            fit(fused, fast_split, recipe=recipe, device=dev, epochs=1)

    fns = {"fast": lambda: fit(model, fast_split, recipe=recipe, device=dev, epochs=1), "fused": fit_fused,
           "naive": lambda: _naive_train(net, opt, on_dev, naive_n, recipe)}
    if opt_in:  # the same initial weights as the default model, so the same naive network checks it
        variant = instantiate_model("sgnet", split.spec, graph_weight_grad="fast").to(dev)
        variant.load_state_dict(model.state_dict())
        v_rate_diff, v_grad_diff = _same_model(variant, net, on_dev, min(check_samples, full), recipe)
        ctx.log(f"  graph_weight_grad='fast': max |rate difference| {v_rate_diff:g}, weight-gradient relative "
                f"difference {v_grad_diff:.2g}")
        fns["opt_in"] = lambda: fit(variant, fast_split, recipe=recipe, device=dev, epochs=1)
    # warm-up outside the timing: one batch of each engine loop, one naive sample
    warm = take(split, recipe.batch_size, seed=1)
    for zoo in [model, variant] if opt_in else [model]:
        fit(zoo, warm, recipe=recipe, device=dev, epochs=1)
    with lif_path("torch"):
        fit(fused, warm, recipe=recipe, device=dev, epochs=1)
    _naive_train(net, opt, on_dev, 1, recipe)
    load_before = "/".join(f"{v:.2f}" for v in os.getloadavg())
    t = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
    load = f"{load_before} -> " + "/".join(f"{v:.2f}" for v in os.getloadavg())
    fast, naive = _scaled(t["fast"], EV_TRAIN_SAMPLES / fast_n), _scaled(t["naive"], EV_TRAIN_SAMPLES / naive_n)
    fast_fused = _scaled(t["fused"], EV_TRAIN_SAMPLES / fast_n)
    note = (f"seconds per epoch of {EV_TRAIN_SAMPLES} samples; naive extrapolated from {naive_n} samples"
            + (f", fast from {fast_n}" if fast_n < EV_TRAIN_SAMPLES else ", fast measured on the whole epoch")
            + "; same weights give the same outputs (max_rate_diff); accuracy per epoch at batch 8 vs 1 is not "
              "measured here")
    naive_desc = "StepwiseSGNet: batch 1, PyG TAGConv + LIF + Linear per time step"
    common = dict(data=data.source, fast_samples_timed=fast_n, naive_samples_timed=naive_n,
                  naive_s_per_sample=t["naive"].median / naive_n, load_avg=load)
    zoo_desc = f"sgnet, engine fit, batch {recipe.batch_size}, dense graph conv"
    rows = [pair_row("epoch", f"{zoo_desc}, compiled LIF kernel", naive_desc, fast, naive, **common,
                     max_rate_diff=rate_diff, grad_rel_diff=grad_diff, target=">= 60x faster (issue 30)", note=note),
            pair_row("epoch_fused_torch", f"{zoo_desc}, fused torch LIF (TACTILE_ZOO_LIF_BACKEND=torch)", naive_desc,
                     fast_fused, naive, **common, target="(the path before issue 30; same rounds)", note=note),
            pair_row("compiled_vs_fused", f"{zoo_desc}, compiled LIF kernel",
                     f"{zoo_desc}, fused torch LIF (TACTILE_ZOO_LIF_BACKEND=torch)", fast, fast_fused,
                     **{**common, "naive_samples_timed": fast_n}, target="(what the kernel is worth per epoch)",
                     note="both sides timed on the same samples in the same rounds")]
    ctx.log(f"  epoch: compiled {fast.median:.1f} s, fused torch {fast_fused.median:.1f} s, naive {naive.median:.0f} s "
            f"(extrapolated; {rows[0]['naive_s_per_sample']:.2f} s/sample) -> {rows[0]['ratio']:.0f}x, fused torch "
            f"{rows[1]['ratio']:.0f}x; load {load}")
    if opt_in:
        fast_v = _scaled(t["opt_in"], EV_TRAIN_SAMPLES / fast_n)
        rows.append(pair_row(
            "graph_weight_grad_fast", f"sgnet graph_weight_grad='fast' (opt-in), engine fit, batch "
                                      f"{recipe.batch_size}", naive_desc, fast_v, naive, **common,
            max_rate_diff=v_rate_diff, grad_rel_diff=v_grad_diff, target="(opt-in; issue 18)",
            note=note + f"; the same timing rounds as row epoch, which takes {fast.median / fast_v.median:.2f}x "
                        f"its time"))
        ctx.log(f"  graph_weight_grad='fast': {fast_v.median:.1f} s -> {rows[-1]['ratio']:.0f}x "
                f"({fast.median / fast_v.median:.2f}x the default)")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE", "StepwiseSGNet"]
