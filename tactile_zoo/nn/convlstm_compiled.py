"""ConvLSTM's ``"compiled"`` recurrence backend: the fused time loop of :mod:`tactile_zoo.nn.convlstm` with each step's
gather, gate arithmetic and scatter-add in numba kernels (:mod:`tactile_zoo.nn._kernels.convlstm`) around one
``addmm``. Opt-in (``ConvLSTMCell(backend="compiled")``): its sigmoid and tanh are the kernel module's own, so results
differ from the fused loop's in the last bits. Kept apart from the layer so that the layer file stays one operator.
"""
from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from . import backend
from .storage_pool import reusable, reusable_like

__all__ = ["CompiledRecurrence", "compiled_applies", "compiled_recurrence"]


def compiled_applies(*tensors: Tensor) -> bool:
    """Whether the ``"compiled"`` backend's kernels can run on these tensors: plain CPU tensors (a tracer's fake
    tensors hold no memory numba could read; traced graphs record the fused loop, which computes the same numbers),
    all float32 or all float64. Elsewhere, the GPU included, the backend runs the ``"fused"`` loop."""
    if torch.compiler.is_compiling() or torch.jit.is_tracing():
        return False
    dtype = tensors[0].dtype
    return dtype in (torch.float32, torch.float64) and all(
        type(v) in (Tensor, nn.Parameter) and v.device.type == "cpu" and v.dtype == dtype for v in tensors)


def compiled_recurrence(xz: Tensor, weight: Tensor, h0: Tensor, c0: Tensor, grid: tuple[int, int, int], keep: bool
                         ) -> tuple[Tensor, Tensor, tuple[Tensor, Tensor, Tensor] | None]:
    """The fused loop (``tactile_zoo.nn.convlstm._recurrence``) with the step's element-wise work in one compiled
    call: ``xz (T, 4h, N)``, ``h0, c0 (h, N)``, ``grid = (B, H, W)`` -> ``hbuf (T+1, h, N)`` (``hbuf[0]`` holds
    ``h0``) and ``c_T (h, N)``, plus with ``keep`` the activated gates, cell states and ``tanh(c)`` of every step.

    A step is one ``addmm`` (the kernel times the im2col matrix of ``h_{t-1}``, added to ``xz_t``) and one call of
    ``forward_step`` of :mod:`tactile_zoo.nn._kernels.convlstm`, which activates the gates, updates ``c`` and ``h`` and
    writes the im2col matrix of ``h_t`` for the next step.
    """
    kern = backend.convlstm_kernels()
    steps, four_h, cols_n = xz.shape
    hid, k = four_h // 4, weight.shape[-1]
    kernel = weight.detach().reshape(four_h, -1)  # (4h, h*k*k)
    xz = xz.detach()
    hbuf = reusable((steps + 1, hid, cols_n), xz)  # pooled storages (contiguous, as before): no page faults
    hbuf[0] = h0
    cols = reusable((kernel.shape[1], cols_n), xz)  # reused: the kernels write every position of it each step
    if keep:
        gates, cs, tcs = (reusable(shape, xz) for shape in (xz.shape, (steps + 1, hid, cols_n), (steps, hid, cols_n)))
        cs[0] = c0
        gates_np, cs_np, tcs_np = gates.numpy(), cs.numpy(), tcs.numpy()
    else:
        gates, c, tc = xz.new_empty(four_h, cols_n), c0.detach().clone(), xz.new_empty(hid, cols_n)
        gates_np, c_np, tc_np = gates.numpy(), c.numpy(), tc.numpy()
    hbuf_np, cols_np = hbuf.numpy(), cols.numpy()
    for j in range(hid):
        kern.im2col(hbuf_np[0, j], cols_np, j, *grid, k)
    for t in range(steps):
        z = gates[t] if keep else gates
        torch.addmm(xz[t], kernel, cols, out=z)  # (4h, N) pre-activations
        if keep:
            kern.forward_step(gates_np[t], cs_np[t], cs_np[t + 1], tcs_np[t], hbuf_np[t + 1], cols_np,
                              t + 1 < steps, *grid, k)
        else:
            kern.forward_step(gates_np, c_np, c_np, tc_np, hbuf_np[t + 1], cols_np, t + 1 < steps, *grid, k)
    c_last = cs[steps] if keep else c
    return hbuf, c_last, ((gates, cs, tcs) if keep else None)


