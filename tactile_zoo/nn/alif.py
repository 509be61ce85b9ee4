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

Two backends compute a step (``backend``): ``"torch"``, the rule as a chain of torch operations (about 15 autograd
nodes a step), and ``"compiled"``, one numba kernel forward and one backward (:mod:`tactile_zoo.nn._kernels.alif`)
on CPU float32 tensors. The compiled forward rounds after each operation of the chain, so its spikes, membranes and
traces are bit-identical to the torch path's; its gradients agree up to float32 rounding (the sums over neurons of
the time constants' gradients are taken in float64). Elsewhere (a GPU, float64, a tracer) ``"compiled"`` runs the
torch chain.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
import torch
from torch import Tensor, nn

from .backend import ALIFBackend, alif_kernels_for, resolve

__all__ = ["AdaptiveLIF", "gaussian_spike"]


def _gaussian_density(u: Tensor, width: float) -> Tensor:
    """The normal density of width ``width`` at ``u``: the surrogate's derivative before its scale."""
    return torch.exp(-(u ** 2) / (2 * width ** 2)) / math.sqrt(2 * math.pi) / width


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
        return grad * _gaussian_density(u, ctx.width) * ctx.scale, None, None


def gaussian_spike(u: Tensor, width: float = 0.5, scale: float = 0.5) -> Tensor:
    """Spikes ``u > 0`` as 0/1 in ``u``'s dtype, with the Gaussian surrogate gradient (module docstring). Without a
    gradient to compute, plain tensor ops (what TorchScript and ONNX export can trace)."""
    if torch.is_grad_enabled() and u.requires_grad:
        return _GaussianSpike.apply(u, width, scale)
    return u.gt(0).to(u.dtype)




class _CompiledStep(torch.autograd.Function):
    """One ALIF step by the compiled kernels: ``(current, mem, spikes, trace, alpha, rho, noise) -> (mem, spikes,
    trace)``, with ``alpha`` and ``rho`` the per-neuron decay factors (their gradients flow on to the time
    constants through torch's ``exp``)."""

    @staticmethod
    def forward(ctx, current: Tensor, mem: Tensor, spikes: Tensor, trace: Tensor, alpha: Tensor,  # type: ignore[override]
                rho: Tensor, noise: Tensor | None, threshold: float, beta: float, width: float, scale: float,
                kernels: ModuleType) -> tuple[Tensor, Tensor, Tensor]:
        inputs = (current, mem, spikes, trace)
        shape = torch.broadcast_shapes(*(t.shape for t in inputs))
        size = shape[-1]
        rows = math.prod(shape[:-1])
        # (B, N, S) -> (B * N, S): every state tensor contiguous, the start's (N, 1) trace spread over the batch
        flat = [t.detach().expand(shape).contiguous().view(rows, size) for t in inputs]
        noise_flat = (noise.detach().expand(shape).contiguous().view(rows, size) if noise is not None
                      else current.new_empty((0, size)))
        factors = [f.detach().contiguous() for f in (alpha, 1 - alpha, rho, 1 - rho)]  # torch's roundings of 1 - x
        out = torch.empty((5, rows, size), dtype=current.dtype)  # mem, spikes, trace, u, drive
        kernels.alif_forward(flat[0].numpy(), noise_flat.numpy(), *(t.numpy() for t in flat[1:]),
                             *(f.numpy() for f in factors), np.float32(threshold), np.float32(beta),
                             *(o.numpy() for o in out))
        ctx.save_for_backward(out[3], out[1], out[2], flat[1], out[4], flat[2], flat[3], *factors)
        ctx.meta = (shape, [t.shape for t in inputs], threshold, beta, width, scale, kernels)
        return out[0].view(shape), out[1].view(shape), out[2].view(shape)

    @staticmethod
    def backward(ctx, g_mem: Tensor, g_spikes: Tensor, g_trace: Tensor  # type: ignore[override]
                 ) -> tuple[Tensor | None, ...]:
        u, spikes, trace, mem, drive, spikes_in, trace_in, alpha, one_alpha, rho, one_rho = ctx.saved_tensors
        shape, shapes, threshold, beta, width, scale, kernels = ctx.meta
        rows, size = u.shape
        grads = [g.contiguous().view(rows, size) for g in (g_mem, g_spikes, g_trace)]
        surrogate = _gaussian_density(u, width) * scale  # torch's vectorised exp: several times a scalar one
        out = torch.empty((4, rows, size), dtype=u.dtype)  # current, mem, spikes, trace
        sums = torch.zeros((2, size), dtype=torch.float64)  # alpha, rho
        kernels.alif_backward(*(g.numpy() for g in grads), surrogate.numpy(), spikes.numpy(), trace.numpy(),
                              mem.numpy(), drive.numpy(), spikes_in.numpy(), trace_in.numpy(), alpha.numpy(),
                              one_alpha.numpy(), rho.numpy(), one_rho.numpy(), np.float32(threshold),
                              np.float32(beta), *(o.numpy() for o in out), sums[0].numpy(), sums[1].numpy())
        # a broadcast input (the start's (N, 1) trace) gets its gradient summed back to its shape
        g_in = [g.view(shape).sum_to_size(s) for g, s in zip(out, shapes)]
        return (*g_in, sums[0].to(u.dtype), sums[1].to(u.dtype), None, None, None, None, None, None)


class AdaptiveLIF(nn.Module):
    """A population of ``size`` ALIF neurons (update rule in the module docstring), shared by every column it runs in:
    one learned ``tau_m`` and ``tau_adp`` per neuron, broadcast over the leading dimensions of the state.

    Args:
        size: neurons in the population (the last dimension of every state tensor).
        tau_m_init, tau_adp_init: means of the normal initialisations (standard deviation 1) of the time constants.
        threshold: the baseline threshold ``theta_0``.
        beta: the adaptation strength.
        surrogate_width, surrogate_scale: the Gaussian surrogate's width and scale.
        backend: ``"torch"`` or ``"compiled"`` (module docstring; the multi-barrel SNN's ``alif_backend``).

    Shapes:
        :meth:`step`: current, membrane, spikes, trace ``(*, size)`` (the trace may be any shape broadcastable to it)
        and noise ``(*, size)`` or ``None`` -> new membrane, spikes and trace ``(*, size)``.
    """

    def __init__(self, size: int, tau_m_init: float, tau_adp_init: float, threshold: float = 0.1, beta: float = 1.8,
                 surrogate_width: float = 0.5, surrogate_scale: float = 0.5, backend: str = "torch") -> None:
        super().__init__()
        self.backend = resolve(ALIFBackend, backend, "backend", "AdaptiveLIF")
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
        if self.backend is ALIFBackend.COMPILED:
            state = (current, mem, spikes, trace) if noise is None else (current, mem, spikes, trace, noise)
            kernels = alif_kernels_for(*state, alpha, rho)
            if kernels is not None:
                return _CompiledStep.apply(current, mem, spikes, trace, alpha, rho, noise, self.threshold, self.beta,
                                           self.surrogate_width, self.surrogate_scale, kernels)
        trace = rho * trace + (1 - rho) * spikes
        theta = self.threshold + self.beta * trace
        drive = current if noise is None else current + noise
        mem = mem * alpha + (1 - alpha) * drive
        spikes = gaussian_spike(mem - theta, self.surrogate_width, self.surrogate_scale)
        return mem - theta * spikes, spikes, trace

    def extra_repr(self) -> str:
        return f"{self.size}, threshold={self.threshold}, beta={self.beta}, backend={self.backend.value!r}"
