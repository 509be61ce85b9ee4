"""X-Tacformer: spatial graph attention (Tacformer's branch) and temporal graph attention (T-GCN + attention over
frames), fused for classification."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn.attention import LIFConfig
from ..nn.tgcn import TemporalGraphAttention
from ..registry import register_model
from .tacformer import PAPER, BinnedStreamer, SpatialGraphAttention

__all__ = ["XTacformer"]


@register_model(
    "x_tacformer",
    paper=PAPER,
    year=2024,
    description="X-Tacformer: spatial graph attention (TAGConv + spiking multi-head self-attention per frame, LIF "
                "over time) fused with temporal graph attention (T-GCN cell + attention over frames).",
    tags=["spiking", "graph", "attention", "recurrent"],
    inputs=["graph", "globals"],
    recipe={"loss": "ce", "optimizer": "adamw", "lr": 2e-3, "weight_decay": 1e-2, "schedule": {"type": "cosine"},
            "max_epochs": 60, "patience": 15, "batch_size": 16, "grad_clip": 1.0},
    causal=True,
    streaming=True,
)
class XTacformer(BinnedStreamer):
    """X-Tacformer (draft model card; see docs/models.md).

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        dim, heads, depth, mlp_ratio, hops, tau, v_th, surrogate, detach_reset, taxel_embedding, attn_dropout:
            the spatial branch, as :class:`~tactile_zoo.models.tacformer.Tacformer`.
        hidden: T-GCN state width per taxel ``H``.
        temporal_pool: frame feature of the temporal branch: ``"mean"`` over taxels or ``"flatten"``.
        attn_dim: hidden width of the frame-scoring network.
        temporal_backend: ``"native"`` (eqs. 10-13) or ``"tgt"`` (torch_geometric_temporal's TGCN2, if importable).
        bin_size: input frames summed per model time step (1 = full time resolution).
        dropout: dropout on the fused vector.
        graph, graph_backend, lif_backend: as Tacformer.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``.
    """

    def __init__(self, spec: DatasetSpec, dim: int = 64, heads: int = 4, depth: int = 1, mlp_ratio: float = 0.0,
                 hops: int = 3, tau: float = 2.0, v_th: float = 1.0, surrogate: str = "atan",
                 detach_reset: bool = True, hidden: int = 32, temporal_pool: str = "mean", attn_dim: int = 32,
                 temporal_backend: str = "native", bin_size: int = 5, taxel_embedding: bool = True,
                 dropout: float = 0.1, attn_dropout: float = 0.0, pool: str = "mean", graph: str = "default",
                 graph_backend: str = "dense", lif_backend: str = "fused") -> None:
        super().__init__()
        if bin_size < 1:
            raise ConfigError(f"x_tacformer: bin_size must be >= 1, got {bin_size}")
        self.name, self.spec, self.bin_size = "x_tacformer", spec, int(bin_size)
        edge_index = spec.sensor.edge_index(graph)
        lif = LIFConfig(tau, v_th, surrogate, detach_reset, lif_backend)
        self.spatial = SpatialGraphAttention(
            spec.num_channels, dim, edge_index, spec.num_nodes, heads=heads, depth=depth, mlp_ratio=mlp_ratio,
            lif=lif, hops=hops, taxel_embedding=taxel_embedding, attn_dropout=attn_dropout,
            graph_backend=graph_backend, pool=pool)
        self.glob = nn.Linear(spec.num_globals, dim) if spec.num_globals else None
        self.readout_lif = lif.build()
        self.temporal = TemporalGraphAttention(spec.num_channels, hidden, edge_index, spec.num_nodes,
                                               pool=temporal_pool, attn_dim=attn_dim,
                                               temporal_backend=temporal_backend, graph_backend=graph_backend)
        self.temporal_norm = nn.LayerNorm(self.temporal.out_features)
        width = dim * (2 if self.glob is not None else 1) + self.temporal.out_features
        self.dropout = nn.Dropout(dropout)
        self.head = nn.Linear(width, spec.num_classes)

    def _advance(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        sp_state, mem, spike_sum, bins, tg_state = core if core is not None else (None, None, 0.0, 0, None)
        f, sp_state = self.spatial.run(xb, sp_state)  # (T', B, D)
        if self.glob is not None:
            f = torch.cat([f, self.glob(gb)], dim=-1)  # (T', B, 2D)
        s, mem = self.readout_lif(f, mem, return_mem=True)  # (T', B, W) spikes
        spike_sum = spike_sum + s.sum(0)
        bins = bins + s.shape[0]
        tg, tg_state = self.temporal.run(xb, tg_state)  # (B, F) attention-weighted frame features so far
        fused = torch.cat([spike_sum / bins, self.temporal_norm(tg)], dim=-1)  # fusion by concatenation
        return self.head(self.dropout(fused)), (sp_state, mem, spike_sum, bins, tg_state)
