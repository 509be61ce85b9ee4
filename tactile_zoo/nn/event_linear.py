"""Event-driven linear layer: ``x W^T + b`` summed over the nonzero entries of a sparse input only.

A spiking layer's input is mostly zeros (SGnet's 2496 -> 128 layer reads 4-6 % active spikes on Ev-Objects), so the
dense product spends most of its multiply-adds on zeros. With the input's nonzero entries as an event list
``(r, c, v)`` (row, input column, value; ``v = 1`` for spikes)::

    out[r]   = b + sum_{(r, c, v)} v * W[:, c]          # forward: the weight columns of the active inputs, summed
    dW[:, c] = sum_{(r, c, v)} v * grad[r]              # weight gradient: the output gradients of the rows where
                                                        # input c was active, summed
    db       = sum_r grad[r]
    dx       = grad @ W                                 # input gradient: dense (a surrogate gradient needs it
                                                        # everywhere, not only at the events)

Both sums run as ``torch.nn.functional.embedding_bag`` (mode ``sum``) over the event list, grouped by row for the
forward and by column for the weight gradient, so no ``(events, out)`` tensor is ever built. They are the dense
product's sums with the zero terms left out, added in another order: outputs and gradients differ from
``F.linear``'s by float rounding (relative differences around 1e-6 in float32; tests/nn/test_event_linear.py).

The event list is computed from ``x`` here (one compiled scan, :func:`events_of`); a producer that already knows its
active inputs (a LIF kernel emitting its spike indices) can pass them as ``events``
(:func:`events_from_rows`) and skip that scan.

CPU only: off CPU, and while a tracer runs (``torch.export``, ``torch.compile``, ``torch.jit.trace``),
:func:`event_linear` is ``F.linear`` (the dense path, which is the oracle the tests compare against). First-order
gradients reach the input, the weight and the bias; a second-order gradient through the event path raises (use the
dense path for it).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

from . import backend, storage_pool

__all__ = ["EventList", "event_linear", "events_from_rows", "events_of", "uses_events"]


class EventList(NamedTuple):
    """The nonzero entries of a ``(R, C)`` matrix, grouped by row (CSR) and by column (CSC).

    Attributes:
        cols: input column of every event, in row-major order ``(E,)`` (int64).
        row_offsets: where each row's events start in ``cols`` ``(R,)``.
        rows_by_col: row of every event, events grouped by column ``(E,)``.
        col_offsets: where each column's events start in ``rows_by_col`` ``(C,)``.
        values: the events' values in row-major order ``(E,)``, or ``None`` when every value is 1 (spikes).
        values_by_col: the same in column order, or ``None``.
    """

    cols: Tensor
    row_offsets: Tensor
    rows_by_col: Tensor
    col_offsets: Tensor
    values: Tensor | None
    values_by_col: Tensor | None


def _offsets(index: Tensor, size: int) -> Tensor:
    """Start of each group ``0..size-1`` in a list sorted by ``index``: an exclusive cumulative count."""
    counts = torch.bincount(index, minlength=size)
    return torch.cumsum(counts, 0) - counts


def events_of(x: Tensor) -> EventList:
    """The event list of ``x (R, C)``: its nonzero entries, with their values unless all of them are 1.

    One compiled scan where numba is installed (:func:`~tactile_zoo.nn.backend.event_kernels`), else
    ``torch.nonzero``; both give the same lists."""
    rows_n, cols_n = x.shape
    kernel = backend.event_kernels()
    if kernel is not None and x.is_contiguous() and type(x) is Tensor:
        # room for every entry: untouched pages of an empty tensor cost nothing, and the lists are cut to length
        cols, values = torch.empty(x.numel(), dtype=torch.int64), torch.empty(x.numel(), dtype=x.dtype)
        row_offsets = torch.empty(rows_n, dtype=torch.int64)
        count, binary = kernel.scan(x.numpy(), cols.numpy(), values.numpy(), row_offsets.numpy())
        cols, values = cols[:count].clone(), None if binary else values[:count].clone()
    else:
        flat = (x != 0).view(-1).nonzero().squeeze(1)  # a flat scan over a bool mask: cheaper than 2-D nonzero
        rows, cols = flat.div(cols_n, rounding_mode="floor"), flat.remainder(cols_n)
        row_offsets = _offsets(rows, rows_n)
        values = x.reshape(-1)[flat]
        if bool((values == 1).all()):
            values = None  # spikes: the sums need no multiplication (embedding_bag without per_sample_weights)
    return events_from_rows(cols, row_offsets, cols_n, values)


def events_from_rows(cols: Tensor, row_offsets: Tensor, num_cols: int, values: Tensor | None = None) -> EventList:
    """The :class:`EventList` of a row-major event list, e.g. the spike indices a LIF kernel emits per time step:
    ``cols`` (int64, ascending within each row) with each row's start in ``row_offsets``, ``values`` None for spikes.
    Adds the column-major half the weight gradient reads (a counting sort: rows stay ascending within a column)."""
    counts = torch.bincount(cols, minlength=num_cols)
    col_offsets = torch.cumsum(counts, 0) - counts
    kernel = backend.event_kernels()
    if kernel is not None:
        rows_by_col = torch.empty(len(cols), dtype=torch.int64)
        values_by_col = torch.empty(0 if values is None else len(cols), dtype=values.dtype if values is not None
                                    else torch.float32)
        kernel.by_column(cols.numpy(), (values_by_col if values is None else values).numpy(), row_offsets.numpy(),
                         col_offsets.numpy(), rows_by_col.numpy(), values_by_col.numpy(), values is not None)
        return EventList(cols, row_offsets, rows_by_col, col_offsets, values, None if values is None else values_by_col)
    row_counts = torch.diff(row_offsets, append=row_offsets.new_tensor([len(cols)]))
    rows = torch.repeat_interleave(torch.arange(len(row_offsets)), row_counts)
    order = torch.sort(cols, stable=True).indices  # column-major order, rows ascending within a column
    return EventList(cols, row_offsets, rows[order], col_offsets, values, None if values is None else values[order])


#: Tensor types the event path reads; a tracer's subclasses (fake, functional tensors) take the dense path.
_PLAIN = (Tensor, torch.nn.Parameter)


def uses_events(x: Tensor, weight: Tensor) -> bool:
    """Whether :func:`event_linear` takes the event path for these tensors (else it is ``F.linear``)."""
    plain = type(x) in _PLAIN and type(weight) in _PLAIN and not torch.compiler.is_compiling() \
        and not torch.jit.is_tracing()  # a TorchScript trace would record numpy calls it cannot replay
    return plain and x.device.type == "cpu" and weight.device.type == "cpu" and x.dtype == weight.dtype \
        and x.dtype in (torch.float32, torch.float64)


class _EventLinear(torch.autograd.Function):
    """``x @ table + bias`` over the events of ``x (R, C)`` with ``table (C, F_out)``; see the module docstring."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, table: Tensor, bias: Tensor | None, events: EventList) -> Tensor:
        table = table.contiguous()
        out = F.embedding_bag(events.cols, table, events.row_offsets, mode="sum", per_sample_weights=events.values)
        if bias is not None:
            out += bias  # in place on the product's own buffer: no second (R, F_out) tensor
        ctx.save_for_backward(table)
        ctx.events, ctx.has_bias = events, bias is not None
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable  # the saved table is a copy outside the graph: no second order
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        (table,) = ctx.saved_tensors
        ev = ctx.events
        grad = grad.contiguous()
        grad_x = grad_table = grad_bias = None
        if ctx.needs_input_grad[0]:
            # (R, C): dense, every input's gradient; into a pooled storage, which a rewrite does not page-fault on
            grad_x = torch.mm(grad, table.t(), out=storage_pool.reusable((grad.shape[0], table.shape[0]), grad))
        if ctx.needs_input_grad[1]:  # (C, F_out): the output gradients of each column's active rows, summed
            grad_table = F.embedding_bag(ev.rows_by_col, grad, ev.col_offsets, mode="sum",
                                         per_sample_weights=ev.values_by_col)
        if ctx.has_bias and ctx.needs_input_grad[2]:
            grad_bias = grad.sum(0)
        return grad_x, grad_table, grad_bias, None


def event_linear(x: Tensor, weight: Tensor, bias: Tensor | None = None, events: EventList | None = None) -> Tensor:
    """``F.linear(x, weight, bias)`` computed over the nonzero entries of ``x`` (see the module docstring).

    Args:
        x: the (mostly zero) input, e.g. spikes.
        weight: ``(F_out, C)``, as ``nn.Linear.weight``.
        bias: ``(F_out,)`` or None.
        events: the event list of ``x`` flattened to ``(R, C)``, if known (else computed here).

    Shapes:
        ``x (*, C)`` -> ``(*, F_out)``.
    """
    if not uses_events(x, weight):
        return F.linear(x, weight, bias)
    lead, width = x.shape[:-1], x.shape[-1]
    flat = x.reshape(-1, width)
    if events is None:
        events = events_of(flat.detach())
    out = _EventLinear.apply(flat, weight.t(), bias, events)
    return out.view(*lead, weight.shape[0])
