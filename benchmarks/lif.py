"""Multi-step LIF layer, forward + backward on 1 thread: the compiled kernel and the fused torch path (both
``MultiStepLIF(backend="fused")``, chosen by ``TACTILE_ZOO_LIF_BACKEND=numba|torch``) vs stepping ``snntorch.Leaky``
once per time step, all three timed in the same interleaved rounds.

Input ``(T, B, N * F)`` currents (T=250, B=32, 39 taxels x 64 features: SGnet's first spiking layer on Ev-Objects),
a fixed random upstream gradient on the spikes, one backward to the input. Two neurons:

- ``sgnet``: TactileSGNet's neuron (beta 0.2, threshold 0.5, reset to zero, rectangular surrogate, reset *not*
  detached). Naive: ``MultiStepLIF(backend="snntorch")``, which steps ``snntorch.Leaky`` (with the reset left in the
  graph) over ``x.unbind(0)``.
- ``snntorch_default``: the same with snnTorch's detached reset. Naive: a plain ``snntorch.Leaky`` loop written here.

Per neuron three rows: ``<case>`` (compiled vs snnTorch, target 10x, issue 30), ``<case>_fused`` (fused torch vs
snnTorch, the row this benchmark had before) and ``<case>_compiled_vs_fused``. Each checks the fast side against
the slow one: spikes (max abs difference) and input gradients (max abs difference relative to the largest gradient);
``equal_to_fused`` says whether the compiled kernel's spikes and input gradient are bit-identical
(``torch.equal``) to the fused path's. ``load_avg`` is ``os.getloadavg()`` before and after the timed rounds.

With ``--slow`` the ``x[t]`` indexing anti-pattern (the same snnTorch loop, but
indexing the grad-requiring input as ``x[t]``) is timed once as well: every ``x[t]`` backward materialises a gradient
as large as ``x``.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import torch
from torch import Tensor

from .common import PAIR_COLUMNS, Context, pair_row, time_interleaved, write_csv

NAME = "lif"
TITLE = "Multi-step LIF, forward+backward, 1 thread: compiled kernel and fused torch path vs stepping snntorch.Leaky"
COLUMNS = (*PAIR_COLUMNS, "params", "max_spike_diff", "grad_rel_diff", "equal_to_fused", "load_avg", "target")

BETA, THRESHOLD = 0.2, 0.5


def _snntorch_leaky() -> torch.nn.Module:
    """``snntorch.Leaky`` with TactileSGNet's constants (snnTorch always detaches its reset)."""
    import snntorch

    from tactile_zoo.nn.surrogate import make_surrogate

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


@contextlib.contextmanager
def lif_path(path: str | None) -> Iterator[None]:
    """Run a block with ``TACTILE_ZOO_LIF_BACKEND=path`` (``None``: leave it as it is), restoring it after."""
    from tactile_zoo.nn.lif import KERNEL_ENV

    before = os.environ.get(KERNEL_ENV)
    if path is not None:
        os.environ[KERNEL_ENV] = path
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(KERNEL_ENV, None)
        else:
            os.environ[KERNEL_ENV] = before


def _fwd_bwd(forward: Callable[[Tensor], Tensor], x: Tensor, grad_out: Tensor, path: str | None = None
             ) -> Callable[[], tuple[Tensor, Tensor]]:
    leaf = x.detach().requires_grad_(True)

    def run() -> tuple[Tensor, Tensor]:
        leaf.grad = None
        with lif_path(path):
            spikes = forward(leaf)
            spikes.backward(grad_out)
        return spikes.detach(), leaf.grad

    return run


def _load() -> str:
    return "/".join(f"{v:.2f}" for v in os.getloadavg())


def _diffs(fast: tuple[Tensor, Tensor], slow: tuple[Tensor, Tensor]) -> tuple[float, float]:
    """Max |spike difference| and max |input-gradient difference| relative to the slow side's largest gradient."""
    spike = float((fast[0] - slow[0]).abs().max())
    return spike, float((fast[1] - slow[1]).abs().max() / slow[1].abs().max().clamp_min(1e-30))


