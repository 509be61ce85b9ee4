"""The event list of a sparse matrix in one compiled pass (numba): its nonzero entries by row, then by column.

Imported lazily by :mod:`tactile_zoo.nn.event_linear`, which falls back to ``torch.nonzero`` and a sort where numba
is missing. Nothing here is public. ``torch.nonzero`` on SGnet's spikes (2000 x 2496 at batch 8) costs about as much
as the dense product the event list replaces; one scan that writes the row-major list and counts the columns, then a
counting sort into column order, costs a fraction of it. Cached on disk as :mod:`._lif_kernel` is.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["scan", "by_column"]


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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
