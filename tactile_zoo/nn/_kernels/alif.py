"""One ALIF step of a population, forward and backward, compiled by numba (serial: the multi-barrel SNN calls it
280 times a pass on blocks of about 150k neurons, one torch thread per cell).

Loaded lazily (:func:`tactile_zoo.nn.backend.alif_kernels`) and run by :class:`tactile_zoo.nn.alif.AdaptiveLIF` with
``backend="compiled"``; nothing here is public. The forward reproduces the torch path of
:meth:`~tactile_zoo.nn.alif.AdaptiveLIF.step` operation for operation in float32, so its spikes, membranes and traces
are bit-identical to it: every operation there is one ATen ``mul``, ``add`` or ``sub`` (each rounded once; ATen's
``sub`` and ``rsub`` are an FMA with -1, which is exact), so the kernel rounds after each of them too and contracts
nothing (numba does not let LLVM fuse a multiply and an add without ``fastmath``, not used here). The time-constant
factors (``alpha``, ``1 - alpha``, ``rho``, ``1 - rho``) are computed by the caller in torch, per neuron.

The backward takes the surrogate's derivative from the caller (torch's vectorised ``exp`` is several times faster than
a scalar one here) and sums the time-constant gradients over the rows in float64: the gradients are those of the
torch path up to float32 rounding, not bit for bit (tests/nn/test_alif.py holds them within 1e-5 of the largest).

Arrays are ``(R, S)``: R rows (batch x taxels) of S neurons, contiguous float32; the per-neuron factors are ``(S,)``.
"""

from __future__ import annotations

import numpy as np

from .jit import jit

__all__ = ["alif_forward", "alif_backward"]


@jit
def alif_forward(cur: np.ndarray, noise: np.ndarray, mem: np.ndarray, spikes: np.ndarray, trace: np.ndarray,
                 alpha: np.ndarray, one_alpha: np.ndarray, rho: np.ndarray, one_rho: np.ndarray, threshold: np.float32,
                 beta: np.float32, out_mem: np.ndarray, out_spikes: np.ndarray, out_trace: np.ndarray,
                 out_u: np.ndarray, out_drive: np.ndarray) -> None:
    """The step into ``out_*``: ``out_u`` keeps ``U_t - theta_t`` before the reset and ``out_drive`` the input
    ``I_t + eps_t`` for the backward; ``noise`` has 0 rows when there is none."""
    zero, one = np.float32(0.0), np.float32(1.0)
    if noise.shape[0] > 0:
        for r in range(cur.shape[0]):
            for k in range(cur.shape[1]):
                out_drive[r, k] = cur[r, k] + noise[r, k]
    else:
        out_drive[:, :] = cur
    for r in range(cur.shape[0]):
        for k in range(cur.shape[1]):
            b = rho[k] * trace[r, k] + one_rho[k] * spikes[r, k]
            theta = threshold + beta * b
            drive = out_drive[r, k]
            m = mem[r, k] * alpha[k] + one_alpha[k] * drive
            u = m - theta
            s = one if u > zero else zero
            out_mem[r, k] = m - theta * s
            out_spikes[r, k] = s
            out_trace[r, k] = b
            out_u[r, k] = u


@jit
def alif_backward(g_mem: np.ndarray, g_spikes: np.ndarray, g_trace: np.ndarray, surrogate: np.ndarray,
                  spikes: np.ndarray, trace: np.ndarray, mem: np.ndarray, drive: np.ndarray,
                  spikes_in: np.ndarray, trace_in: np.ndarray, alpha: np.ndarray, one_alpha: np.ndarray,
                  rho: np.ndarray, one_rho: np.ndarray, threshold: np.float32, beta: np.float32,
                  g_cur: np.ndarray, g_mem_in: np.ndarray, g_spikes_in: np.ndarray, g_trace_in: np.ndarray,
                  g_alpha: np.ndarray, g_rho: np.ndarray) -> None:
    """Gradients of one step. Inputs: the output gradients (``g_mem``, ``g_spikes``, ``g_trace``; autograd passes
    zeros for an unused one), the surrogate derivative at the forward's ``u``, its spikes and trace out, and its
    membrane, drive, spikes and trace in. Writes the gradients of the input current (= of the drive), membrane, spikes
    and trace in, and adds the float64 row sums of ``alpha``'s and ``rho``'s gradients into ``g_alpha``, ``g_rho``."""
    for r in range(spikes.shape[0]):
        for k in range(spikes.shape[1]):
            gm = g_mem[r, k]
            theta = threshold + beta * trace[r, k]
            # out_mem = m - theta * s and s = H(u), u = m - theta
            g_u = (g_spikes[r, k] - gm * theta) * surrogate[r, k]
            g_m = gm + g_u
            g_theta = -gm * spikes[r, k] - g_u
            g_b = g_trace[r, k] + beta * g_theta
            g_mem_in[r, k] = alpha[k] * g_m
            g_cur[r, k] = one_alpha[k] * g_m
            g_spikes_in[r, k] = one_rho[k] * g_b
            g_trace_in[r, k] = rho[k] * g_b
            # d/d alpha of m = mem * alpha + (1 - alpha) * drive; d/d rho of b = rho * trace + (1 - rho) * spikes
            g_alpha[k] += np.float64(g_m) * (np.float64(mem[r, k]) - np.float64(drive[r, k]))
            g_rho[k] += np.float64(g_b) * (np.float64(trace_in[r, k]) - np.float64(spikes_in[r, k]))
