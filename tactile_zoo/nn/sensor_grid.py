"""Sensor image grid: per-taxel features scattered onto an ``(H, W)`` lattice, empty cells filled.

Image models (ConvLSTM, CNN-LSTM) see a frame as a small image. The layer takes the grid geometry only (the models
unpack a sensor's ``grid``, ``grid_shape`` and ``grid_fill``; ``nn`` never imports ``data``). Each taxel ``i`` owns
cell ``grid[i]``; the other cells are empty and start at zero. ``fill_passes`` passes of neighbour filling follow
(BioTac SP: 2, the ConvLSTM source's 12x11 layout, Zapata-Impata et al., Sensors 2019):

    pass k:  v_k(cell) = mean{ v_{k-1}(n) : n in N8(cell), n non-empty after pass k-1 }   for every cell empty
             after pass k-1 that has at least one such neighbour; all other cells keep v_{k-1}.

``N8`` are the up to 8 neighbours inside the grid. Passes are synchronous (a cell filled in pass k feeds its
neighbours only from pass k+1 on), so the result does not depend on a scan order; "non-empty" is a property of the
cell (a taxel, or filled by an earlier pass), never of its value, so a taxel that reads 0 still counts. Cells no pass
reaches stay 0.

Every step above is linear in the taxel values and fixed by the geometry, so the whole map (placement plus all
passes) is precomputed once as a matrix ``M [H*W, N]`` and applied to all ``B*T`` frames and channels in one matrix
product. Without fill passes ``M`` only selects, and a gather with a precomputed index replaces the product.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from ..errors import ConfigError

__all__ = ["SensorGrid", "grid_weights"]

_NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def grid_weights(grid: tuple[tuple[int, int], ...], grid_shape: tuple[int, int], fill_passes: int) -> Tensor:
    """The linear map from taxel values to cell values, ``float64 [H*W, N]`` (rule in the module docstring)."""
    h, w = grid_shape
    n = len(grid)
    weights = torch.zeros(h * w, n, dtype=torch.float64)
    filled = torch.zeros(h * w, dtype=torch.bool)
    for i, (r, c) in enumerate(grid):
        weights[r * w + c, i] = 1.0
        filled[r * w + c] = True
    for _ in range(fill_passes):
        new_weights, new_filled = weights.clone(), filled.clone()
        for r in range(h):
            for c in range(w):
                if filled[r * w + c]:
                    continue
                around = [(r + dr) * w + (c + dc) for dr, dc in _NEIGHBOURS
                          if 0 <= r + dr < h and 0 <= c + dc < w and filled[(r + dr) * w + (c + dc)]]
                if around:
                    new_weights[r * w + c] = weights[around].mean(0)
                    new_filled[r * w + c] = True
        weights, filled = new_weights, new_filled
    return weights


class SensorGrid(nn.Module):
    """Scatter node features onto the sensor image: ``[..., N, C] -> [..., C, H, W]``.

    Args:
        grid: ``(row, col)`` of every taxel, in taxel order (``N = len(grid)``); no two taxels share a cell.
        grid_shape: ``(H, W)`` of the image.
        fill_passes: passes of empty-cell filling (rule in the module docstring); 0 only places the taxels.

    Shapes:
        input ``[..., N, C]`` (any number of leading dimensions, e.g. ``B, T`` or ``B``);
        output ``[..., C, H, W]``, contiguous.
    """

    def __init__(self, grid: Sequence[Sequence[int]], grid_shape: Sequence[int], fill_passes: int = 0) -> None:
        super().__init__()
        if fill_passes < 0:
            raise ConfigError(f"fill_passes must be >= 0, got {fill_passes}")
        cells = tuple((int(r), int(c)) for r, c in grid)
        if len(grid_shape) != 2 or min(grid_shape) < 1:
            raise ConfigError(f"SensorGrid: grid_shape must be (H, W) with H, W >= 1, got {tuple(grid_shape)}")
        h, w = (int(v) for v in grid_shape)
        if not cells or len(set(cells)) != len(cells) or any(not (0 <= r < h and 0 <= c < w) for r, c in cells):
            raise ConfigError(f"SensorGrid: grid must give every taxel its own cell inside the {h}x{w} grid")
        self.grid_shape = (h, w)
        self.num_nodes = len(cells)
        self.fill_passes = fill_passes
        weights = grid_weights(cells, self.grid_shape, fill_passes)
        # non-persistent: derived from the geometry, so checkpoints stay free of it and `.to()` still moves it
        self.register_buffer("weight_t", weights.t().contiguous().float(), persistent=False)  # (N, H*W)
        # source of every cell for the no-fill gather: its taxel, or N (a zero column appended at run time)
        source = torch.full((weights.shape[0],), self.num_nodes, dtype=torch.long)
        rows, cols = weights.nonzero(as_tuple=True)
        source[rows] = cols
        self.register_buffer("source", source, persistent=False)
        # the flat cell of every taxel, in taxel order: a read-out that keeps where on the sensor a feature is
        self.register_buffer("taxel_cells", torch.tensor([r * w + c for r, c in cells], dtype=torch.long),
                             persistent=False)

    def forward(self, x: Tensor) -> Tensor:
        if x.dim() < 2 or x.shape[-2] != self.num_nodes:
            raise ConfigError(f"SensorGrid expects node features [..., {self.num_nodes}, C], got {tuple(x.shape)}")
        h, w = self.grid_shape
        lead = x.shape[:-2]
        xt = x.transpose(-1, -2)  # (..., C, N)
        if self.fill_passes == 0:
            padded = torch.cat([xt, xt.new_zeros(*xt.shape[:-1], 1)], dim=-1)  # (..., C, N + 1)
            cells = padded.index_select(-1, self.source)  # (..., C, H*W)
        else:
            cells = xt @ self.weight_t.to(x.dtype)  # (..., C, H*W): one GEMM over all leading dims and channels
        return cells.reshape(*lead, x.shape[-1], h, w)  # (..., C, H, W)

    def extra_repr(self) -> str:
        return f"nodes={self.num_nodes}, grid={self.grid_shape}, fill_passes={self.fill_passes}"
