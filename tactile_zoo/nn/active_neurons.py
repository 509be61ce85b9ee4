"""The active neurons of every step of a spike tensor, in compressed-sparse-row form, for layers that work on the
spikes that fired only (an event-driven linear layer gathers the weight rows of its active inputs).

``MultiStepLIF(...)(x, return_active=True)`` returns them with the spikes; :func:`active_spikes` computes them from
any spike tensor. On CPU for float32 spikes one compiled pass does it (``active_csr`` of the event kernels,
:func:`tactile_zoo.nn.backend.event_kernels`, into a reused storage with room for every neuron:
:func:`tactile_zoo.nn.storage_pool.reusable`), elsewhere torch's ``nonzero``; both give the same arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from . import backend, storage_pool

__all__ = ["ActiveSpikes", "active_spikes"]

_INT32 = torch.empty(0, dtype=torch.int32)


@dataclass(frozen=True)
class ActiveSpikes:
    """The nonzero entries of spikes ``(T, B, ..., F)`` seen as a matrix of ``rows = T * B * ...`` rows (row-major
    over the leading dimensions: row ``t * B + b`` for ``(T, B, F)``) and ``cols = F`` columns (the last dimension).

    Attributes:
        indptr: ``(rows + 1,)`` int64; the active columns of row ``r`` are ``indices[indptr[r]:indptr[r + 1]]``.
        indices: ``(nnz,)`` int32 column indices, ascending within each row.
        shape: the spike tensor's shape.
    """

    indptr: Tensor
    indices: Tensor
    shape: tuple[int, ...]

    @property
    def rows(self) -> int:
        return self.indptr.numel() - 1

    @property
    def cols(self) -> int:
        return self.shape[-1]

    def counts(self) -> Tensor:
        """Active neurons per row, ``(rows,)`` int64."""
        return self.indptr[1:] - self.indptr[:-1]

    def to_dense(self) -> Tensor:
        """The 0/1 float32 spike tensor these indices describe (for checks; the event-driven path avoids it)."""
        dense = torch.zeros(self.rows, self.cols, device=self.indices.device)
        rows = torch.repeat_interleave(torch.arange(self.rows, device=self.indptr.device), self.counts())
        dense[rows, self.indices.long()] = 1.0
        return dense.view(self.shape)


def active_spikes(spikes: Tensor) -> ActiveSpikes:
    """The active (nonzero) neurons of every row of ``spikes`` (see :class:`ActiveSpikes`); not differentiable.

    Args:
        spikes: ``(T, ..., F)`` spikes, at least 1-d (a 1-d tensor is one row).
    """
    shape = tuple(spikes.shape)
    flat = spikes.detach().reshape(-1, shape[-1] if shape else 1)
    if flat.device.type == "cpu" and flat.dtype == torch.float32:
        kernels = backend.event_kernels()
        if kernels is not None:
            flat = flat.contiguous()
            indptr = torch.empty(flat.shape[0] + 1, dtype=torch.int64)
            # room for every neuron firing, from the pool of reused storages (a fresh tensor this large would cost
            # more in page faults than the pass itself); the indices are a view of it, which keeps it in use
            room = storage_pool.reusable((flat.numel() + 1,), _INT32)
            count = kernels.active_csr(flat.numpy(), indptr.numpy(), room.numpy())
            return ActiveSpikes(indptr, room[:count], shape)
    nonzero = flat != 0
    indptr = torch.zeros(flat.shape[0] + 1, dtype=torch.int64, device=flat.device)
    torch.cumsum(nonzero.sum(1), 0, out=indptr[1:])
    indices = nonzero.nonzero()[:, 1].to(torch.int32)
    return ActiveSpikes(indptr, indices, shape)
