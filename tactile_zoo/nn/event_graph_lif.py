"""Event-driven graph convolution -> LIF -> spike list, fused per time step: SGnet's first layer without its current.

SGnet's first layer is a TAGConv over every frame's taxel graph, computed over the input events
(:func:`~tactile_zoo.nn.event_graph_conv.event_graph_conv`), then a LIF population with the zero reset, then the
spike list the next layer's event product reads (:func:`~tactile_zoo.nn.event_linear.event_linear`). Apart, the three
write and reread a ``(T, B, N * F)`` current (20 MB at batch 8 on Ev-Objects), and the spike list is a second scan of
the spikes. Fused, each frame row's current is built from its input events and used at once by the LIF step, in the
same compiled loop (:mod:`tactile_zoo.nn._kernels.graph_lif`)::

    I[t, b]  = sum_{(j, f) active in x[t, b]} E[(j, f)] + bias       # the effective TAGConv matrix's rows
    U[t, b]  = beta * U[t-1, b] * (1 - S[t-1, b]) + I[t, b]            # the LIF, zero reset
    S[t, b]  = U[t, b] > threshold, and its active columns listed

The backward recomputes each window's currents from the input events and its membranes from checkpoints, and gives
dL/dI, from which the effective matrix's and the bias's gradients are summed as the unfused path sums them.

Every operation is the unfused path's, in the same order: spikes, spike list and gradients are bit for bit the
same (tests/nn/test_event_graph_lif.py), so it is not a new revision. It runs where the unfused path would run the
event product and the compiled LIF kernel, on a binary input (spikes or events), with a plain LIF that has no hooks;
elsewhere :func:`event_graph_lif` is the two layers apart, the oracle (so a hook recording the LIF's spikes still
sees every call).
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from . import backend as switch
from . import lif_fused, storage_pool
from .backend import GraphBackend, LIFBackend
from .event_graph_conv import effective_matrix, event_graph_conv
from .event_linear import EventList, events_from_rows, events_of, uses_events
from .graph import FrameGraphConv
from .hooks import has_hooks
from .lif import MultiStepLIF
from .lif_compiled import f32, surrogate_args

__all__ = ["event_graph_lif"]


def _fusable(conv: FrameGraphConv, lif: MultiStepLIF, x: Tensor) -> ModuleType | None:
    """The compiled LIF kernels if the fused loop computes this call exactly as the two layers apart, else None.

    The LIF must be a plain :class:`~tactile_zoo.nn.lif.MultiStepLIF` without hooks: a subclass's own ``forward``
    (the exporter's) and a hook recording its spikes see the layers apart, which give the same numbers."""
    if conv.backend is not GraphBackend.DENSE or x.dim() != 4 or x.shape[-2:] != (conv.num_nodes, conv.in_channels):
        return None
    if type(lif) is not MultiStepLIF or has_hooks(lif) or lif.backend is not LIFBackend.FUSED or lif.reset != "zero" \
            or lif.input_scale != 1.0:
        return None
    if not uses_events(x, conv.hop_weights()[0]) or x.dtype != torch.float32 or switch.graph_lif_kernels() is None:
        return None
    return switch.lif_kernels_for(x, x, lif.surrogate)


def event_graph_lif(conv: FrameGraphConv, lif: MultiStepLIF, x: Tensor) -> tuple[Tensor, EventList | None]:
    """``lif(conv(x))`` over time, fused where it can be (see the module docstring), with the spikes' event list.

    Args:
        conv: a :class:`~tactile_zoo.nn.graph.FrameGraphConv` (its ``"dense"`` backend, for the fused loop).
        lif: the :class:`~tactile_zoo.nn.lif.MultiStepLIF` after it (membranes at rest at the first step).
        x: time-major node features, mostly zero.

    Returns:
        The spikes, and their event list as :func:`~tactile_zoo.nn.event_linear.events_of` gives it for the
        ``(T * B, N * F_out)`` rows, or ``None`` where the layers ran apart.

    Shapes:
        ``x (T, B, N, F_in)`` -> spikes ``(T, B, N * F_out)``.
    """
    kernels = _fusable(conv, lif, x)
    events = None if kernels is None else events_of(x.detach().reshape(-1, x.shape[-2] * x.shape[-1]))
    if events is None or events.values is not None:  # unfused, or an input that is not 0/1: the layers apart
        steps, batch = x.shape[:2]
        return lif(event_graph_conv(conv, x).reshape(steps, batch, -1)), None  # (T, B, N * F_out)
    n = conv.num_nodes
    matrix = effective_matrix(conv, x.dtype)  # (N * F_out, N * F_in)
    bias = conv.conv.bias.repeat(n) if conv.conv.bias is not None else matrix.new_zeros(matrix.shape[0])
    offsets = torch.cat([events.row_offsets, events.row_offsets.new_tensor([len(events.cols)])])  # (T * B + 1,)
    sink: list[EventList] = []
    cfg = (tuple(x.shape[:2]), lif, kernels, events, offsets, sink)
    if torch.is_grad_enabled() and (matrix.requires_grad or bias.requires_grad):
        spikes = _EventGraphLIF.apply(matrix, bias, cfg)
    else:
        spikes = _forward(matrix.detach().t().contiguous(), bias.detach(), cfg, save=False)[0]
    return spikes, sink[0]


def _forward(table: Tensor, bias: Tensor, cfg: tuple, save: bool) -> tuple[Tensor, Tensor | None]:
    """The compiled forward from ``table (N * F_in, W)``, the effective matrix with a row per input column (as the
    event product's table): spikes ``(T, B, W)`` and, with ``save``, the membrane checkpoints; the spike list goes
    into ``cfg``'s sink."""
    (steps, batch), lif, kernels, events, offsets, sink = cfg
    graph = switch.graph_lif_kernels()
    width = table.shape[1]
    spikes = storage_pool.reusable((steps, batch, width), table)
    ckpt = torch.empty(kernels.checkpoint_rows(steps), batch, width) if save else torch.empty(1, 1, 1)
    # room for every spike and a spare slot, on a pooled storage: only the part written is read, and no page faults
    by_batch = storage_pool.reusable((batch, steps * width + 1), events.cols)
    counts = torch.empty(steps, batch, dtype=torch.int64)
    mem0, last = torch.zeros(batch, width), torch.empty(batch, width)
    switch.launch(graph, "graph_lif_forward", table.numpy(), bias.contiguous().numpy(), events.cols.numpy(),
                  offsets.numpy(), mem0.numpy(), spikes.numpy(), last.numpy(), ckpt.numpy(), save, by_batch.numpy(),
                  counts.numpy(), *f32(lif.beta, lif.threshold, lif_fused.next_up(lif.threshold, torch.float32)),
                  serial=batch == 1)
    cols, row_offsets = torch.empty(int(counts.sum()), dtype=torch.int64), torch.empty(steps * batch, dtype=torch.int64)
    graph.merge_events(by_batch.numpy(), counts.numpy(), cols.numpy(), row_offsets.numpy())
    sink.append(events_from_rows(cols, row_offsets, width))
    return spikes, (ckpt if save else None)


class _EventGraphLIF(torch.autograd.Function):
    """Spikes from the effective matrix ``(W, C_in)`` and the bias ``(W,)`` over the input events in ``cfg``; see the
    module docstring."""

    @staticmethod
    def forward(ctx: Any, matrix: Tensor, bias: Tensor, cfg: tuple) -> Tensor:
        table, bias = matrix.detach().t().contiguous(), bias.detach()  # (N * F_in, W)
        spikes, ckpt = _forward(table, bias, cfg, save=True)
        ctx.save_for_backward(table, bias, ckpt)
        ctx.cfg = cfg
        ctx.set_materialize_grads(False)
        return spikes

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: Any, grad_spikes: Tensor | None) -> tuple[Tensor | None, ...]:
        if grad_spikes is None:
            return None, None, None
        table, bias, ckpt = ctx.saved_tensors
        (steps, batch), lif, kernels, ev, offsets, _ = ctx.cfg
        width = table.shape[1]
        block = lif_fused.block_steps(steps, batch * width * table.element_size())  # the unfused LIF's blocks
        grad_cur = storage_pool.reusable((steps, batch, width), table)  # dL/dI (T, B, W)
        switch.launch(switch.graph_lif_kernels(), "graph_lif_backward", table.numpy(), bias.numpy(), ev.cols.numpy(),
                      offsets.numpy(), ckpt.numpy(), grad_spikes.contiguous().numpy(), grad_cur.numpy(),
                      *f32(lif.beta, lif.threshold, lif_fused.next_up(lif.threshold, torch.float32)),
                      lif.detach_reset, *surrogate_args(kernels, lif.surrogate), block, serial=batch == 1)
        rows = grad_cur.view(steps * batch, width)  # (T * B, W), as the event product's output gradient
        grad_matrix = grad_bias = None
        if ctx.needs_input_grad[0]:  # (N * F_in, W): each input column's active rows, summed; then as E's layout
            grad_matrix = F.embedding_bag(ev.rows_by_col, rows, ev.col_offsets, mode="sum").t()
        if ctx.needs_input_grad[1]:
            grad_bias = rows.sum(0)
        return grad_matrix, grad_bias, None
