"""Top-k routing between neighbouring columns: each taxel's column reads a few neuron populations of its nearest
neighbours, chosen per step by a gate on its own input (Zhu et al., "Localist Topographic Expert Routing: A Barrel
Cortex-Inspired Modular Network for Sensorimotor Processing", NeurIPS 2025; code: github.com/fun0515/MultiBarrelModel).

For column ``n`` with neighbours ``nb(n, 1..k)`` (its ``k`` nearest taxels) and ``P`` populations of ``S`` neurons
each, the ``k * P`` candidate groups are (neighbour, population) pairs, numbered ``j * P + p``::

    w_n   = W_2 GELU(LN(W_1 x_n + c_1)) + c_2                  gate scores, (k * P,)
    sel_n = the indices of the m largest entries of w_n, largest first
    out_n = LN(A [s_{nb(n, j)}^p for j * P + p in sel_n] + a)  (S,), the groups concatenated in that order

The selection is an index, so no gradient reaches the gate: as in the source, where the gate's weights are never
updated, they are buffers here (drawn as ``nn.Linear``/``nn.LayerNorm`` would draw them). ``m = int(k * P *
ratio)``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["NeighbourTopKRouter", "nearest_neighbours"]


def nearest_neighbours(positions: Tensor, k: int) -> Tensor:
    """``(N, k)`` indices of each taxel's ``k`` nearest other taxels, nearest first: the Euclidean distances of
    ``positions (N, D)`` ranked by ``torch.topk`` (its order among equal distances, as the source ranks them), the
    taxel itself (distance 0, ranked first) dropped."""
    dist = torch.cdist(positions, positions)  # (N, N)
    return torch.topk(dist, k + 1, largest=False)[1][:, 1:k + 1]


class NeighbourTopKRouter(nn.Module):
    """The gated read-out of neighbouring columns (update rule in the module docstring).

    Args:
        in_features: the gate's input features per taxel (``x_n``).
        neighbours: ``(N, k)`` neighbour indices (:func:`nearest_neighbours`).
        populations: ``P``, populations per column; size: ``S``, neurons per population.
        ratio: the fraction of the ``k * P`` groups read (``m = int(k * P * ratio)``, at least 1).
        gate_hidden: the gate's hidden width.

    Shapes:
        :meth:`select`: ``x (B, N, in_features)`` -> ``(B, N, m)`` group indices. :meth:`forward`: spikes
        ``(B, N, P * S)`` (the populations concatenated), indices ``(B, N, m)`` -> ``(B, N, S)``.
    """

    def __init__(self, in_features: int, neighbours: Tensor, populations: int, size: int, ratio: float = 0.2,
                 gate_hidden: int = 256) -> None:
        super().__init__()
        self.populations, self.size = populations, size
        self.k = int(neighbours.shape[1])
        self.select_num = max(1, int(self.k * populations * ratio))
        self.register_buffer("neighbours", neighbours.long().clone(), persistent=False)
        first, second = nn.Linear(in_features, gate_hidden), nn.Linear(gate_hidden, self.k * populations)
        for name, tensor in (("gate_w1", first.weight), ("gate_b1", first.bias), ("gate_ln_w", torch.ones(gate_hidden)),
                             ("gate_ln_b", torch.zeros(gate_hidden)), ("gate_w2", second.weight),
                             ("gate_b2", second.bias)):
            self.register_buffer(name, tensor.detach().clone())
        self.aggregate = nn.Linear(self.select_num * size, size)
        self.norm = nn.LayerNorm(size)

    def select(self, x: Tensor) -> Tensor:
        """The ``m`` groups each column reads, best-scored first, ``(B, N, m)``."""
        h = F.linear(x, self.gate_w1, self.gate_b1)
        h = F.gelu(F.layer_norm(h, h.shape[-1:], self.gate_ln_w, self.gate_ln_b))
        scores = F.linear(h, self.gate_w2, self.gate_b2)  # (B, N, k * P)
        return torch.topk(scores, self.select_num, dim=-1)[1]

    def forward(self, spikes: Tensor, index: Tensor) -> Tensor:
        batch, n, _ = spikes.shape
        p = self.populations
        # group j * P + q of column i is population q of taxel neighbours[i, j]: row neighbours[i, j] * P + q
        rows = self.neighbours[torch.arange(n, device=index.device)[:, None], index // p] * p + index % p
        # the groups as rows of one (B * N * P, S) table: index_select copies whole rows, the same values as a gather
        # along dim 1 with the index expanded over S, and about 3x faster forward + backward on the CPU (B = 120)
        rows = rows + torch.arange(batch, device=index.device)[:, None, None] * (n * p)  # (B, N, m) in the table
        picked = spikes.reshape(batch * n * p, self.size).index_select(0, rows.reshape(-1))  # (B * N * m, S)
        return self.norm(self.aggregate(picked.reshape(batch, n, -1)))
