"""TactileSGNet (Gu, Sng, Taunyazov, Soh, "TactileSGNet: A Spiking Graph Neural Network for Event-based
Tactile Object Recognition", IROS 2020; code: github.com/clear-nus/TactileSGNet).

A graph convolution over the taxel graph of every frame feeds a spiking multilayer perceptron; the class scores are
the output spike rates::

    (B, T, N, C) -> TAGConv K=3 (C -> 64) -> LIF -> flatten (N * 64) [++ g_t] -> Linear 128 -> LIF -> Linear 256 -> LIF
    -> Linear K -> LIF -> spike count / T (B, K)

Every linear and graph operation runs once over all ``T * B`` frames; only the membrane recurrences loop over time
(fused, :class:`~tactile_zoo.nn.lif.MultiStepLIF`). The model is causal, and :meth:`SGNet.step` streams it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn import backend as switch
from ..nn.backend import Compute, GraphBackend, LIFBackend, WeightGrad
from ..nn.classifier import ClassifierMixin
from ..nn.event_graph_conv import event_graph_conv
from ..nn.event_graph_lif import event_graph_lif
from ..nn.event_linear import EventList, event_linear
from ..nn.graph import FrameGraphConv
from ..nn.lif import MultiStepLIF
from ..registry import recipe_file, register_model
from ._inputs import check_inputs

__all__ = ["SGNet", "SGNetState"]

@dataclass
class SGNetState:
    """Streaming state: the membrane of each LIF layer ``(B, width)``, the output spike counts ``(B, K)`` and the
    number of steps read."""

    mems: tuple[Tensor, ...]
    count: Tensor
    steps: int = 0


@register_model(
    "sgnet",
    paper="TactileSGNet: A Spiking Graph Neural Network for Event-based Tactile Object Recognition",
    citation="F. Gu, W. Sng, T. Taunyazov, H. Soh. TactileSGNet: A Spiking Graph Neural Network for Event-based "
             "Tactile Object Recognition. IEEE/RSJ International Conference on Intelligent Robots and Systems "
             "(IROS), 2020",
    year=2020,
    url="https://github.com/clear-nus/TactileSGNet",
    description="Spiking graph network: TAGConv (K=3, 64 channels) on the taxel graph of every frame, LIF, then a "
                "spiking MLP 128-256-classes; scores are output spike rates (MSE to one-hot).",
    tags=["spiking", "graph", "table1"],
    inputs=["graph", "globals"],
    display_name="SGnet",
    family="spiking graph network",
    reference={"type": "conference-paper",
               "authors": ["Gu, Fuqiang", "Sng, Weicong", "Taunyazov, Tasbolat", "Soh, Harold"],
               "collection-title": "IEEE/RSJ International Conference on Intelligent Robots and Systems (IROS)",
               "notes": "the Ev-Objects and Ev-Containers datasets"},
    **recipe_file("tactile_zoo", "sgnet"),
    causal=True,
    streaming=True,
    # 2: the NeuTouch default graph is the reference's exact edge list; 3: the event products by default (the same
    # spikes as 2, gradients within 1e-5 of its own: tests/models/test_revision_paths.py)
    revision=3,
    revisions={2: {"lif_backend": "fused", "graph_backend": "dense", "graph_weight_grad": "autograd",
                   "compute": "dense"},
               3: {"lif_backend": "fused", "graph_backend": "dense", "graph_weight_grad": "autograd",
                   "compute": "event"}},
)
class SGNet(ClassifierMixin, nn.Module):
    """TactileSGNet (Gu et al., IROS 2020): TAGConv on every frame's taxel graph, then a spiking MLP; scores are
    output spike rates.

    Neuron (the reference's, snnTorch ``Leaky(beta=0.2, threshold=0.5, reset_mechanism="zero")``):
    ``mem = 0.2 * mem * (1 - spike_prev) + I``, ``spike = mem > 0.5``, membranes at 0 at the start of every
    sequence; rectangular surrogate, reset not detached.

    Departures (ours): He-normal Linear weights and batch 8 (``init="default"``, ``batch_size=1`` restore the
    reference), all frames through each layer in one call (same function); model card: docs/models.md, section
    "`sgnet`: TactileSGNet".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        graph_channels: TAGConv output channels per taxel (reference: 64).
        hops: TAGConv ``K`` (reference: 3).
        hidden: widths of the hidden linear layers (reference: 128, 256).
        beta, threshold, surrogate, surrogate_width, detach_reset: the LIF neurons (reference: 0.2, 0.5, rect,
            1.0, False).
        graph: the sensor graph kind (``"default"``, ``"mst"``, ``"knn"``...), with ``graph_kwargs``.
        lif_backend: ``"fused"`` or ``"snntorch"``; graph_backend: ``"dense"`` or ``"pyg"``.
        init: ``"he"`` (He-normal Linear weights) or ``"default"`` (PyTorch's, as the reference).
        graph_weight_grad: ``"autograd"`` (default) or ``"fast"`` (opt-in): the TAGConv weights' gradient summed in
            another order, which skips a copy of the layer's output gradient (a training step on Ev-Objects at
            batch 8 about 8% faster on 1 CPU thread); the same function, rounded differently
            (:class:`~tactile_zoo.nn.graph.FrameGraphConv`'s ``weight_grad``).
        compute: ``"event"`` (default since revision 3) or ``"dense"`` (revision 2's): the graph convolution as
            one product over the input events (:func:`~tactile_zoo.nn.event_graph_conv.event_graph_conv`) and the
            first linear layer over the first LIF's spikes (:func:`~tactile_zoo.nn.event_linear.event_linear`); the
            same function, rounded differently (the same spikes, gradients within about 1e-6 relative), so each
            default is its own revision (``create_model("sgnet", spec, revision=2)`` builds the dense one). Off CPU
            it runs the dense products, which are its oracle; it needs ``graph_backend="dense"`` (with ``"pyg"``,
            pass ``compute="dense"``).

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> rates ``(B, K)`` in [0, 1]; streaming:
        ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> running rates ``(B, K)``.
    """

    def __init__(self, spec: DatasetSpec, graph_channels: int = 64, hops: int = 3, hidden: tuple[int, ...] = (128, 256),
                 beta: float = 0.2, threshold: float = 0.5, surrogate: str = "rect", surrogate_width: float = 1.0,
                 detach_reset: bool = False, graph: str = "default", graph_kwargs: dict[str, Any] | None = None,
                 lif_backend: str = "fused", graph_backend: str = "dense", init: str = "he",
                 graph_weight_grad: str = "autograd", compute: str = "event") -> None:
        super().__init__()
        if init not in ("he", "default"):
            raise ConfigError(f"sgnet: init must be 'he' or 'default', got {init!r}")
        compute = switch.resolve_compute(compute, graph_backend, "sgnet")  # the compute paths, checked up front
        lif_backend = switch.resolve(LIFBackend, lif_backend, "lif_backend", "sgnet")
        graph_backend = switch.resolve(GraphBackend, graph_backend, "graph_backend", "sgnet")
        graph_weight_grad = switch.resolve(WeightGrad, graph_weight_grad, "graph_weight_grad", "sgnet")
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1 or graph_channels < 1:
            raise ConfigError(f"sgnet: widths must be positive, got graph_channels={graph_channels}, hidden={hidden}")
        self.spec, self.init, self.compute = spec, init, compute
        n = spec.num_nodes
        edge_index = spec.sensor.edge_index(graph, **(graph_kwargs or {}))
        self.gc = FrameGraphConv(spec.num_channels, graph_channels, edge_index, n, kind="tag", K=hops,
                                 backend=graph_backend, weight_grad=graph_weight_grad)
        widths = (n * graph_channels + spec.num_globals, *hidden, spec.num_classes)
        self.fcs = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
        if init == "he":  # keeps every layer spiking at initialisation (see the model card)
            for fc in self.fcs:
                nn.init.kaiming_normal_(fc.weight)
        lif_kw = dict(beta=beta, threshold=threshold, reset="zero", surrogate=surrogate,
                      surrogate_width=surrogate_width, detach_reset=detach_reset, backend=lif_backend)
        self.lifs = nn.ModuleList(MultiStepLIF(**lif_kw) for _ in range(len(widths)))
        self._widths = (n * graph_channels, *widths[1:])  # the width of each LIF layer

    def _spikes(self, x: Tensor, g: Tensor | None) -> Tensor:
        """The spike trains the classifier layer reads, time-major ``(T, B, width)``."""
        g = check_inputs("sgnet", self.spec, x, g)
        steps, batch = x.shape[1], x.shape[0]
        x = x.transpose(0, 1)  # (T, B, N, C): time-major before the convolution, where C is small
        events = None  # the first LIF's spike list, where the fused first layer gives it
        if self.compute is Compute.EVENT:  # convolution -> LIF -> spike list in one loop, without the current
            s, events = event_graph_lif(self.gc, self.lifs[0], x)  # (T, B, N * F)
        else:
            s = self.lifs[0](self.gc(x).reshape(steps, batch, -1))  # (T, B, N * F)
        if g is not None:
            s = torch.cat([s, g.transpose(0, 1).to(s.dtype)], dim=-1)  # (T, B, N * F + G)
            events = None
        for i, (fc, lif) in enumerate(zip(self.fcs[:-1], self.lifs[1:-1])):
            s = lif(self._first(s, events) if i == 0 else fc(s))  # (T, B, width)
        return s

    def _conv(self, x: Tensor) -> Tensor:
        """The graph convolution, over the input events with ``compute="event"``."""
        return event_graph_conv(self.gc, x) if self.compute is Compute.EVENT else self.gc(x)

    def _first(self, s: Tensor, events: EventList | None = None) -> Tensor:
        """The first linear layer, over the first LIF's spikes (their ``events`` where known) with
        ``compute="event"``."""
        fc = self.fcs[0]
        return event_linear(s, fc.weight, fc.bias, events) if self.compute is Compute.EVENT else fc(s)

    def _rates(self, s: Tensor) -> Tensor:
        """The spiking classifier: the last layer and its LIF on ``s (T, B, width)``, then the output spike rates."""
        return self.lifs[-1](self.fcs[-1](s)).mean(dim=0)  # (B, K) output spike count / T

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self._rates(self._spikes(x, g))

    def forward_features(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """The spike trains the classifier reads, ``(B, T, width)`` (no pooled vector: the scores are spike rates)."""
        return self._spikes(x, g).transpose(0, 1)

    def forward_head(self, features: Tensor) -> Tensor:
        """Spike rates ``(B, K)`` from :meth:`forward_features`'s ``(B, T, width)``."""
        return self._rates(features.transpose(0, 1))

    def reset_classifier(self, num_classes: int) -> None:
        super().reset_classifier(num_classes)
        self._widths = (*self._widths[:-1], num_classes)  # the output LIF's membrane width, for streaming

    def _init_classifier(self, layer: nn.Linear) -> None:
        if self.init == "he":
            nn.init.kaiming_normal_(layer.weight)

    def init_state(self, batch_size: int) -> SGNetState:
        """Membranes at rest and no output spikes yet, on the model's device and dtype."""
        ref = self.fcs[0].weight
        mems = tuple(ref.new_zeros(batch_size, w) for w in self._widths)
        return SGNetState(mems=mems, count=ref.new_zeros(batch_size, self.spec.num_classes), steps=0)

    def step(self, x_t: Tensor, g_t: Tensor | None, state: SGNetState) -> tuple[Tensor, SGNetState]:
        """One frame: ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> (running rates ``(B, K)``, new state). After
        step ``t`` the rates equal :meth:`forward` on the frames ``0..t``."""
        g_t = check_inputs("sgnet", self.spec, x_t, g_t, per_step=True)
        s, mem = self.lifs[0].step(self._conv(x_t).reshape(x_t.shape[0], -1), state.mems[0])  # (B, N * F)
        mems = [mem]
        if g_t is not None:
            s = torch.cat([s, g_t.to(s.dtype)], dim=-1)
        for i, (fc, lif, m) in enumerate(zip(self.fcs, self.lifs[1:], state.mems[1:])):
            s, m = lif.step(self._first(s) if i == 0 else fc(s), m)
            mems.append(m)
        count = state.count + s
        steps = state.steps + 1
        return count / steps, SGNetState(mems=tuple(mems), count=count, steps=steps)
