"""DeepTactile (Guo, Long, Yu, Li, Chen, Yan, Li, Gu, Guo, "Event-driven Tactile Sensing With Dense Spiking Graph
Neural Networks", IEEE Transactions on Instrumentation and Measurement, 2024 in the release's citation; code:
github.com/GuoFM/DeepTactile).

A densely connected spiking graph network: every frame's taxel graph goes through a TAGConv stem and two dense blocks
of spiking graph convolutions (DenseNet's pre-activation order, with threshold-dependent batch norm and LIF neurons
as the activation), then a spiking multilayer perceptron; the class scores are the output spike rates::

    (B, T, N, C) -> TAGConv K=1 (C -> 64) -> tdBN -> LIF
    -> dense block: 3 x [tdBN -> LIF -> TAGConv K=1 (-> 128) -> tdBN -> LIF -> TAGConv K=3 (-> 32), concatenated]
    -> transition: tdBN -> LIF -> TAGConv K=1 (160 -> 80)
    -> dense block: 3 x [... as above] (80 -> 176) -> tdBN -> LIF -> flatten (N * 176) [++ g_t]
    -> Linear 128 -> LIF -> Linear 256 -> LIF -> Linear K -> LIF -> spike count / T (B, K)

As in SGnet (:mod:`.sgnet`), every graph, batch-norm and linear operation runs once over all ``T * B`` frames and
only the membrane recurrences loop over time. In evaluation mode the batch norms are per-frame affine maps, so the
model is causal and streams (:meth:`DeepTactile.step`). Model card: docs/models.md, section "`deeptactile`".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..data.sensors import NEUTOUCH, NEUTOUCH_HAND_EDGES
from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn import backend as switch
from ..nn.backend import GraphBackend, LIFBackend
from ..nn.graph import FrameGraphConv
from ..nn.lif import MultiStepLIF
from ..nn.tdbn import TdBatchNorm
from ..registry import recipe_file, register_model
from ._binned import BinnedStreamer

__all__ = ["DeepTactile"]

#: ``spike(lif, h)``: one LIF layer on time-major pre-activations ``h (S, B, ...)``, with or without carried state
Spike = Callable[[MultiStepLIF, Tensor], Tensor]
#: initialisations of the linear layers (see ``init`` in :class:`DeepTactile`)
_INITS = ("lecun", "he", "default")



class _DenseLayer(nn.Module):
    """One layer of a dense block: ``tdBN -> LIF -> TAGConv K=1 (-> bn_size * growth) -> tdBN -> LIF -> TAGConv
    (-> growth)``; its output is its input with the new ``growth`` channels appended."""

    def __init__(self, channels: int, growth: int, bottleneck: int, hops: int, conv: Callable[..., FrameGraphConv],
                 lif: Callable[[], MultiStepLIF], threshold: float, dropout: float) -> None:
        super().__init__()
        self.norm1, self.lif1 = TdBatchNorm(channels, threshold), lif()
        self.conv1 = conv(channels, bottleneck, K=1)
        self.norm2, self.lif2 = TdBatchNorm(bottleneck, threshold), lif()
        self.conv2 = conv(bottleneck, growth, K=hops)
        self.dropout = dropout

    def forward(self, h: Tensor, spike: Spike) -> Tensor:
        new = self.conv1(spike(self.lif1, self.norm1(h)))
        new = self.conv2(spike(self.lif2, self.norm2(new)))
        if self.dropout:  # on the new channels only, as the source's drop_rate
            new = F.dropout(new, self.dropout, self.training)
        return torch.cat([h, new], dim=-1)


class _Transition(nn.Module):
    """Between dense blocks: ``tdBN -> LIF -> TAGConv K=1`` to fewer channels."""

    def __init__(self, channels: int, out: int, conv: Callable[..., FrameGraphConv], lif: Callable[[], MultiStepLIF],
                 threshold: float) -> None:
        super().__init__()
        self.norm, self.lif = TdBatchNorm(channels, threshold), lif()
        self.conv = conv(channels, out, K=1)

    def forward(self, h: Tensor, spike: Spike) -> Tensor:
        return self.conv(spike(self.lif, self.norm(h)))


@register_model(
    "deeptactile",
    paper="Event-driven Tactile Sensing With Dense Spiking Graph Neural Networks",
    citation="F. Guo, X. Long, F. Yu, M. Li, C. Chen, J. Yan, Y. Li, F. Gu, S. Guo. Event-driven Tactile Sensing "
             "With Dense Spiking Graph Neural Networks. IEEE Transactions on Instrumentation and Measurement",
    year=2024,
    url="https://github.com/GuoFM/DeepTactile",
    description="Dense spiking graph network: a TAGConv stem and two dense blocks of 3 spiking graph-conv layers "
                "(tdBN, LIF, TAGConv K=1 then K=3, growth 32) with a transition, then a spiking MLP "
                "128-256-classes; scores are output spike rates (MSE to one-hot).",
    tags=["spiking", "graph"],
    inputs=["graph", "globals"],
    display_name="DeepTactile",
    family="dense spiking graph network (tdBN)",
    reference={"type": "article", "authors": ["Guo", "Long", "Yu", "Li", "Chen", "Yan", "Li", "Gu", "Guo"],
               "journal": "IEEE Transactions on Instrumentation and Measurement"},
    # small sizes for the contract suite (tests/models/test_zoo.py): one dense layer per block, narrow, one hidden
    # layer, so every kind of layer is still checked (0.9 M parameters at full size on NeuTouch, 30 k here)
    test_hparams={"block_config": [1, 1], "growth_rate": 8, "init_features": 16, "hidden": [32]},
    **recipe_file("tactile_zoo", "deeptactile"),
    causal=True,
    streaming=True,
    revision=1,  # 1: what it has computed since it was added (the revision its committed cells and outputs carry)
)
class DeepTactile(BinnedStreamer):
    """DeepTactile (Guo et al., IEEE TIM): a dense spiking graph network on every frame's taxel graph, then a
    spiking MLP; scores are output spike rates.

    Neuron (the source's ``tdlayer.py``, the same as SGnet's): ``mem = 0.2 * mem * (1 - spike_prev) + I``, ``spike =
    mem > 0.5``, membranes at 0 at the start of every sequence; rectangular surrogate (gradient 1 where
    ``|mem - 0.5| < 0.5``), reset not detached. tdBN (:class:`~tactile_zoo.nn.tdbn.TdBatchNorm`) scales to the same
    threshold 0.5 with ``alpha = 1``.

    Departures (ours): LeCun-normal Linear weights (``init="default"``, as the ``source`` recipe sets, restores the
    source's), the first linear layer sized for the sensor's taxels (the source hard-codes ST-MNIST's 100), global
    features joining the flattened spikes before it, ``bin_size`` to sum frames (1, the source's full time
    resolution, by default); all frames through each layer in one call (same function). Model card: docs/models.md,
    section "`deeptactile`: DeepTactile".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        growth_rate: channels each dense layer adds (source: 32).
        block_config: dense layers per block (source: (3, 3)).
        init_features: channels of the stem convolution (source: 64).
        bn_size: bottleneck width as a multiple of ``growth_rate`` (source: 4).
        compression: channel ratio of a transition (source: 0.5).
        hops: TAGConv ``K`` of each dense layer's second convolution (source: 3; the stem, bottleneck and
            transition convolutions have K = 1, as in the source).
        hidden: widths of the hidden linear layers (source: 128, 256).
        dropout: dropout on each dense layer's new channels in training (source: 0).
        beta, threshold, surrogate, surrogate_width, detach_reset: the LIF neurons (source: 0.2, 0.5, rect, 1.0,
            False); ``threshold`` also scales tdBN.
        bin_size: input frames summed per model time step (1: every frame, as the source; more is a departure).
        graph: the sensor graph kind, with ``graph_kwargs``; ``None`` (default) is the source's graph: on NeuTouch
            (its taxel positions) the hand-made 73-edge graph of the source's ``to_graph.py``
            (:data:`~tactile_zoo.data.sensors.NEUTOUCH_HAND_EDGES`), on other sensors their default graph.
        lif_backend: ``"fused"`` or ``"snntorch"``; graph_backend: ``"dense"`` or ``"pyg"``.
        init: the linear layers' weights: ``"lecun"`` (default: normal, std 1 / sqrt(fan_in); with the source's
            initialisation the last two LIF layers start silent), ``"he"`` (std sqrt(2 / fan_in), SGnet's default) or
            ``"default"`` (PyTorch's, as the source). Graph convolutions and tdBN keep PyG's and PyTorch's.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> rates ``(B, K)`` in [0, 1]; streaming:
        ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> running rates ``(B, K)``.
    """

    def __init__(self, spec: DatasetSpec, growth_rate: int = 32, block_config: tuple[int, ...] = (3, 3),
                 init_features: int = 64, bn_size: int = 4, compression: float = 0.5, hops: int = 3,
                 hidden: tuple[int, ...] = (128, 256), dropout: float = 0.0, beta: float = 0.2,
                 threshold: float = 0.5, surrogate: str = "rect", surrogate_width: float = 1.0,
                 detach_reset: bool = False, bin_size: int = 1, graph: str | None = None,
                 graph_kwargs: dict[str, Any] | None = None, lif_backend: str = "fused", graph_backend: str = "dense",
                 init: str = "lecun") -> None:
        super().__init__()
        block_config, hidden = tuple(int(b) for b in block_config), tuple(int(h) for h in hidden)
        if init not in _INITS:
            raise ConfigError(f"deeptactile: init must be one of {', '.join(_INITS)}, got {init!r}")
        if min(growth_rate, init_features, bn_size, *hidden, *block_config, 1) < 1 or not block_config or not hidden:
            raise ConfigError(f"deeptactile: widths and block sizes must be positive, got growth_rate={growth_rate}, "
                              f"init_features={init_features}, bn_size={bn_size}, block_config={block_config}, "
                              f"hidden={hidden}")
        if not 0.0 < compression <= 1.0 or not 0.0 <= dropout < 1.0:
            raise ConfigError(f"deeptactile: compression must lie in (0, 1] and dropout in [0, 1), got "
                              f"{compression} and {dropout}")
        if bin_size < 1:
            raise ConfigError(f"deeptactile: bin_size must be >= 1, got {bin_size}")
        lif_backend = switch.resolve(LIFBackend, lif_backend, "lif_backend", "deeptactile")
        graph_backend = switch.resolve(GraphBackend, graph_backend, "graph_backend", "deeptactile")
        self.name, self.spec, self.bin_size, self.init = "deeptactile", spec, int(bin_size), init
        n = spec.num_nodes
        if graph is None:  # the source's: its hand-made graph where it has one (NeuTouch), else the sensor's own
            hand = spec.sensor.positions == NEUTOUCH.positions
            graph, graph_kwargs = ("edges", {"pairs": NEUTOUCH_HAND_EDGES}) if hand else ("default", graph_kwargs)
        edge_index = spec.sensor.edge_index(graph, **(graph_kwargs or {}))

        def conv(c_in: int, c_out: int, K: int) -> FrameGraphConv:
            return FrameGraphConv(c_in, c_out, edge_index, n, kind="tag", K=K, backend=graph_backend)

        lif_kw = dict(beta=beta, threshold=threshold, reset="zero", surrogate=surrogate,
                      surrogate_width=surrogate_width, detach_reset=detach_reset, backend=lif_backend)

        def lif() -> MultiStepLIF:
            return MultiStepLIF(**lif_kw)

        self.stem = conv(spec.num_channels, init_features, K=1)
        self.stem_norm, self.stem_lif = TdBatchNorm(init_features, threshold), lif()
        units: list[nn.Module] = []
        channels = init_features
        for i, layers in enumerate(block_config):
            for _ in range(layers):
                units.append(_DenseLayer(channels, growth_rate, bn_size * growth_rate, hops, conv, lif, threshold,
                                          float(dropout)))
                channels += growth_rate
            if i < len(block_config) - 1:
                out = int(channels * compression)  # the source's int(): rounds down
                units.append(_Transition(channels, out, conv, lif, threshold))
                channels = out
        self.features = nn.ModuleList(units)
        self.out_norm, self.out_lif = TdBatchNorm(channels, threshold), lif()
        widths = (n * channels + spec.num_globals, *hidden, spec.num_classes)
        self.fcs = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.fc_lifs = nn.ModuleList(lif() for _ in self.fcs)
        for fc in self.fcs:
            self._init_classifier(fc)

    # ------------------------------------------------------------------------------------------------ computation
    def _trains(self, xb: Tensor, gb: Tensor | None, spike: Spike) -> Tensor:
        """The spike trains the classifier layer reads, ``(S, B, hidden[-1])``, from time-major bins ``xb (S, B, N,
        C)`` and ``gb (S, B, G)`` or None."""
        h = spike(self.stem_lif, self.stem_norm(self.stem(xb)))  # (S, B, N, 64): spikes
        for unit in self.features:
            h = unit(h, spike)
        s = spike(self.out_lif, self.out_norm(h)).flatten(2)  # (S, B, N * F), node-major as the source's view()
        if gb is not None:
            s = torch.cat([s, gb.to(s.dtype)], dim=-1)
        for fc, lif in zip(self.fcs[:-1], self.fc_lifs[:-1]):
            s = spike(lif, fc(s))
        return s

    def _advance(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        """Fold bins ``xb (S, B, N, C)`` into the state ``core`` (``None``: at rest): the running output rates
        ``(B, K)`` and ``(membranes, spike count, bins)``."""
        mems_in = iter(core[0]) if core is not None else None
        mems_out: list[Tensor] = []

        def spike(lif: MultiStepLIF, h: Tensor) -> Tensor:
            s, mem = lif(h, None if mems_in is None else next(mems_in), return_mem=True)
            mems_out.append(mem)
            return s

        out = spike(self.fc_lifs[-1], self.fcs[-1](self._trains(xb, gb, spike)))  # (S, B, K) output spikes
        count = out.sum(0) if core is None else core[1] + out.sum(0)
        steps = xb.shape[0] + (0 if core is None else core[2])
        return count / steps, (tuple(mems_out), count, steps)

    def forward_features(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """The spike trains the classifier reads, ``(B, T', hidden[-1])`` (no pooled vector: the scores are spike
        rates)."""
        return self._trains(*self._bins(x, g), lambda lif, h: lif(h)).transpose(0, 1)

    def forward_head(self, features: Tensor) -> Tensor:
        """Spike rates ``(B, K)`` from :meth:`forward_features`'s ``(B, T', hidden[-1])``."""
        return self.fc_lifs[-1](self.fcs[-1](features.transpose(0, 1))).mean(dim=0)

    def _init_classifier(self, layer: nn.Linear) -> None:
        """A linear layer's weights as ``init`` says (the constructor's and :meth:`reset_classifier`'s)."""
        if self.init != "default":  # normal, std gain / sqrt(fan_in): gain 1 ("lecun") or sqrt(2) ("he")
            nn.init.kaiming_normal_(layer.weight, nonlinearity="linear" if self.init == "lecun" else "relu")

