"""Multi-step LIF layer, forward + backward: the fused backend vs stepping ``snntorch.Leaky`` once per time step.

Input ``(T, B, N * F)`` currents (T=250, B=32, 39 taxels x 64 features: SGnet's first spiking layer on Ev-Objects),
a fixed random upstream gradient on the spikes, one backward to the input. Two neurons:

- ``sgnet``: TactileSGNet's neuron (beta 0.2, threshold 0.5, reset to zero, rectangular surrogate, reset *not*
  detached). Naive: ``MultiStepLIF(backend="snntorch")``, which steps ``snntorch.Leaky`` (with the reset left in the
  graph) over ``x.unbind(0)``.
- ``snntorch_default``: the same with snnTorch's detached reset. Naive: a plain ``snntorch.Leaky`` loop written here.

Both check that the fused backend gives the same spikes (max abs difference) and input gradients (max abs difference
relative to the largest gradient). With ``--slow`` the ``x[t]`` indexing anti-pattern (the same snnTorch loop, but
indexing the grad-requiring input as ``x[t]``) is timed once as well: every ``x[t]`` backward materialises a gradient
as large as ``x``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor

from .common import PAIR_COLUMNS, Context, pair_row, time_interleaved, write_csv

NAME = "lif"
TITLE = "Multi-step LIF, forward+backward: fused vs stepping snntorch.Leaky"
COLUMNS = (*PAIR_COLUMNS, "params", "max_spike_diff", "grad_rel_diff", "target")

BETA, THRESHOLD = 0.2, 0.5


def _snntorch_leaky() -> torch.nn.Module:
    """``snntorch.Leaky`` with TactileSGNet's constants (snnTorch always detaches its reset)."""
    import snntorch

    from tactile_zoo.nn.lif import make_surrogate

    return snntorch.Leaky(beta=BETA, threshold=THRESHOLD, spike_grad=make_surrogate("rect").spike_fn,
                          reset_mechanism="zero")


def stepping_loop(leaky: torch.nn.Module, x: Tensor) -> Tensor:
    """The naive way: ``snntorch.Leaky`` called once per step over ``x.unbind(0)``; spikes ``(T, *)``."""
    mem = torch.zeros_like(x[0].detach())
    spikes = []
    for x_t in x.unbind(0):
        spk, mem = leaky(x_t, mem)
        spikes.append(spk)
    return torch.stack(spikes)


def indexing_loop(leaky: torch.nn.Module, x: Tensor) -> Tensor:
    """The anti-pattern the project forbids: the same loop reading ``x[t]`` (each backward of ``x[t]`` allocates and
    fills a zero tensor as large as ``x``)."""
    mem = torch.zeros_like(x[0].detach())
    spikes = []
    for t in range(x.shape[0]):
        spk, mem = leaky(x[t], mem)
        spikes.append(spk)
    return torch.stack(spikes)


def _fwd_bwd(forward: Callable[[Tensor], Tensor], x: Tensor, grad_out: Tensor) -> Callable[[], tuple[Tensor, Tensor]]:
    leaf = x.detach().requires_grad_(True)

    def run() -> tuple[Tensor, Tensor]:
        leaf.grad = None
        spikes = forward(leaf)
        spikes.backward(grad_out)
        return spikes.detach(), leaf.grad

    return run


def run(ctx: Context, batch: int = 32, steps: int = 250, nodes: int = 39, features: int = 64) -> Path:
    from tactile_zoo.nn.lif import MultiStepLIF

    dev = ctx.device
    gen = torch.Generator().manual_seed(0)
    # currents around the threshold, so that neurons fire and reset (about a third of the steps spike)
    x = (0.4 + 0.5 * torch.randn(steps, batch, nodes * features, generator=gen)).to(dev)  # (T, B, N * F)
    grad_out = torch.randn(x.shape, generator=gen).to(dev)
    params = f"B={batch} T={steps} features={nodes}x{features}"
    repeats = ctx.reps(7, 3)
    rows, timings = [], {}
    for case, detach in (("sgnet", False), ("snntorch_default", True)):
        fused = MultiStepLIF(BETA, THRESHOLD, reset="zero", surrogate="rect", detach_reset=detach, backend="fused")
        if detach:
            leaky = _snntorch_leaky().to(dev)
            naive_name = "snntorch.Leaky loop over x.unbind(0) (written here)"

            def naive_fwd(v: Tensor, leaky: torch.nn.Module = leaky) -> Tensor:
                return stepping_loop(leaky, v)
        else:
            naive_name = "MultiStepLIF(backend='snntorch'): snntorch.Leaky per step over x.unbind(0)"
            naive_fwd = MultiStepLIF(BETA, THRESHOLD, reset="zero", surrogate="rect", detach_reset=False,
                                     backend="snntorch")
        fast_fn, naive_fn = _fwd_bwd(fused, x, grad_out), _fwd_bwd(naive_fwd, x, grad_out)
        (s_fast, g_fast), (s_naive, g_naive) = fast_fn(), naive_fn()
        spike_diff = float((s_fast - s_naive).abs().max())
        grad_diff = float((g_fast - g_naive).abs().max() / g_naive.abs().max().clamp_min(1e-30))
        t = time_interleaved({"fast": fast_fn, "naive": naive_fn}, repeats, ctx, warmup=0)  # both ran just above
        timings[case] = t
        rows.append(pair_row(case, "MultiStepLIF(backend='fused')", naive_name, t["fast"], t["naive"],
                             params=params, max_spike_diff=spike_diff, grad_rel_diff=grad_diff,
                             target="fused >= 3x faster, same spikes and gradients",
                             note=f"spike rate {float(s_fast.mean()):.3f}"))
        ctx.log(f"  {case}: fused {t['fast'].median * 1e3:.1f} ms, snntorch stepping {t['naive'].median * 1e3:.1f} ms"
                f" -> {rows[-1]['ratio']:.1f}x (spike diff {spike_diff:g}, grad rel diff {grad_diff:.2g})")
    if ctx.slow:
        leaky = _snntorch_leaky().to(dev)
        slow_fn = _fwd_bwd(lambda v: indexing_loop(leaky, v), x, grad_out)
        t_slow = time_interleaved({"naive": slow_fn}, 1, ctx, warmup=0)["naive"]
        fast = timings["snntorch_default"]["fast"]
        rows.append(pair_row("x[t]_antipattern", "MultiStepLIF(backend='fused')",
                             "snntorch.Leaky loop reading x[t] (forbidden in the project)", fast, t_slow,
                             params=params, target="(reference only: why no loop may index x[t])",
                             note="naive timed once; fast timings of the snntorch_default case"))
        t_unbind = timings["snntorch_default"]["naive"]
        ctx.log(f"  x[t] anti-pattern: {t_slow.median:.2f} s, {t_slow.median / t_unbind.median:.1f}x the unbind loop")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE", "stepping_loop", "indexing_loop"]
