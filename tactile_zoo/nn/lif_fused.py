"""The fused LIF path in plain torch: the whole sequence's membrane updates in a few ATen calls per step, with a
hand-written backward (:class:`FusedLIF`). It runs wherever the compiled kernel (:mod:`.lif_compiled`) does not: on
the GPU, in float64, with surrogates the kernel does not mirror. :class:`~tactile_zoo.nn.lif.MultiStepLIF` chooses."""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from . import hugepages, storage_pool
from .surrogate import Surrogate, open_interval_mask

__all__ = ["FusedLIF", "run_forward", "next_up", "block_steps", "SAVE_LIMIT_BYTES", "BLOCK_BYTES"]

#: Sequences whose membrane history is at most this large keep it for the backward pass; longer ones keep one
#: checkpoint per block and recompute the block (two kernels per step) instead of allocating, and page-faulting in,
#: a history as large as the input.
SAVE_LIMIT_BYTES = 8 << 20
#: Bytes per block of steps that the vectorised parts of forward and backward process at once (stays in cache).
BLOCK_BYTES = 2 << 20


def block_steps(steps: int, step_bytes: int) -> int:
    """Steps per block of a ``steps``-long sequence whose step is ``step_bytes`` large: the blocks the fused loops
    process at once. The backward's gradient crosses a block boundary with another rounding than inside a block, so
    every kernel that reproduces this path's gradients uses the same blocks."""
    return max(1, min(steps, BLOCK_BYTES // max(1, step_bytes)))


@functools.lru_cache(maxsize=64)
def next_up(level: float, dtype: torch.dtype) -> float:
    """The smallest value of ``dtype`` above ``level``: ``u <= level`` is ``u < next_up(level)`` exactly."""
    return torch.nextafter(torch.tensor(level, dtype=dtype), torch.tensor(math.inf, dtype=dtype)).item()


def _advance(x_t: Tensor, prev: Tensor, out: Tensor, flag: Tensor, ones: Tensor, beta: float, threshold: float,
             th_up: float, subtract: bool) -> Tensor:
    """One LIF step from membrane ``prev`` into ``out``. ``flag`` is scratch for the previous step's reset, ``ones``
    an all-ones tensor of the step's shape (may be expanded), ``th_up = next_up(threshold)``."""
    if subtract:
        # R[t] = (U > U_thr) as 0/1 in one kernel; it misses U = +inf, whose next membrane is +inf either way
        open_interval_mask(prev, threshold, math.inf, out=flag, ones=ones)
        # one kernel for (beta * U) * 1 + I: exactly the rounding of snnTorch's beta * U + I; R * U_thr is exact, so
        # subtracting it rounds once, as snnTorch's does
        return torch.addcmul(x_t, prev, ones, value=beta, out=out).sub_(flag, alpha=threshold)
    # 1 - R[t] = (U <= U_thr) as 0/1 in one kernel (a comparison into a float tensor takes two)
    open_interval_mask(prev, -math.inf, th_up, out=flag, ones=ones)
    # one kernel for (beta * U) * (1 - R) + I: exactly the rounding of snnTorch's beta * ((1 - R) * U) + I
    return torch.addcmul(x_t, prev, flag, value=beta, out=out)


def run_forward(x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, for_backward: bool
                ) -> tuple[Tensor, Tensor, Tensor | None, tuple[int, bool, list[int]]]:
    """The forward time loop: spikes ``[T, ...]``, the last membrane, what the backward pass needs (the membrane
    history with ``mem0`` as row 0 when small, else the membrane entering each block) and the block layout."""
    steps, step_bytes = x.shape[0], max(1, mem0.numel() * x.element_size())
    block = block_steps(steps, step_bytes)
    keep_all = for_backward and (steps + 1) * step_bytes <= SAVE_LIMIT_BYTES
    # huge pages when large (its first write would page-fault), and for training a storage of an earlier call that
    # nothing refers to any more (storage_pool.reusable), whose pages are already mapped
    spikes = storage_pool.reusable(x.shape, x) if for_backward else hugepages.empty(x.shape, x)
    flag, ones = torch.empty_like(mem0), mem0.new_ones(()).expand_as(mem0)
    th_up = next_up(threshold, x.dtype)
    hist = x.new_empty((steps + 1 if keep_all else block + 1, *mem0.shape))  # row 0: the membrane entering
    hist[0] = mem0
    starts = list(range(0, steps, block))
    ckpts = x.new_empty((len(starts), *mem0.shape)) if for_backward and not keep_all else None
    xs = x.unbind(0)
    for j, t0 in enumerate(starts):
        t1 = min(t0 + block, steps)
        rows = hist[t0:t1 + 1] if keep_all else hist[:t1 - t0 + 1]  # (n + 1, ...) with the entering membrane
        if ckpts is not None:
            ckpts[j].copy_(rows[0])
        out = rows.unbind(0)
        prev = out[0]
        for k in range(t1 - t0):
            prev = _advance(xs[t0 + k], prev, out[k + 1], flag, ones, beta, threshold, th_up, subtract)
        # spikes U > U_thr as 0/1 in one kernel (only an infinite membrane would be missed)
        open_interval_mask(rows[1:], threshold, math.inf, out=spikes[t0:t1], ones=ones.expand_as(rows[1:]))
        if not keep_all and t1 < steps:
            rows[0].copy_(prev)  # the next block reuses the buffer, starting from this block's last membrane
    return spikes, prev.clone(), (hist if keep_all else ckpts), (block, keep_all, starts)


class FusedLIF(torch.autograd.Function):
    """The whole LIF time loop as one autograd node. Inputs ``x [T, ...]``, ``mem0 [...]``; outputs spikes
    ``[T, ...]`` and the last membrane potential ``[...]``.

    Forward: two kernels per step; spikes are thresholded a block of steps at a time. The membrane history (with
    ``mem0`` as row 0) is saved when small, else only the membrane entering each block. Backward, block by block
    from the end: recompute the block's membranes if needed, evaluate the surrogate derivatives and the step-to-step
    factors ``dU[t]/dU[t-1]`` for the whole block at once, then one multiply-add per step carries dL/dU back.
    Large temporaries are avoided on purpose: on CPU each fresh tensor as large as the input costs about as much in
    page faults as the whole loop. The two that cannot be avoided, the spikes and the input gradient, ask for
    transparent huge pages (:func:`tactile_zoo.nn.hugepages.empty`): at SGnet's shapes (78 MB each) that took the fused
    forward + backward from 2.1-2.2x to 3.3-3.9x the speed of stepping ``snntorch.Leaky`` (detached reset;
    benchmarks/lif.py on 1 thread, side by side, on a loaded 2-core machine where huge pages come on request).
    On CPU they also come from a pool of storages reused once nothing refers to them any more
    (:func:`tactile_zoo.nn.storage_pool.reusable`), whose pages are already mapped.
    """

    @staticmethod
    def forward(ctx, x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, detach_reset: bool,
                surrogate: Surrogate) -> tuple[Tensor, Tensor]:
        spikes, last, saved, layout = run_forward(x, mem0, beta, threshold, subtract, for_backward=True)
        ctx.save_for_backward(saved, x)
        ctx.cfg = (beta, threshold, subtract, detach_reset, surrogate, *layout)
        ctx.set_materialize_grads(False)  # an unused output needs no zero-filled gradient
        return spikes, last

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_spikes: Tensor | None, grad_mem: Tensor | None) -> tuple[Tensor | None, ...]:
        saved, x = ctx.saved_tensors
        beta, th, subtract, detach_reset, surrogate, block, keep_all, starts = ctx.cfg
        steps, shape = x.shape[0], saved.shape[1:]
        grad = storage_pool.reusable((steps, *shape), saved)
        # per-block workspaces, reused (fresh temporaries this size would page-fault on every block)
        u_buf, sg_buf = saved.new_empty((block + 1, *shape)), saved.new_empty((block + 1, *shape))
        decay_buf = saved.new_empty((block, *shape))
        ones, th_up = saved.new_ones(()).expand(block + 1, *shape), next_up(th, saved.dtype)
        if not keep_all:
            rows_buf = saved.new_empty((block + 1, *shape))
            xs = x.unbind(0)
        carry = grad_mem  # dL/dU[t1 - 1], the gradient reaching the end of the current block from later blocks
        carry_buf = saved.new_empty(shape)
        for j in range(len(starts) - 1, -1, -1):
            t0 = starts[j]
            n = min(t0 + block, steps) - t0
            if keep_all:
                rows = saved[t0:t0 + n + 1]
            else:  # recompute the block's membranes from its checkpoint
                rows = rows_buf[:n + 1]
                out = rows.unbind(0)
                prev = out[0].copy_(saved[j])
                for k in range(n):
                    # the step's reset flags land in decay_buf, where the zero reset's factors start from them
                    prev = _advance(xs[t0 + k], prev, out[k + 1], decay_buf[k], ones[0], beta, th, th_up, subtract)
            u = torch.sub(rows, th, out=u_buf[:n + 1])  # U - U_thr, exactly what snnTorch feeds its surrogate
            sg = surrogate.grad(u, out=sg_buf[:n + 1])  # dS/dU of U[t0-1 .. t0+n-1]
            # dU[t]/dU[t-1] for the block's steps, in units of beta where that helps: the step-to-step path
            if subtract:
                if detach_reset:
                    decay, scale = None, beta
                else:  # beta - U_thr * S'(U[t-1])
                    decay, scale = torch.mul(sg[:-1], -th, out=decay_buf[:n]).add_(beta), 1.0
            else:
                decay = decay_buf[:n]  # 1 - R[t] = (U[t-1] <= U_thr), left there by the recomputation
                if keep_all:
                    open_interval_mask(rows[:-1], -math.inf, th_up, out=decay, ones=ones[:n])
                if not detach_reset:  # beta * (1 - S[t-1]) * U[t-1] also depends on U[t-1] through S[t-1]
                    decay.addcmul_(rows[:-1], sg[:-1], value=-1.0)
                scale = beta
            # grad[t] = dL/dS[t] * S'(U[t]) + grad[t+1] * dU[t+1]/dU[t]
            g = grad[t0:t0 + n]
            if grad_spikes is None:
                g.zero_()
            else:
                torch.mul(grad_spikes[t0:t0 + n], sg[1:], out=g)
            if carry is not None:
                g[-1].add_(carry)
            rows_g = g.unbind(0)
            for k in range(n - 2, -1, -1):
                if decay is None:
                    rows_g[k].add_(rows_g[k + 1], alpha=scale)
                else:
                    rows_g[k].addcmul_(rows_g[k + 1], decay[k + 1], value=scale)
            if decay is None:
                carry = torch.mul(rows_g[0], scale, out=carry_buf)
            else:
                carry = torch.mul(rows_g[0], decay[0], out=carry_buf).mul_(scale)
        return grad, (carry if ctx.needs_input_grad[1] else None), None, None, None, None, None


