"""Adaptive leaky integrate-and-fire (ALIF) neurons with a per-neuron learned membrane and adaptation time constant,
as the multi-barrel SNN uses them (Zhu, Hu, Zhou, Du, Li, "Localist Topographic Expert Routing: A Barrel
Cortex-Inspired Modular Network for Sensorimotor Processing", NeurIPS 2025; code: github.com/fun0515/MultiBarrelModel).

Update rule for one step (``dt = 1``, membrane resistance 1), per neuron, ``S_{t-1}`` the previous step's spikes::

    alpha = exp(-1 / tau_m),   rho = exp(-1 / tau_adp)
    b_t     = rho * b_{t-1} + (1 - rho) * S_{t-1}           adaptation trace
    theta_t = theta_0 + beta * b_t                           adaptive threshold
    U_t     = alpha * U_{t-1} + (1 - alpha) * (I_t + eps_t)  eps_t ~ N(0, noise_std^2) when noise is on
    S_t     = H(U_t - theta_t)
    U_t     = U_t - theta_t * S_t                            soft reset by the threshold

Surrogate gradient of ``H``: a Gaussian, ``dS/du = scale * exp(-u^2 / (2 width^2)) / (sqrt(2 pi) width)`` (the
source's width 0.5 and scale 0.5). The time constants are trained; nothing keeps them positive (the source does not).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["AdaptiveLIF", "gaussian_spike"]


class _GaussianSpike(torch.autograd.Function):
    """``H(u)`` forward (``u > 0``), a scaled Gaussian density backward."""

    @staticmethod
    def forward(ctx, u: Tensor, width: float, scale: float) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(u)
        ctx.width, ctx.scale = width, scale
        return u.gt(0).to(u.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None, None]:  # type: ignore[override]
        (u,) = ctx.saved_tensors
        density = torch.exp(-(u ** 2) / (2 * ctx.width ** 2)) / math.sqrt(2 * math.pi) / ctx.width
        return grad * density * ctx.scale, None, None


def gaussian_spike(u: Tensor, width: float = 0.5, scale: float = 0.5) -> Tensor:
    """Spikes ``u > 0`` as 0/1 in ``u``'s dtype, with the Gaussian surrogate gradient (module docstring). Without a
    gradient to compute, plain tensor ops (what TorchScript and ONNX export can trace)."""
    if torch.is_grad_enabled() and u.requires_grad:
        return _GaussianSpike.apply(u, width, scale)
    return u.gt(0).to(u.dtype)


class AdaptiveLIF(nn.Module):
    """A population of ``size`` ALIF neurons (update rule in the module docstring), shared by every column it runs in:
    one learned ``tau_m`` and ``tau_adp`` per neuron, broadcast over the leading dimensions of the state.

    Args:
        size: neurons in the population (the last dimension of every state tensor).
        tau_m_init, tau_adp_init: means of the normal initialisations (standard deviation 1) of the time constants.
        threshold: the baseline threshold ``theta_0``.
        beta: the adaptation strength.
        surrogate_width, surrogate_scale: the Gaussian surrogate's width and scale.

    Shapes:
        :meth:`step`: current, membrane, spikes, trace ``(*, size)`` (the trace may be any shape broadcastable to it)
        and noise ``(*, size)`` or ``None`` -> new membrane, spikes and trace ``(*, size)``.
    """

    def __init__(self, size: int, tau_m_init: float, tau_adp_init: float, threshold: float = 0.1, beta: float = 1.8,
                 surrogate_width: float = 0.5, surrogate_scale: float = 0.5) -> None:
        super().__init__()
        self.size, self.threshold, self.beta = size, float(threshold), float(beta)
        self.surrogate_width, self.surrogate_scale = float(surrogate_width), float(surrogate_scale)
        self.tau_adp = nn.Parameter(torch.empty(size))
        self.tau_m = nn.Parameter(torch.empty(size))
        self.tau_m_init, self.tau_adp_init = float(tau_m_init), float(tau_adp_init)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        nn.init.normal_(self.tau_adp, mean=self.tau_adp_init, std=1.0)  # the source's order: adaptation first
        nn.init.normal_(self.tau_m, mean=self.tau_m_init, std=1.0)

    def step(self, current: Tensor, mem: Tensor, spikes: Tensor, trace: Tensor, noise: Tensor | None = None
             ) -> tuple[Tensor, Tensor, Tensor]:
        """One step of the update rule: ``(mem, spikes, trace)`` after input ``current`` (and ``noise``, if any)."""
        alpha = torch.exp(-1.0 / self.tau_m)
        rho = torch.exp(-1.0 / self.tau_adp)
        trace = rho * trace + (1 - rho) * spikes
        theta = self.threshold + self.beta * trace
        drive = current if noise is None else current + noise
        mem = mem * alpha + (1 - alpha) * drive
        spikes = gaussian_spike(mem - theta, self.surrogate_width, self.surrogate_scale)
        return mem - theta * spikes, spikes, trace

    def extra_repr(self) -> str:
        return f"{self.size}, threshold={self.threshold}, beta={self.beta}"
