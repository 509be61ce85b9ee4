"""Tacformer: the spatial graph attention module of X-Tacformer, on its own.

Paper: "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition" (Tacformer is its spatial branch,
reported separately in its Table I; no code published). Shapes for NeuTouch (N = 39, C = 2, T = 250) and the
defaults (D = 64, 4 heads, bins of 5 frames)::

    x (B, T, N, C) -> events summed over bins of 5 frames, time-major          (T' = 50, B, N, C)
    -> TAGConv (K = 3, PyG semantics) on every frame, + learned taxel embedding (T', B, N, D)
    -> depth x residual [z = z + MSA-SNN(z)] [z = z + MLP(z)], over the taxels of each frame
    -> tokens flattened, Linear N*D -> D, LayerNorm [++ Linear(G -> D) of the bin's mean globals]   (T', B, D or 2D)
    -> LIF over time -> running spike rate -> LayerNorm -> dropout -> Linear -> logits (B, K)

MSA-SNN (eqs. 7-9): ``Q, K, V = LN(Linear(LIF(LN(Linear(X)))))``, ``softmax(Q K^T / sqrt(d_k)) V``, output
``LN(Linear(LIF(.)))``; every LIF is the paper's (eqs. 2-4, V_reset = 0). Attention stays inside a frame, so only
LIF membranes carry over time and :meth:`Tacformer.step` streams exactly.

Also home of the piece X-Tacformer shares, :class:`SpatialGraphAttention`; the frame bins and their streaming
machinery (:func:`bin_frames`, :class:`BinnedStreamer`) live in :mod:`._binned`.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn import backend as switch
from ..nn.attention import SpikingSelfAttention
from ..nn.backend import Attention, GraphBackend, LIFBackend
from ..nn.graph import FrameGraphConv
from ..nn.lif import LIFConfig
from ..registry import recipe_file, register_model
from ._binned import BinnedStreamer

__all__ = ["Tacformer", "SpatialGraphAttention", "SpikingMLP"]

PAPER = "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition"


class SpikingMLP(nn.Module):
    """The feed-forward half of a spiking transformer block: LN(Linear(LIF(LN(Linear(x))))), same pattern as the
    MSA-SNN chains. ``(T, *, D) -> (T, *, D)``; the LIF membrane is the state."""

    def __init__(self, dim: int, hidden: int, lif: LIFConfig) -> None:
        super().__init__()
        self.fc1, self.norm1, self.lif = nn.Linear(dim, hidden), nn.LayerNorm(hidden), lif.build()
        self.fc2, self.norm2 = nn.Linear(hidden, dim), nn.LayerNorm(dim)

    def run(self, x: Tensor, mem: Tensor | None = None) -> tuple[Tensor, Tensor]:
        s, mem = self.lif(self.norm1(self.fc1(x)), mem, return_mem=True)
        return self.norm2(self.fc2(s)), mem


class SpatialGraphAttention(nn.Module):
    """Per-frame graph convolution, spiking self-attention over the taxels of each frame, pooling over taxels.

    ``x (T, B, N, C)`` -> TAGConv (K hops) -> ``(T, B, N, D)`` taxel tokens (+ a learned per-taxel embedding) ->
    ``depth`` residual blocks ``z = z + MSA(z)`` [``z = z + MLP(z)``] -> pooled over taxels (``"flatten"``: the
    ``N * D`` tokens projected to ``D``; ``"mean"``) -> LayerNorm -> ``(T, B, D)`` frame features. Attention never
    crosses frames, so only LIF membranes carry over time (:meth:`run` takes and returns them). ``attention``
    picks the MSA blocks' implementation of eq. 8 (:data:`~tactile_zoo.nn.attention.ATTENTION_KINDS`).
    """

    def __init__(self, in_channels: int, dim: int, edge_index: Tensor, num_nodes: int, *, heads: int, depth: int,
                 mlp_ratio: float, lif: LIFConfig, hops: int, taxel_embedding: bool, attn_dropout: float,
                 graph_backend: str, pool: str = "flatten", attention: str = "fused") -> None:
        super().__init__()
        if pool not in ("mean", "flatten"):
            raise ConfigError(f"pool must be 'mean' or 'flatten', got {pool!r}")
        # checked here too: depth = 0 builds no attention block to check it
        attention = switch.resolve(Attention, attention, "attention", "SpatialGraphAttention")
        self.gc = FrameGraphConv(in_channels, dim, edge_index, num_nodes, kind="tag", K=hops, backend=graph_backend)
        self.embed = nn.Parameter(torch.randn(num_nodes, dim) * 0.02) if taxel_embedding else None
        self.attn = nn.ModuleList([SpikingSelfAttention(dim, heads, lif, attn_dropout, attention)
                                   for _ in range(depth)])
        hidden = round(dim * mlp_ratio)
        self.mlp = nn.ModuleList([SpikingMLP(dim, hidden, lif) for _ in range(depth)]) if hidden > 0 else None
        # flatten keeps which taxel is which: (N * D) -> D, one matmul over all frames
        self.pool = nn.Linear(num_nodes * dim, dim) if pool == "flatten" else None
        self.norm = nn.LayerNorm(dim)

    def run(self, x: Tensor, state: list[Any] | None = None) -> tuple[Tensor, list[Any]]:
        state = list(state) if state is not None else [None] * (2 * len(self.attn))
        z = self.gc(x)  # (T, B, N, D)
        if self.embed is not None:
            z = z + self.embed
        new_state: list[Any] = []
        for i, attn in enumerate(self.attn):
            a, st = attn.run(z, state[2 * i])
            z = z + a
            new_state.append(st)
            if self.mlp is not None:
                m, st = self.mlp[i].run(z, state[2 * i + 1])
                z = z + m
            else:
                st = None
            new_state.append(st)
        pooled = z.mean(dim=2) if self.pool is None else self.pool(z.flatten(2))  # (T, B, D)
        return self.norm(pooled), new_state


@register_model(
    "tacformer",
    paper=PAPER,
    year=2024,
    description="Spatial graph attention of X-Tacformer: per-frame TAGConv over the taxel graph, spiking multi-head "
                "self-attention (MSA-SNN) over the taxels of each frame, LIF over time, spike-rate read-out.",
    tags=["spiking", "graph", "attention", "table1"],
    inputs=["graph", "globals"],
    display_name="Tacformer",
    family="spiking graph attention (spatial)",
    reference={"type": "article", "authors": [{"name": "The X-Tacformer authors"}],
               "notes": "the Table I protocol reproduced in benchmarks/results/paper-table1"},
    **recipe_file("tactile_zoo", "tacformer"),
    causal=True,
    streaming=True,
    # 2: the NeuTouch default graph is the reference's exact edge list; 3: the explicit attention product by default
    # (the same spikes as 2, gradients within 1e-5 of its own: tests/models/test_revision_paths.py)
    revision=3,
    revisions={2: {"graph_backend": "dense", "lif_backend": "fused", "attention": "fused"},
               3: {"graph_backend": "dense", "lif_backend": "fused", "attention": "explicit"}},
)
class Tacformer(BinnedStreamer):
    """Tacformer: X-Tacformer's spatial graph attention module on its own (structure in the module docstring).

    Departures: the paper gives no sizes or training settings, so widths, heads, one block without MLP, frames
    summed in bins of ``bin_size`` and the flatten pooling are ours. Model card: docs/models.md, section
    "`tacformer`: Tacformer (spatial graph attention)".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        dim: token width ``D``.
        heads: attention heads.
        depth: residual MSA(-MLP) blocks.
        mlp_ratio: hidden width of the spiking MLP as a multiple of ``D``; 0 (default) leaves the MLP out.
        hops: TAGConv hops ``K``.
        tau, v_th, surrogate, detach_reset: every LIF (:class:`~tactile_zoo.nn.lif.LIFConfig`).
        bin_size: input frames summed per model time step (1 = the full time resolution).
        taxel_embedding: add a learned vector per taxel to its token.
        pool: frame feature from the tokens: ``"flatten"`` (``N * D -> D``, keeps which taxel is which) or
            ``"mean"`` over taxels.
        readout_norm: LayerNorm on the spike-rate vector before the classifier.
        dropout: dropout on the read-out vector; ``attn_dropout`` on the attention weights.
        graph: the sensor graph kind (``"default"``: the sensor's own).
        graph_backend, lif_backend: implementations of the shared operators (same results).
        attention: the MSA-SNN's attention product (eq. 8): ``"explicit"`` (batched matmuls with the softmax kept
            for the backward: on CPU faster for the 39 NeuTouch taxels; the default since revision 3) or ``"fused"``
            (``scaled_dot_product_attention``, revision 2's); the same up to float rounding, each default its own
            revision (``create_model("tacformer", spec, revision=2)`` builds the fused one).

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``; streaming ``x_t (B, N, C)``,
        ``g_t (B, G)`` or None -> ``(B, num_classes)``.
    """

    #: the final classifier layer (X-Tacformer's too), which ``create_model(..., pretrained=..., new_head=True)``
    #: starts afresh
    zoo_head = "head"

    def __init__(self, spec: DatasetSpec, dim: int = 64, heads: int = 4, depth: int = 1, mlp_ratio: float = 0.0,
                 hops: int = 3, tau: float = 2.0, v_th: float = 1.0, surrogate: str = "atan",
                 detach_reset: bool = True, bin_size: int = 5, taxel_embedding: bool = True, pool: str = "flatten",
                 readout_norm: bool = True, dropout: float = 0.1, attn_dropout: float = 0.0, graph: str = "default",
                 graph_backend: str = "dense", lif_backend: str = "fused", attention: str = "explicit") -> None:
        super().__init__()
        if bin_size < 1:
            raise ConfigError(f"{type(self).__name__}: bin_size must be >= 1, got {bin_size}")
        owner = type(self).__name__  # the compute paths, checked before anything is built
        attention = switch.resolve(Attention, attention, "attention", owner)
        graph_backend = switch.resolve(GraphBackend, graph_backend, "graph_backend", owner)
        lif_backend = switch.resolve(LIFBackend, lif_backend, "lif_backend", owner)
        self.name, self.spec, self.bin_size = "tacformer", spec, int(bin_size)
        self.lif_config = LIFConfig(tau, v_th, surrogate, detach_reset, lif_backend)
        self.spatial = SpatialGraphAttention(
            spec.num_channels, dim, spec.sensor.edge_index(graph), spec.num_nodes, heads=heads, depth=depth,
            mlp_ratio=mlp_ratio, lif=self.lif_config, hops=hops, taxel_embedding=taxel_embedding,
            attn_dropout=attn_dropout, graph_backend=graph_backend, pool=pool, attention=attention)
        self.glob = nn.Linear(spec.num_globals, dim) if spec.num_globals else None
        self.rate_width = dim * (2 if self.glob is not None else 1)
        self.readout_lif = self.lif_config.build()
        self.rate_norm = nn.LayerNorm(self.rate_width) if readout_norm else nn.Identity()
        self.dropout = nn.Dropout(dropout)
        self.head = nn.Linear(self.rate_width, spec.num_classes)

    def _spatial_rate(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        """Fold bins ``xb (T', B, N, C)`` into the spatial branch; the (normalised) spike rate so far ``(B, W)``."""
        sp_state, mem, spike_sum, bins = core if core is not None else (None, None, 0.0, 0)
        f, sp_state = self.spatial.run(xb, sp_state)  # (T', B, D)
        if self.glob is not None:
            f = torch.cat([f, self.glob(gb)], dim=-1)  # (T', B, 2D)
        s, mem = self.readout_lif(f, mem, return_mem=True)  # (T', B, W) spikes
        spike_sum = spike_sum + s.sum(0)  # (B, W)
        bins = bins + s.shape[0]
        return self.rate_norm(spike_sum / bins), (sp_state, mem, spike_sum, bins)

    def _features(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        return self._spatial_rate(xb, gb, core)

    def forward_head(self, features: Tensor) -> Tensor:
        return self.head(self.dropout(features))
