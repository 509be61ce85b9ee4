"""SGnet's first layer as one compiled time loop (numba): the event-driven graph convolution's current, the LIF step
and the spike list of every frame, without writing the ``(T, B, W)`` current anywhere.

Run by :mod:`tactile_zoo.nn.event_graph_lif`; nothing here is public. For every frame row ``r = t * B + b`` the
current is the sum of the effective matrix's rows that the frame's input events select, then the bias
(``embedding_bag`` then ``+= bias``, as :func:`~tactile_zoo.nn.event_graph_conv.event_graph_conv` computes it: one
float32 add per event, in the events' order, so the same bits), and is used at once, while it is in L1, by the LIF
step of :mod:`._kernels.lif` (its own row helpers, so the same operations per element). The forward writes the spikes,
the spike list of each row and a membrane checkpoint every :data:`~._kernels.lif.EVERY` steps; the backward recomputes
each window's currents from the input events and its membranes from the checkpoint, then carries dL/dU back as
:func:`~._kernels.lif.lif_backward` does for the zero reset, its ``block`` boundaries included.

Work items are batch rows (``prange`` over ``B``): each owns its membranes and its part of the spike list, and
:func:`merge_events` puts the parts in row order afterwards.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .jit import CSR_MODE, get_csr, jit, serial_copy, set_csr
from .lif import EVERY, ZERO, ZERO_DETACHED, advance_row, carry_row, step_row, surrogate_row, zero_reset_decay_row

__all__ = ["graph_lif_forward", "graph_lif_backward", "graph_lif_forward_serial", "graph_lif_backward_serial",
           "merge_events"]


@jit
def _current_row(table: np.ndarray, bias: np.ndarray, in_cols: np.ndarray, e0: int, e1: int,
                 cur: np.ndarray) -> None:
    """``cur = sum(table[in_cols[e0:e1]]) + bias``: ``embedding_bag``'s sum from zero in the events' order, then the
    bias added in place (two float32 roundings per event and one for the bias, as the unfused path)."""
    zero = np.float32(0.0)
    for j in range(cur.shape[0]):
        cur[j] = zero
    for e in range(e0, e1):
        row = table[in_cols[e]]
        for j in range(cur.shape[0]):
            cur[j] = cur[j] + row[j]
    for j in range(cur.shape[0]):
        cur[j] = cur[j] + bias[j]


@jit
def _list_spikes(row: np.ndarray, out: np.ndarray, k: int) -> int:
    """Append the columns where ``row`` is nonzero to ``out`` from ``k`` on; returns the new end. No branch: every
    column is written, and the end moves past it where the row spiked (``out`` needs one spare slot)."""
    for j in range(row.shape[0]):
        out[k] = j
        k += row[j] != 0
    return k


def graph_lif_forward(table: np.ndarray, bias: np.ndarray, in_cols: np.ndarray, in_offsets: np.ndarray,
                      mem0: np.ndarray, spikes: np.ndarray, last: np.ndarray, ckpt: np.ndarray, save: bool,
                      cols_by_batch: np.ndarray, counts: np.ndarray, beta: np.float32, thr: np.float32,
                      th_up: np.float32) -> None:
    """Forward time loop of ``spikes (T, B, W)`` from the input events (``in_cols`` with each row's start in
    ``in_offsets (T * B + 1,)``), ``table (C_in, W)``, ``bias (W,)`` and ``mem0 (B, W)``; zero reset. Writes
    ``last (B, W)``, with ``save`` the checkpoints ``ckpt (rows, B, W)``, and batch row ``b``'s spike columns, step
    after step, into ``cols_by_batch[b]`` (room for ``T * W + 1``) with their number per row in ``counts (T, B)``."""
    steps, batch, width = spikes.shape
    csr = get_csr() & CSR_MODE
    one = np.float32(1.0)
    for b in prange(batch):
        own = get_csr()
        set_csr(csr)  # the caller's denormal and rounding modes
        mem, nxt = mem0[b].copy(), np.empty(width, dtype=np.float32)
        cur = np.empty(width, dtype=np.float32)
        out = cols_by_batch[b]
        k = 0
        for s in range(steps):
            if save and s % EVERY == 0:
                ckpt[s // EVERY, b] = mem
            r = s * batch + b
            _current_row(table, bias, in_cols, in_offsets[r], in_offsets[r + 1], cur)
            row = spikes[s, b]
            step_row(mem, cur, nxt, row, beta, thr, th_up, False, one, False)
            k0 = k
            k = _list_spikes(row, out, k)
            counts[s, b] = k - k0
            mem, nxt = nxt, mem
        last[b] = mem
        set_csr(own)


@jit
def merge_events(cols_by_batch: np.ndarray, counts: np.ndarray, cols: np.ndarray, row_offsets: np.ndarray) -> None:
    """The spike list in row order ``r = t * B + b`` (as a scan of the ``(T * B, W)`` spikes gives it) from the
    per-batch-row parts of :func:`graph_lif_forward`."""
    steps, batch = counts.shape
    pos = np.zeros(batch, dtype=np.int64)
    k = 0
    for s in range(steps):
        for b in range(batch):
            row_offsets[s * batch + b] = k
            n = counts[s, b]
            src = cols_by_batch[b]
            p = pos[b]
            for i in range(n):
                cols[k + i] = src[p + i]
            pos[b] = p + n
            k += n


def graph_lif_backward(table: np.ndarray, bias: np.ndarray, in_cols: np.ndarray, in_offsets: np.ndarray,
                       ckpt: np.ndarray, grad_spikes: np.ndarray, grad_cur: np.ndarray, beta: np.float32,
                       thr: np.float32, th_up: np.float32, detach_reset: bool, kind: int, lo: np.float32,
                       hi: np.float32, c1: np.float32, c2: np.float32, block: int) -> None:
    """Backward time loop: ``grad_cur (T, B, W)``, dL/d(current), from ``grad_spikes (T, B, W)``; the membranes of
    each window are recomputed from ``ckpt`` and from the currents, recomputed from the input events. The same
    operations per element as :func:`~._kernels.lif.lif_backward` with the zero reset, no input scale, no gradient of
    the last membrane and the same ``block``."""
    steps, batch, width = grad_spikes.shape
    csr = get_csr() & CSR_MODE
    one = np.float32(1.0)
    mode = ZERO_DETACHED if detach_reset else ZERO
    scale = beta  # dU[t]/dU[t-1] carries as fma(beta * g, decay, .) for the zero reset
    for b in prange(batch):
        own = get_csr()
        set_csr(csr)
        hist = np.empty((EVERY + 1, width), dtype=np.float32)  # one window: U[s0-1], U[s0], ..., U[s1-1]
        decay = np.zeros(width, dtype=np.float32)
        sg = np.empty(width, dtype=np.float32)
        cur = np.empty(width, dtype=np.float32)
        g_next = decay
        s0 = 0
        for s in range(steps - 1, -1, -1):
            if s == steps - 1 or (s + 1) % EVERY == 0:  # entering window [s0, s]: recompute its membranes
                s0 = s - s % EVERY
                hist[0] = ckpt[s0 // EVERY, b]
                for k in range(s + 1 - s0):
                    r = (s0 + k) * batch + b
                    _current_row(table, bias, in_cols, in_offsets[r], in_offsets[r + 1], cur)
                    advance_row(hist[k], cur, hist[k + 1], beta, thr, th_up, False, one, False)
                if s == steps - 1:
                    surrogate_row(hist[s + 1 - s0], thr, kind, lo, hi, c1, c2, sg)  # S'(U[T-1])
            g = grad_cur[s, b]
            u_prev = hist[s - s0]  # U[s-1]
            gs = grad_spikes[s, b]
            if s + 1 < steps and (s + 1) % block != 0:  # the usual step: one pass
                carry_row(gs, sg, decay, g_next, g, u_prev, beta, scale, thr, th_up, mode, kind, lo, hi, c1, c2)
                g_next = g
                continue
            for j in range(width):
                g[j] = gs[j] * sg[j]
            if s + 1 < steps:  # U[s] ends a block: add the carry mul(mul(g, decay), scale) of the next
                for j in range(width):
                    g[j] = g[j] + (g_next[j] * decay[j]) * scale
            surrogate_row(u_prev, thr, kind, lo, hi, c1, c2, sg)
            zero_reset_decay_row(u_prev, sg, decay, th_up, detach_reset)
            g_next = g
        set_csr(own)


graph_lif_forward_serial = serial_copy(graph_lif_forward)
graph_lif_backward_serial = serial_copy(graph_lif_backward)
graph_lif_forward = jit(graph_lif_forward, parallel=True)
graph_lif_backward = jit(graph_lif_backward, parallel=True)
