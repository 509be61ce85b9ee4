"""X-Tacformer: spatial graph attention (Tacformer's branch) and temporal graph attention (T-GCN cell + attention over
frames), fused by concatenation.

Paper: "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition" (the full model; no code published;
T-GCN cell after Zhao et al. 2020, as the paper's eqs. 10-13 state it). Shapes for NeuTouch (N = 39, C = 2,
T = 250) and the defaults (D = 64, H = 16, bins of 5 frames)::

    spatial:  exactly Tacformer up to its read-out -> LayerNorm-ed spike rate (B, D) ((B, 2D) with globals)
    temporal: binned frames (T' = 50, B, N, C) -> GCNConv C -> H on every frame -> T-GCN cell, an H-wide state per
              taxel (T', B, N, H) -> mean over taxels (T', B, H) -> additive attention over the frames seen
              (B, H) -> LayerNorm
    fusion:   concatenation (B, D + H) -> dropout -> Linear -> logits (B, K)

T-GCN cell (eqs. 10-13, :mod:`tactile_zoo.nn.tgcn`): ``u_t, r_t = sigmoid(W_{u,r} [GC(A, X_t), h_{t-1}] + b)``,
``c_t = tanh(W_c [GC(A, X_t), r_t * h_{t-1}] + b_c)``, ``h_t = u_t h_{t-1} + (1 - u_t) c_t``; frame scores
``w^T tanh(W f_t + b)``, softmax over the frames seen so far. Both branches only look back, so
:meth:`XTacformer.step` streams in constant memory.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..nn.tgcn import TemporalGraphAttention
from ..registry import recipe_file, register_model
from .tacformer import PAPER, Tacformer

__all__ = ["XTacformer"]


@register_model(
    "x_tacformer",
    paper=PAPER,
    year=2024,
    description="X-Tacformer: spatial graph attention (TAGConv + spiking multi-head self-attention over the taxels of "
                "each frame, LIF over time) fused with temporal graph attention (GCN + T-GCN cell, attention over "
                "frames).",
    tags=["spiking", "graph", "attention", "recurrent"],
    inputs=["graph", "globals"],
    **recipe_file("tactile_zoo", "x_tacformer"),
    causal=True,
    streaming=True,
    revision=2,  # 2: the NeuTouch default graph is the reference's exact edge list
)
class XTacformer(Tacformer):
    """X-Tacformer: Tacformer's spatial branch plus the temporal graph attention branch (structure in the module
    docstring).

    Departures: as Tacformer for the spatial branch (sizes, bins, pooling are ours); the temporal frame feature is
    the mean of the taxel states and ``hidden=16`` (ours). Model card: docs/models.md, section "`x_tacformer`:
    X-Tacformer".

    It takes every argument of :class:`~tactile_zoo.models.tacformer.Tacformer`, with the same meaning (``spec``,
    ``dim``, ``heads``, ``depth``, ``mlp_ratio``, ``hops``, ``tau``, ``v_th``, ``surrogate``, ``detach_reset``,
    ``bin_size``, ``taxel_embedding``, ``pool``, ``readout_norm``, ``attn_dropout``, ``graph``, ``graph_backend``,
    ``lif_backend``), and these:

    Args:
        hidden: T-GCN state width per taxel ``H``.
        temporal_pool: frame feature of the temporal branch: ``"mean"`` over taxels (``H``) or ``"flatten"``
            (``N * H``; on Ev-Objects it over-fitted: val loss 0.50 against 0.24, see docs/models.md).
        attn_dim: hidden width of the frame-scoring network.
        temporal_backend: ``"native"`` (eqs. 10-13) or ``"tgt"`` (torch_geometric_temporal's TGCN2, a different cell;
            needs ``pip install --no-deps torch-geometric-temporal==0.56.2``, which ``make install`` runs).
        dropout: dropout on the fused vector.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``; streaming ``x_t (B, N, C)``,
        ``g_t (B, G)`` or None -> ``(B, num_classes)``.
    """

    def __init__(self, spec: DatasetSpec, dim: int = 64, heads: int = 4, depth: int = 1, mlp_ratio: float = 0.0,
                 hops: int = 3, tau: float = 2.0, v_th: float = 1.0, surrogate: str = "atan",
                 detach_reset: bool = True, bin_size: int = 5, taxel_embedding: bool = True, pool: str = "flatten",
                 readout_norm: bool = True, hidden: int = 16, temporal_pool: str = "mean", attn_dim: int = 32,
                 temporal_backend: str = "native", dropout: float = 0.1, attn_dropout: float = 0.0,
                 graph: str = "default", graph_backend: str = "dense", lif_backend: str = "fused") -> None:
        super().__init__(spec, dim=dim, heads=heads, depth=depth, mlp_ratio=mlp_ratio, hops=hops, tau=tau, v_th=v_th,
                         surrogate=surrogate, detach_reset=detach_reset, bin_size=bin_size,
                         taxel_embedding=taxel_embedding, pool=pool, readout_norm=readout_norm, dropout=dropout,
                         attn_dropout=attn_dropout, graph=graph, graph_backend=graph_backend,
                         lif_backend=lif_backend)
        self.name = "x_tacformer"
        self.temporal = TemporalGraphAttention(spec.num_channels, hidden, spec.sensor.edge_index(graph),
                                               spec.num_nodes, pool=temporal_pool, attn_dim=attn_dim,
                                               temporal_backend=temporal_backend, graph_backend=graph_backend)
        self.temporal_norm = nn.LayerNorm(self.temporal.out_features)
        self.head = nn.Linear(self.rate_width + self.temporal.out_features, spec.num_classes)

    def _features(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        sp_core, tg_state = core if core is not None else (None, None)
        rate, sp_core = self._spatial_rate(xb, gb, sp_core)  # (B, W)
        tg, tg_state = self.temporal.run(xb, tg_state)  # (B, F): attention-weighted frame features so far
        fused = torch.cat([rate, self.temporal_norm(tg)], dim=-1)  # fusion by concatenation, (B, W + F)
        return fused, (sp_core, tg_state)  # Tacformer's forward_head: dropout, then the classifier