def run(ctx: Context, batch: int = 32, steps: int = 250, nodes: int = 39, features: int = 64) -> Path:
    with ctx.threads_scope(1):
        return _run(ctx, batch, steps, nodes, features)


def _run(ctx: Context, batch: int, steps: int, nodes: int, features: int) -> Path:
    from tactile_zoo.nn.backend import lif_kernels
    from tactile_zoo.nn.lif import MultiStepLIF

    dev = ctx.device
    compiled_path = "numba" if dev.type == "cpu" and lif_kernels() is not None else None
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
        fns = {"compiled": _fwd_bwd(fused, x, grad_out, compiled_path), "fused": _fwd_bwd(fused, x, grad_out, "torch"),
               "naive": _fwd_bwd(naive_fwd, x, grad_out)}
        out = {name: fn() for name, fn in fns.items()}  # the warm-up (and the kernel's compilation or cache load)
        equal = all(torch.equal(a, b) for a, b in zip(out["compiled"], out["fused"]))
        load_before = _load()
        t = time_interleaved(fns, repeats, ctx, warmup=0)
        load = f"{load_before} -> {_load()}"
        timings[case] = t
        compiled_name = ("MultiStepLIF(backend='fused'), compiled kernel" if compiled_path else
                         "MultiStepLIF(backend='fused'), torch path (no compiled kernel here)")
        fused_name = "MultiStepLIF(backend='fused'), TACTILE_ZOO_LIF_BACKEND=torch"
        extra = dict(params=params, equal_to_fused=equal, load_avg=load,
                     note=f"spike rate {float(out['fused'][0].mean()):.3f}")
        for name, fast, slow, fast_desc, slow_desc, target in (
                (case, "compiled", "naive", compiled_name, naive_name, "compiled >= 10x faster, same spikes"),
                (f"{case}_fused", "fused", "naive", fused_name, naive_name, "fused >= 3x faster, same spikes"),
                (f"{case}_compiled_vs_fused", "compiled", "fused", compiled_name, fused_name,
                 "bit-identical (equal_to_fused)")):
            spike_diff, grad_diff = _diffs(out[fast], out[slow])
            rows.append(pair_row(name, fast_desc, slow_desc, t[fast], t[slow], max_spike_diff=spike_diff,
                                 grad_rel_diff=grad_diff, target=target, **extra))
        ctx.log(f"  {case}: compiled {t['compiled'].median * 1e3:.1f} ms, fused {t['fused'].median * 1e3:.1f} ms, "
                f"snntorch stepping {t['naive'].median * 1e3:.1f} ms -> compiled {rows[-3]['ratio']:.1f}x, fused "
                f"{rows[-2]['ratio']:.1f}x (compiled bit-identical to fused: {equal}; load {load})")
    if ctx.slow:
        leaky = _snntorch_leaky().to(dev)
        slow_fn = _fwd_bwd(lambda v: indexing_loop(leaky, v), x, grad_out)
        t_slow = time_interleaved({"naive": slow_fn}, 1, ctx, warmup=0)["naive"]
        fast = timings["snntorch_default"]["compiled"]
        rows.append(pair_row("x[t]_antipattern", "MultiStepLIF(backend='fused')",
                             "snntorch.Leaky loop reading x[t] (forbidden in the project)", fast, t_slow,
                             params=params, target="(reference only: why no loop may index x[t])",
                             note="naive timed once; fast timings of the snntorch_default case"))
        t_unbind = timings["snntorch_default"]["naive"]
        ctx.log(f"  x[t] anti-pattern: {t_slow.median:.2f} s, {t_slow.median / t_unbind.median:.1f}x the unbind loop")
    for row in rows:
        row["threads"] = 1
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE", "stepping_loop", "indexing_loop", "lif_path"]
