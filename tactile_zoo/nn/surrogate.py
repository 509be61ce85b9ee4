"""Surrogate gradients for spiking neurons: the Heaviside spike forward, a smooth stand-in for dS/dU backward.

Each :class:`Surrogate` provides both things the LIF backends need: ``spike_fn``, the ``snntorch.surrogate``
callable ``snntorch.Leaky(spike_grad=...)`` takes (spike ``U - U_thr > 0`` forward, its surrogate backward), and
``grad(u)``, the derivative dS/dU at ``u = U - U_thr`` as a tensor, which the fused LIF evaluates for a whole block
of steps in one go. Kinds (``u = U - U_thr``):

    rect      dS/dU = 1 where |u| < width / 2, else 0    TactileSGNet's rectangle (width 1: |U - 0.5| < 0.5 at
                                                         U_thr 0.5); snnTorch has none, so spike_fn wraps it in
                                                         snntorch.surrogate.custom_surrogate
    atan      dS/dU = (alpha / 2) / (1 + (pi alpha u / 2)^2)   snntorch.surrogate.atan(alpha), default alpha 2
    sigmoid   dS/dU = k sigmoid(k u) sigmoid(-k u)       snntorch.surrogate.sigmoid(slope=k), default k 25; snnTorch
                                                         writes it k e^{-ku} / (e^{-ku} + 1)^2, which overflows to NaN
                                                         for u < -88/k in float32; this form stays finite
    custom    any snnTorch surrogate callable; grad(u) asks it (autograd, unit output gradient) for dS/dU
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from ..errors import ConfigError

__all__ = ["Surrogate", "make_surrogate", "open_interval_mask"]

_hardtanh_backward = torch.ops.aten.hardtanh_backward.grad_input  # grad where lo < u < hi, else 0


def open_interval_mask(u: Tensor, lo: float, hi: float, out: Tensor | None = None, ones: Tensor | None = None
                       ) -> Tensor:
    """``lo < u < hi`` as 0/1 in ``u``'s dtype, in one kernel (a comparison into a float tensor takes two, and
    allocates). ``ones``: an all-ones tensor broadcastable to ``u`` (default: an expanded scalar)."""
    if out is None:
        out = torch.empty_like(u)
    if ones is None:
        ones = u.new_ones(()).expand_as(u)
    return _hardtanh_backward(ones, u, lo, hi, grad_input=out)


class Surrogate:
    """A surrogate gradient: the snnTorch spike function (``spike_fn``) and its derivative as a tensor (``grad``).

    Args:
        kind: ``"rect"``, ``"atan"``, ``"sigmoid"`` or ``"custom"`` (an snnTorch surrogate callable).
        param: rectangle width, atan alpha or sigmoid slope.
        fn: the callable for ``"custom"``.
    """

    def __init__(self, kind: str, param: float = 1.0, fn: Callable[[Tensor], Tensor] | None = None) -> None:
        self.kind, self.param, self._fn = kind, float(param), fn

    def grad(self, u: Tensor, out: Tensor | None = None) -> Tensor:
        """dS/dU at ``u = U - U_thr`` (elementwise), into ``out`` if given."""
        if out is None:
            out = torch.empty_like(u)
        if self.kind == "rect":  # |u| < width / 2, as a 0/1 mask in one kernel
            return open_interval_mask(u, -self.param / 2, self.param / 2, out=out)
        if self.kind == "atan":  # snntorch.surrogate.ATan.backward: alpha / 2 / (1 + (pi / 2 * alpha * u) ** 2)
            torch.mul(u, math.pi / 2 * self.param, out=out).pow_(2).add_(1)
            return torch.reciprocal(out, out=out).mul_(self.param / 2)
        if self.kind == "sigmoid":  # k sigmoid(k u) sigmoid(-k u): finite where snnTorch's form overflows
            ku = torch.mul(u, self.param, out=out)
            tail = torch.sigmoid(-ku)  # 1 - sigmoid(k u) without the cancellation near 1
            return torch.sigmoid(ku, out=out).mul_(tail).mul_(self.param)
        # an arbitrary snnTorch surrogate: its backward is elementwise, so one call with unit output grads gives dS/dU
        with torch.enable_grad():
            leaf = u.detach().requires_grad_(True)
            (g,) = torch.autograd.grad(self.spike_fn(leaf), leaf, torch.ones_like(leaf))
        return out.copy_(g)

    @property
    def spike_fn(self) -> Callable[[Tensor], Tensor]:
        """The callable ``snntorch.Leaky(spike_grad=...)`` takes."""
        if self._fn is None:
            from snntorch import surrogate

            if self.kind == "rect":
                half = self.param / 2
                self._fn = surrogate.custom_surrogate(lambda u, grad, spk: grad * (u.abs() < half).to(grad.dtype))
            elif self.kind == "atan":
                self._fn = surrogate.atan(alpha=self.param)
            else:
                self._fn = surrogate.sigmoid(slope=self.param)
        return self._fn

    def __repr__(self) -> str:
        return f"Surrogate({self.kind!r}, {self.param:g})" if self.kind != "custom" else f"Surrogate({self._fn!r})"


def make_surrogate(surrogate: str | Callable[[Tensor], Tensor], width: float = 1.0, alpha: float = 2.0,
                   slope: float = 25.0) -> Surrogate:
    """A :class:`Surrogate` from a name (``rect`` uses ``width``, ``atan`` ``alpha``, ``sigmoid`` ``slope``) or an
    snnTorch surrogate callable."""
    if callable(surrogate) and not isinstance(surrogate, str):
        return Surrogate("custom", fn=surrogate)
    params = {"rect": width, "atan": alpha, "sigmoid": slope}
    if surrogate not in params:
        raise ConfigError(f"surrogate must be one of {sorted(params)} or an snntorch.surrogate callable, "
                          f"got {surrogate!r}")
    if not params[surrogate] > 0:
        raise ConfigError(f"the {surrogate} surrogate needs a positive parameter, got {params[surrogate]}")
    return Surrogate(surrogate, params[surrogate])
