"""Whole-sequence LIF kernels for CPU, compiled by numba: one call runs the forward (or backward) time loop of every
neuron, in parallel over blocks of neurons.

Loaded lazily (:func:`tactile_zoo.nn.backend.lif_kernels`; numba's import and first compilation cost seconds) and run
by :mod:`tactile_zoo.nn.lif_compiled`; nothing here is public. The kernels reproduce the fused torch path of
:class:`tactile_zoo.nn.lif_fused.FusedLIF` operation for operation in float32, so that spikes, membranes and
gradients are bit-identical to it. What that takes, from the ATen CPU kernels the fused path calls (checked on
x86-64 builds, AVX2 and AVX512 capability; tests/nn/test_lif.py compares):

- ``a.add_(b, alpha=c)`` is ``fma(b, c, a)`` and ``a.addcmul_(b, d, value=c)`` is ``fma(c * b, d, a)``: ATen's
  vector code calls ``fmadd`` and GCC contracts its scalar tails into the same FMA. Plain ``mul``/``add``/``sub``
  calls round once each. :func:`~.jit.fma` emits ``llvm.fma`` where torch fuses; nothing else is contracted, because
  numba does not allow LLVM to fuse separate multiplies and adds without ``fastmath`` (not used here).
- Python scalars are rounded to float32 before use; masks are ``lo < u < hi`` (so ``-inf`` or ``+inf`` never pass).
- The fused backward carries the gradient between blocks of ``block`` steps as ``(g * decay) * scale`` added to the
  next row, and inside a block as one FMA per step; the two round differently, so the kernel takes ``block`` and
  does the same at the same steps.
- Denormals: the engine trains under flush-to-zero / denormals-are-zero (``torch.set_flush_denormal``), which sets
  the calling thread's MXCSR only. Each parallel chunk runs under the caller's MXCSR (read and set with the
  ``stmxcsr``/``ldmxcsr`` intrinsics) and restores its own afterwards.

Memory order: ``x`` is ``(T, N)`` with ``N`` (batch x neurons) contiguous, so each step of a block of neurons is
one contiguous run. A block of :data:`CHUNK` neurons (32 KB a row) is long enough for the hardware prefetchers and
short enough that the rows the backward works on stay in a core's L2. The backward needs the membranes in reverse
order; storing them all would be as large as ``x``, and recomputing a whole block's history at once does not fit in
L2 at this width. So the forward writes the membrane every :data:`EVERY` steps (a checkpoint, 1/16 of ``x``), and the
backward recomputes one :data:`EVERY`-step window at a time from its checkpoint, then sweeps that window in reverse.
The arithmetic per element is unchanged, so the results stay bit-identical.

The compiled code is cached on disk where it can be (:func:`~.jit.jit`).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .jit import CSR_MODE, fma, get_csr, jit, serial_copy, set_csr

__all__ = ["lif_forward", "lif_backward", "lif_forward_serial", "lif_backward_serial", "RECT", "ATAN", "CHUNK",
           "FORWARD_CHUNK", "EVERY", "SERIAL_BELOW", "checkpoint_rows", "PLAIN", "SUB", "ZERO_DETACHED", "ZERO",
           "surrogate_row", "carry_row", "advance_row", "step_row", "zero_reset_decay_row"]

#: Surrogate kinds the kernels evaluate themselves (others stay on the torch path).
RECT, ATAN = 0, 1
#: Neurons per work item: each step reads a contiguous run of CHUNK floats (32 KB) from every (T, N) array, and the
#: backward's (EVERY + 1, CHUNK) window of membranes (544 KB) stays in L2 with its working rows.
CHUNK = 8192
#: Most neurons per work item of the forward, which sweeps whole rows step by step (time-major): its two membrane
#: rows (512 KB each at most) stay in L2 while x and the spikes stream through. SGnet's 32 x 2496 is one row.
FORWARD_CHUNK = 1 << 17
#: Steps between two membrane checkpoints of the forward, which the backward recomputes its windows from.
EVERY = 16
#: Sequences with fewer elements (steps x neurons) than this run the serial builds even with several threads.
SERIAL_BELOW = 1 << 16
PLAIN, SUB, ZERO_DETACHED, ZERO = 0, 1, 2, 3  # how dU[t]/dU[t-1] is formed (lif_backward's reset modes)


# Row helpers (the fused kernels of .graph_lif call them too): each is one loop over a chunk's neurons with no branch
# left inside it (the mode tests sit outside), so that LLVM vectorises it; the conditional expressions become selects.

@jit
def surrogate_row(mem: np.ndarray, thr: np.float32, kind: int, lo: np.float32, hi: np.float32, c1: np.float32,
                   c2: np.float32, out: np.ndarray) -> None:
    """``out = S'(mem - thr)`` as :meth:`tactile_zoo.nn.surrogate.Surrogate.grad` computes it in float32: the
    ``rect`` mask ``lo < u < hi`` (``hardtanh_backward``), or ``atan``'s ``mul``, ``pow_(2)``, ``add_(1)``,
    ``reciprocal``, ``mul_`` (each rounded once)."""
    one, zero = np.float32(1.0), np.float32(0.0)
    if kind == RECT:
        for j in range(out.shape[0]):
            u = mem[j] - thr
            out[j] = one if (lo < u) & (u < hi) else zero
    else:
        for j in range(out.shape[0]):
            t = (mem[j] - thr) * c1
            t = t * t
            out[j] = (one / (t + one)) * c2


@jit
def carry_row(gs: np.ndarray, sg: np.ndarray, decay: np.ndarray, g_next: np.ndarray, g: np.ndarray,
               u_prev: np.ndarray, beta: np.float32, scale: np.float32, thr: np.float32, th_up: np.float32,
               mode: int, kind: int, lo: np.float32, hi: np.float32, c1: np.float32, c2: np.float32) -> None:
    """An ordinary step of the backward (grad_spikes given, no block boundary) in one pass over the row instead of
    four: ``g = gs * S'(U[s])`` plus the carry of ``g_next`` as in :func:`lif_backward`, then ``sg = S'(U[s-1])``
    and ``decay = dU[s]/dU[s-1]`` from ``u_prev = U[s-1]`` -- per element the same operations in the same order.
    ``mode``: :data:`PLAIN` (detached subtractive reset), :data:`SUB`, :data:`ZERO_DETACHED`, :data:`ZERO`."""
    one, zero, ninf, nthr = np.float32(1.0), np.float32(0.0), np.float32(-np.inf), -thr
    for j in range(g.shape[0]):
        if mode == PLAIN:
            g[j] = fma(g_next[j], beta, gs[j] * sg[j])
        else:
            g[j] = fma(scale * g_next[j], decay[j], gs[j] * sg[j])
        m = u_prev[j]
        if kind == RECT:
            u = m - thr
            v = one if (lo < u) & (u < hi) else zero
        else:
            t = (m - thr) * c1
            t = t * t
            v = (one / (t + one)) * c2
        sg[j] = v
        if mode == SUB:
            decay[j] = v * nthr + beta
        elif mode == ZERO_DETACHED:
            decay[j] = one if (ninf < m) & (m < th_up) else zero
        elif mode == ZERO:
            decay[j] = fma(-m, v, one if (ninf < m) & (m < th_up) else zero)


@jit
def advance_row(prev: np.ndarray, x: np.ndarray, out: np.ndarray, beta: np.float32, thr: np.float32,
                 th_up: np.float32, subtract: bool, scale: np.float32, scaled: bool) -> None:
    """One membrane update of a row of neurons (``out`` may be ``prev``), as ``tactile_zoo.nn.lif_fused._advance``;
    with ``scaled`` the input is ``x * scale`` (one float32 multiply, as ``x * input_scale`` rounds it in torch)."""
    one, zero = np.float32(1.0), np.float32(0.0)
    if subtract:  # addcmul(x, U, ones, value=beta) then sub_(R, alpha=thr): fma(beta * U, 1, x), then fma(R, -thr, .)
        inf, nthr = np.float32(np.inf), -thr
        if scaled:
            for j in range(out.shape[0]):
                p = prev[j]
                r = one if (thr < p) & (p < inf) else zero
                out[j] = fma(r, nthr, fma(beta * p, one, x[j] * scale))
        else:
            for j in range(out.shape[0]):
                p = prev[j]
                r = one if (thr < p) & (p < inf) else zero  # R = (U > thr)
                out[j] = fma(r, nthr, fma(beta * p, one, x[j]))
    else:  # addcmul(x, U, 1 - R, value=beta): fma(beta * U, 1 - R, x)
        ninf = np.float32(-np.inf)
        if scaled:
            for j in range(out.shape[0]):
                p = prev[j]
                keep = one if (ninf < p) & (p < th_up) else zero
                out[j] = fma(beta * p, keep, x[j] * scale)
        else:
            for j in range(out.shape[0]):
                p = prev[j]
                keep = one if (ninf < p) & (p < th_up) else zero  # 1 - R = (U <= thr)
                out[j] = fma(beta * p, keep, x[j])


@jit
def step_row(prev: np.ndarray, x: np.ndarray, out: np.ndarray, spikes: np.ndarray, beta: np.float32,
              thr: np.float32, th_up: np.float32, subtract: bool, scale: np.float32, scaled: bool) -> None:
    """:func:`advance_row` and the spikes in one loop: the forward's step reads ``prev`` and ``x`` once and writes
    the membrane and the spike ``S = (U > thr)`` (``open_interval_mask(U, thr, inf)``) of each neuron: the same
    operations per element as two passes, with one pass less over the row (measured 1.45x on the forward alone)."""
    one, zero, inf, ninf = np.float32(1.0), np.float32(0.0), np.float32(np.inf), np.float32(-np.inf)
    nthr = -thr
    if subtract and scaled:
        for j in range(out.shape[0]):
            p = prev[j]
            u = fma(one if (thr < p) & (p < inf) else zero, nthr, fma(beta * p, one, x[j] * scale))
            out[j] = u
            spikes[j] = one if (thr < u) & (u < inf) else zero
    elif subtract:
        for j in range(out.shape[0]):
            p = prev[j]
            u = fma(one if (thr < p) & (p < inf) else zero, nthr, fma(beta * p, one, x[j]))
            out[j] = u
            spikes[j] = one if (thr < u) & (u < inf) else zero
    elif scaled:
        for j in range(out.shape[0]):
            p = prev[j]
            u = fma(beta * p, one if (ninf < p) & (p < th_up) else zero, x[j] * scale)
            out[j] = u
            spikes[j] = one if (thr < u) & (u < inf) else zero
    else:
        for j in range(out.shape[0]):
            p = prev[j]
            u = fma(beta * p, one if (ninf < p) & (p < th_up) else zero, x[j])
            out[j] = u
            spikes[j] = one if (thr < u) & (u < inf) else zero


@jit
def zero_reset_decay_row(u_prev: np.ndarray, sg: np.ndarray, decay: np.ndarray, th_up: np.float32,
                         detach_reset: bool) -> None:
    """dU[s]/dU[s-1] before the scale for the zero reset, from ``u_prev = U[s-1]`` and ``sg = S'(U[s-1])``:
    ``1 - R[s] = (U[s-1] <= thr)``, then, with the reset attached, ``addcmul_(U[s-1], S'(U[s-1]), value=-1)``."""
    one, zero, ninf = np.float32(1.0), np.float32(0.0), np.float32(-np.inf)
    if detach_reset:
        for j in range(decay.shape[0]):
            m = u_prev[j]
            decay[j] = one if (ninf < m) & (m < th_up) else zero
    else:
        for j in range(decay.shape[0]):
            m = u_prev[j]
            decay[j] = fma(-m, sg[j], one if (ninf < m) & (m < th_up) else zero)


@jit
def _scale_row(row: np.ndarray, scale: np.float32) -> None:
    """``row *= scale``, one rounding each (``mul`` by a float32 scalar)."""
    for j in range(row.shape[0]):
        row[j] = row[j] * scale


def checkpoint_rows(steps: int) -> int:
    """Rows of the forward's checkpoint array for a ``steps``-long sequence: one every :data:`EVERY` steps."""
    return (steps + EVERY - 1) // EVERY


def lif_forward(x: np.ndarray, mem0: np.ndarray, spikes: np.ndarray, last: np.ndarray, ckpt: np.ndarray, save: bool,
                beta: np.float32, thr: np.float32, th_up: np.float32, subtract: bool, chunk: int,
                in_scale: np.float32, scaled: bool) -> None:
    """Forward time loop. ``x (T, N)``, ``mem0 (N,)`` in; ``spikes (T, N)`` and ``last (N,)`` out (float32, C order).
    With ``save``, ``ckpt (checkpoint_rows(T), N)`` receives the membrane before every :data:`EVERY`-th step (row 0
    is ``mem0``), which :func:`lif_backward` recomputes from. With ``scaled`` the input current is ``x * in_scale``.

    Time-major: each work item sweeps its ``chunk`` neurons (the caller passes the whole row, up to
    :data:`FORWARD_CHUNK`) step after step, so its two membrane rows stay in L2 while ``x`` and the spikes stream."""
    steps, n = x.shape
    csr = get_csr() & CSR_MODE
    for c in prange((n + chunk - 1) // chunk):
        own = get_csr()
        set_csr(csr)  # the caller's denormal and rounding modes
        n0 = c * chunk
        n1 = min(n, n0 + chunk)
        # two membrane rows, swapped every step: updating one row in place would make LLVM's overlap check send the
        # loop down its scalar path (measured 2x slower)
        mem, nxt = mem0[n0:n1].copy(), np.empty(n1 - n0, dtype=np.float32)
        for s in range(steps):
            if save and s % EVERY == 0:
                ckpt[s // EVERY, n0:n1] = mem
            step_row(mem, x[s, n0:n1], nxt, spikes[s, n0:n1], beta, thr, th_up, subtract, in_scale, scaled)
            mem, nxt = nxt, mem
        last[n0:n1] = mem
        set_csr(own)


def lif_backward(x: np.ndarray, ckpt: np.ndarray, grad_spikes: np.ndarray, has_grad_spikes: bool,
                 grad_last: np.ndarray, has_grad_last: bool, grad_x: np.ndarray, grad_mem0: np.ndarray,
                 beta: np.float32, thr: np.float32, th_up: np.float32, subtract: bool, detach_reset: bool, kind: int,
                 lo: np.float32, hi: np.float32, c1: np.float32, c2: np.float32, block: int, chunk: int,
                 in_scale: np.float32, scaled: bool) -> None:
    """Backward time loop. Recomputes the membranes of each :data:`EVERY`-step window, last window first, from the
    forward's checkpoints ``ckpt`` and from ``x``, then carries dL/dU back through the window as
    :meth:`tactile_zoo.nn.lif_fused.FusedLIF.backward` does, its ``block`` boundaries included. ``grad_spikes
    (T, N)`` and ``grad_last (N,)`` are read only where their ``has_`` flag is set; writes ``grad_x (T, N)`` and
    ``grad_mem0 (N,)``. With ``scaled`` the forward's input was ``x * in_scale``: the membranes are recomputed from
    it, and each row of ``grad_x`` is multiplied by ``in_scale`` once the recurrence has read it (``MulBackward``'s
    ``grad * in_scale``, one rounding)."""
    steps, n = x.shape
    csr = get_csr() & CSR_MODE
    one, zero = np.float32(1.0), np.float32(0.0)
    # dU[t]/dU[t-1] is applied as fma(scale * g, decay, .); with a detached subtractive reset it is beta itself,
    # applied as fma(g, beta, .) (add_(g, alpha=beta)) -- a different rounding, hence its own branches below
    plain = subtract and detach_reset
    mode = PLAIN if plain else SUB if subtract else ZERO_DETACHED if detach_reset else ZERO
    scale = one if subtract else beta
    nthr = -thr
    for c in prange((n + chunk - 1) // chunk):
        own = get_csr()
        set_csr(csr)
        n0 = c * chunk
        n1 = min(n, n0 + chunk)
        width = n1 - n0
        hist = np.empty((EVERY + 1, width), dtype=np.float32)  # one window: U[s0-1], U[s0], ..., U[s1-1]
        decay = np.zeros(width, dtype=np.float32)  # dU[s + 1]/dU[s] before the scale (unused when plain)
        sg = np.empty(width, dtype=np.float32)  # S'(U[s])
        g_next = decay  # dL/dU[s + 1]: a row of grad_x once s < T - 1
        s0 = 0  # the first step of the current window
        for s in range(steps - 1, -1, -1):
            if s == steps - 1 or (s + 1) % EVERY == 0:  # entering window [s0, s1): recompute its membranes
                s0 = s - s % EVERY
                hist[0] = ckpt[s0 // EVERY, n0:n1]
                for k in range(s + 1 - s0):
                    advance_row(hist[k], x[s0 + k, n0:n1], hist[k + 1], beta, thr, th_up, subtract, in_scale,
                                 scaled)
                if s == steps - 1:
                    surrogate_row(hist[s + 1 - s0], thr, kind, lo, hi, c1, c2, sg)  # S'(U[T-1])
            g = grad_x[s, n0:n1]
            u_prev = hist[s - s0]  # U[s-1]
            if has_grad_spikes and s + 1 < steps and (s + 1) % block != 0:  # the usual step: one pass
                carry_row(grad_spikes[s, n0:n1], sg, decay, g_next, g, u_prev, beta, scale, thr, th_up, mode, kind,
                           lo, hi, c1, c2)
                if scaled:
                    _scale_row(g_next, in_scale)
                g_next = g
                continue
            if has_grad_spikes:  # mul(grad_spikes, S'(U[s]))
                gs = grad_spikes[s, n0:n1]
                for j in range(width):
                    g[j] = gs[j] * sg[j]
            else:  # zero_()
                g[:] = zero
            if s + 1 == steps:  # add_(grad of the last membrane)
                if has_grad_last:
                    gl = grad_last[n0:n1]
                    for j in range(width):
                        g[j] = g[j] + gl[j]
            elif (s + 1) % block == 0:  # U[s] ends a block: add_ the carry mul(mul(g, decay), scale) of the next
                if plain:
                    for j in range(width):
                        g[j] = g[j] + g_next[j] * beta
                else:
                    for j in range(width):
                        g[j] = g[j] + (g_next[j] * decay[j]) * scale
            elif plain:  # add_(g[s+1], alpha=beta)
                for j in range(width):
                    g[j] = fma(g_next[j], beta, g[j])
            else:  # addcmul_(g[s+1], decay[s+1], value=scale)
                for j in range(width):
                    g[j] = fma(scale * g_next[j], decay[j], g[j])
            surrogate_row(u_prev, thr, kind, lo, hi, c1, c2, sg)
            if subtract and not plain:  # mul(S'(U[s-1]), -thr).add_(beta): two roundings
                for j in range(width):
                    decay[j] = sg[j] * nthr + beta
            elif not subtract:
                zero_reset_decay_row(u_prev, sg, decay, th_up, detach_reset)
            if scaled and s + 1 < steps:  # dL/dU[s + 1] has been read for the last time: make it dL/dx[s + 1]
                _scale_row(g_next, in_scale)
            g_next = g
        gm = grad_mem0[n0:n1]
        for j in range(width):  # the carry out of the first block: dL/dmem0
            gm[j] = g_next[j] * beta if plain else (g_next[j] * decay[j]) * scale
        if scaled:
            _scale_row(g_next, in_scale)
        set_csr(own)


# Launching a parallel region wakes numba's worker threads, which costs tens of microseconds on a quiet machine and
# can wait milliseconds for a time slice on a busy one: one-thread calls and small sequences (streaming steps) take
# the serial builds instead.
lif_forward_serial = serial_copy(lif_forward)
lif_backward_serial = serial_copy(lif_backward)
lif_forward = jit(lif_forward, parallel=True)
lif_backward = jit(lif_backward, parallel=True)