class CompiledRecurrence(torch.autograd.Function):
    """The fused autograd Function (``tactile_zoo.nn.convlstm._FusedRecurrence``) with the per-step element-wise
    work, gather and scatter-add in numba kernels: ``(xz (T, 4h, N), W_h (4h, h, k, k), h0, c0 (h, N), grid (B, H,
    W)) -> (hs (T, h, N), c_T (h, N))``, CPU only, float32 or float64; ``h0`` and ``c0`` contiguous, ``xz`` any layout
    (its gradient comes back in the same strides)."""

    @staticmethod
    def forward(ctx: Any, xz: Tensor, weight: Tensor, h0: Tensor, c0: Tensor, grid: tuple[int, int, int]
                ) -> tuple[Tensor, Tensor]:
        hbuf, c_last, saved = compiled_recurrence(xz, weight, h0, c0, grid, keep=True)
        ctx.grid, ctx.xz_layout = grid, torch.empty_like(xz, device="meta")  # xz's shape and strides, no memory
        ctx.save_for_backward(weight, hbuf, *saved)
        return hbuf[1:], c_last

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, d_hs: Tensor, d_c_last: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, None]:
        kern = backend.convlstm_kernels()
        weight, hbuf, gates, cs, tcs = ctx.saved_tensors
        grid = ctx.grid
        steps, four_h, cols_n = gates.shape
        hid, k = four_h // 4, weight.shape[-1]
        kernel = weight.detach().reshape(four_h, -1)  # (4h, h*k*k)
        d_kernel = torch.zeros_like(kernel)
        d_z = gates.new_empty(four_h, cols_n)  # one step's gradient of the pre-activations, channel-major
        d_xz = reusable_like(ctx.xz_layout, gates)  # all steps' gradients, in xz's layout (the convolution's)
        d_c = d_c_last.detach().clone(memory_format=torch.contiguous_format)
        # a zero gradient arrives as an expanded zero (not writable, not contiguous): give the kernel real zeros
        d_hs = d_hs.detach().contiguous()
        cols, d_cols = reusable((kernel.shape[1], cols_n), gates), reusable((kernel.shape[1], cols_n), gates)
        dh = gates.new_empty(cols_n)
        d_hs_np, d_c_np, d_z_np, dh_np = d_hs.numpy(), d_c.numpy(), d_z.numpy(), dh.numpy()
        gates_np, cs_np, tcs_np, hbuf_np = gates.numpy(), cs.numpy(), tcs.numpy(), hbuf.numpy()
        cols_np, d_cols_np = cols.numpy(), d_cols.numpy()
        for t in reversed(range(steps)):
            # gate derivatives of step t (dL/dh_t summed from step t+1's im2col gradient), im2col of h_{t-1}
            kern.backward_step(gates_np[t], cs_np[t], tcs_np[t], d_hs_np[t], d_cols_np, t + 1 < steps, d_c_np,
                               d_z_np, dh_np, hbuf_np[t], cols_np, True, *grid, k)
            d_kernel.addmm_(d_z, cols.t())
            torch.mm(kernel.t(), d_z, out=d_cols)  # (h*k*k, N): gradient of h_{t-1}'s im2col matrix
            d_xz[t] = d_z  # a transpose of one step, in cache: much cheaper than one over all steps afterwards
        d_h0 = gates.new_zeros(hid, cols_n)
        d_h0_np = d_h0.numpy()
        for j in range(hid):
            kern.col2im(d_cols_np, d_h0_np[j], j, *grid, k)
        return d_xz, d_kernel.view_as(weight), d_h0, d_c, None
