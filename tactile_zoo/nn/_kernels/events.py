"""The nonzero entries of a spike or event matrix as lists, in one compiled pass each (numba).

:func:`scan` and :func:`by_column` build the event list of :mod:`tactile_zoo.nn.event_linear` (its nonzero entries by
row, then by column); :func:`active_csr` the active neurons of :mod:`tactile_zoo.nn.active_neurons` (CSR). Loaded
lazily (:func:`tactile_zoo.nn.backend.event_kernels`); the callers fall back to ``torch.nonzero`` (and a sort) where
numba is missing, with the same lists. Nothing here is public. ``torch.nonzero`` on SGnet's spikes (2000 x 2496 at
batch 8) costs about as much as the dense product the event list replaces; one scan that writes the row-major list
and counts the columns, then a counting sort into column order, costs a fraction of it. Cached on disk where it can
be (:func:`~.jit.jit`).
"""

from __future__ import annotations

import numpy as np

from .jit import jit

__all__ = ["scan", "by_column", "active_csr"]


@jit
def scan(x: np.ndarray, cols: np.ndarray, values: np.ndarray,
         row_offsets: np.ndarray) -> tuple[int, bool]:  # pragma: no cover - compiled
    """Row-major nonzeros of ``x (R, C)`` into ``cols`` and ``values`` (each at least ``R * C`` long); each
    row's start into ``row_offsets (R,)``. Returns (number of events, whether every value is 1)."""
    n_rows, n_cols = x.shape
    k = 0
    binary = True
    for r in range(n_rows):
        row_offsets[r] = k
        for c in range(n_cols):
            v = x[r, c]
            if v != 0:
                cols[k] = c
                values[k] = v
                binary &= v == 1
                k += 1
    return k, binary


@jit
def by_column(cols: np.ndarray, values: np.ndarray, row_offsets: np.ndarray, col_offsets: np.ndarray,
              rows_by_col: np.ndarray, values_by_col: np.ndarray, with_values: bool) -> None:  # pragma: no cover
    """Counting sort of the row-major events (row ``r``'s from ``row_offsets[r]`` on) into column order, rows
    ascending within a column; ``col_offsets`` holds each column's start."""
    pos = col_offsets.copy()
    n_rows, count = row_offsets.shape[0], cols.shape[0]
    for r in range(n_rows):
        end = row_offsets[r + 1] if r + 1 < n_rows else count
        for k in range(row_offsets[r], end):
            c = cols[k]
            p = pos[c]
            rows_by_col[p] = r
            if with_values:
                values_by_col[p] = values[k]
            pos[c] = p + 1


@jit
def active_csr(spikes: np.ndarray, indptr: np.ndarray, out: np.ndarray) -> int:
    """The nonzero columns of each row of ``spikes (R, F)`` in CSR form, in one pass: fills ``indptr (R + 1,)``
    (int64) and ``out`` (int32, room for ``R * F + 1``) so that the columns of row ``r`` are
    ``out[indptr[r]:indptr[r + 1]]``, ascending; returns the count. The fill has no branch: every column is written
    and the position advances where the spike is nonzero (hence the spare slot)."""
    rows, cols = spikes.shape
    indptr[0] = 0
    k = 0
    for r in range(rows):
        row = spikes[r]
        for j in range(cols):
            out[k] = j
            k += row[j] != 0
        indptr[r + 1] = k
    return k
