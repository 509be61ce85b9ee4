"""The multi-barrel SNN, shared-parameter variant (Zhu, Hu, Zhou, Du, Li, "Localist Topographic Expert Routing: A
Barrel Cortex-Inspired Modular Network for Sensorimotor Processing", NeurIPS 2025; code:
github.com/fun0515/MultiBarrelModel, ``SharedMultiBarrel4EvTask.py`` with the parts of ``MultiBarrel4EvTask.py``).

Every taxel drives one cortical column ("barrel") of ``P = 8`` populations of ``S = 32`` adaptive LIF neurons; all
columns share their weights. Shapes for NeuTouch (N = 39, C = 2, T = 250) and the defaults::

    x (B, T, N, C) -> per taxel: Conv1d 64 (k 21, dilation 3, stride 2) -> BN -> GELU -> Conv1d 64 (k 21, dilation 3)
        -> BN                                                                     (T' = 35, B, N, 64) "thalamic" input
    -> per step t, population i = 0..7 in turn (the later ones already see this step's spikes of the earlier ones):
        I_i = BN(Linear 64->32 of the input) + sum over the source populations j of BN(Linear 32->32 of s_j)
              + top-k routed read of the neighbouring columns (tactile_zoo.nn.routing)
        s_i = ALIF_i(I_i)                                                         (tactile_zoo.nn.alif)
    -> spikes of populations 4..7 (layers 5/6) over time                          (B, 128, T', N)
    -> Conv2d 512 (kernel 11 x N) -> BN -> GELU -> mean over time and taxels      (B, 512)
    -> Linear 256 -> LayerNorm -> GELU -> Linear K                                logits (B, K)

About 28.4M parameters on NeuTouch, 28.1M of them in the read-out convolution (its kernel spans every taxel). The
model reads the whole sequence (the read-out pools over time), so it is not causal. Quirks of the source and the
zoo's decision on each: docs/models.md, section "`multibarrel`: multi-barrel SNN".
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn.alif import AdaptiveLIF
from ..nn.classifier import ClassifierMixin
from ..nn.routing import NeighbourTopKRouter, nearest_neighbours
from ..registry import recipe_file, register_model
from ._inputs import check_inputs

__all__ = ["MultiBarrel", "CONNECTIONS", "OUTPUTS", "convert_released"]

#: which population feeds which, ``CONNECTIONS[j][i] = 1`` when population j projects to population i (the source's
#: eight excitatory types L2Pyr, L3Pyr, SSPyr, Pyr, STPyr, TTPyr, CTPyr, CCPyr; self-connections included)
CONNECTIONS = ((1, 1, 0, 0, 1, 0, 0, 0), (1, 1, 1, 1, 0, 1, 0, 0), (1, 1, 1, 1, 0, 0, 1, 0), (1, 1, 1, 1, 0, 0, 1, 0),
               (1, 1, 0, 0, 1, 0, 1, 0), (0, 0, 1, 1, 0, 1, 1, 0), (0, 0, 1, 1, 1, 0, 1, 1), (0, 0, 1, 1, 1, 1, 1, 1))
#: the populations whose spikes the read-out sees (layers 5 and 6)
OUTPUTS = (4, 5, 6, 7)
OUTPUT_KINDS = ("logits", "softmax")



@register_model(
    "multibarrel",
    paper="Localist Topographic Expert Routing: A Barrel Cortex-Inspired Modular Network for Sensorimotor Processing",
    citation="T. Zhu, D. Hu, J. Zhou, K. Du, A. Li. Localist Topographic Expert Routing: A Barrel Cortex-Inspired "
             "Modular Network for Sensorimotor Processing. Advances in Neural Information Processing Systems "
             "(NeurIPS), 2025",
    year=2025,
    url="https://github.com/fun0515/MultiBarrelModel",
    description="Multi-barrel SNN, shared-parameter variant: a dilated temporal Conv1d per taxel, then one column of "
                "8 adaptive-LIF populations per taxel (shared weights, top-k routing between neighbouring columns), "
                "a Conv2d read-out over time x taxels, an MLP classifier.",
    tags=["spiking", "graph", "convolutional"],
    inputs=["graph"],
    display_name="multi-barrel SNN",
    family="spiking columns per taxel, top-k routing between neighbours",
    reference={"type": "conference-paper", "authors": ["Zhu, T.", "Hu, D.", "Zhou, J.", "Du, K.", "Li, A."],
               "conference": {"name": "Advances in Neural Information Processing Systems (NeurIPS)"}},
    # small sizes for the contract suite (tests/models/test_zoo.py): 28.4 M parameters at full size on NeuTouch
    test_hparams={"channels": 8, "kernel_size": 3, "dilation": 1, "readout_channels": 6, "readout_kernel": 2,
                  "hidden": 5, "gate_hidden": 7},
    **recipe_file("tactile_zoo", "multibarrel"),
    causal=False,
    streaming=False,
    # revision 2 (selectable, not the default): the ALIF step as one compiled kernel forward and one backward on CPU,
    # the same spikes as revision 1 and gradients within 1e-5 of its own (tests/models/test_revision_paths.py); in a
    # bench cell no faster (4.63 against 4.66 CPU-hours an Ev-Objects cell), 2.2 GB lighter (docs/performance.md)
    revision=1,
    revisions={1: {"alif_backend": "torch"}, 2: {"alif_backend": "compiled"}},
)
class MultiBarrel(ClassifierMixin, nn.Module):
    """Multi-barrel SNN, shared-parameter variant (Zhu et al., NeurIPS 2025); pipeline in the module docstring.

    Defaults are the source's, with its quirks fixed as the zoo's recipe runs it: logits out, BatchNorm trained
    normally, no noise and a fixed start at test time; the ``source`` recipe turns the three back on. A sequence
    shorter than :attr:`min_steps` (201 frames by default) is zero-padded at the end; the neighbours are each taxel's
    nearest ones on the sensor (``min(4, N - 1)``). Model card: docs/models.md, section "`multibarrel`".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        channels: the temporal convolutions' channels (source: 64). kernel_size, dilation, stride: theirs (21, 3, 2).
        population: neurons per population, ``S`` (source: 32).
        neighbours: nearest taxels each column reads (source: 4; at most ``N - 1``). route_ratio: the fraction of
            the ``neighbours * 8`` groups it reads (source: 0.2, i.e. 6). gate_hidden: the gate's width (256).
        readout_channels, readout_kernel, hidden: the read-out convolution's channels and time extent, the MLP's
            hidden width (source: 512, 11, 256).
        tau_m_init, tau_adp_init, init_b: the means of the membrane and adaptation time constants and the initial
            adaptation trace (the source's training call: 4.34378016, 9.90546331, 0.46028508).
        threshold, beta: the baseline threshold and adaptation strength (source: 0.1 and 1.8).
        noise_std: the membrane noise in training (source: 1).
        eval_noise: at test time too, noise on the membranes and a random start (U(0, 1) membranes and spikes, as in
            training); off: no noise, membranes and spikes start at 0.5, the mean of that draw (source: on).
        output: ``"logits"`` or ``"softmax"`` (the source's forward returns probabilities, which its training then
            feeds to cross-entropy).
        bn_train_steps: ``None`` (BatchNorm as usual) or a count of training forward passes after which every
            BatchNorm layer stays in eval mode, training included (source: 1; see the card).
        alif_backend: how each population's ALIF step runs (:class:`~tactile_zoo.nn.alif.AdaptiveLIF`'s
            ``backend``): ``"torch"`` (revision 1, the default) or ``"compiled"`` (revision 2); the same spikes.

    Shapes:
        ``x (B, T, N, C)``, ``g`` ignored -> logits (or probabilities) ``(B, K)``.
    """

    def __init__(self, spec: DatasetSpec, channels: int = 64, kernel_size: int = 21, dilation: int = 3,
                 stride: int = 2, population: int = 32, neighbours: int = 4, route_ratio: float = 0.2,
                 gate_hidden: int = 256, readout_channels: int = 512, readout_kernel: int = 11, hidden: int = 256,
                 tau_m_init: float = 4.34378016, tau_adp_init: float = 9.90546331, init_b: float = 0.46028508,
                 threshold: float = 0.1, beta: float = 1.8, noise_std: float = 1.0, eval_noise: bool = False,
                 output: str = "logits", bn_train_steps: int | None = None, alif_backend: str = "torch") -> None:
        super().__init__()
        n = spec.num_nodes
        if output not in OUTPUT_KINDS:
            raise ConfigError(f"multibarrel: output must be one of {', '.join(OUTPUT_KINDS)}, got {output!r}")
        if n < 2:
            raise ConfigError(f"multibarrel: needs at least 2 taxels (each column reads its neighbours), got {n}")
        if min(channels, kernel_size, dilation, stride, population, neighbours, gate_hidden, readout_channels,
               readout_kernel, hidden) < 1:
            raise ConfigError("multibarrel: sizes, kernel sizes, dilation, stride and neighbours must be positive")
        if bn_train_steps is not None and bn_train_steps < 0:
            raise ConfigError(f"multibarrel: bn_train_steps must be >= 0 or None, got {bn_train_steps!r}")
        if noise_std < 0:
            raise ConfigError(f"multibarrel: noise_std must be >= 0, got {noise_std!r}")
        self.spec, self.output = spec, output
        self.noise_std, self.eval_noise, self.init_b = float(noise_std), bool(eval_noise), float(init_b)
        span = dilation * (kernel_size - 1)
        self.compressor = nn.Sequential(
            nn.Conv1d(spec.num_channels, channels, kernel_size, stride=stride, dilation=dilation),
            nn.BatchNorm1d(channels), nn.GELU(),
            nn.Conv1d(channels, channels, kernel_size, dilation=dilation), nn.BatchNorm1d(channels))
        #: the shortest input the convolutions take: the read-out needs ``readout_kernel`` compressed steps
        self.min_steps = (readout_kernel + span - 1) * stride + span + 1
        pops = len(CONNECTIONS)
        self.population = population
        self.thalamic = nn.ModuleList(_Link(channels, population) for _ in range(pops))
        self.sources = tuple(tuple(j for j in range(pops) if CONNECTIONS[j][i]) for i in range(pops))
        self.links = nn.ModuleList(nn.ModuleList(_Link(population, population) for _ in src) for src in self.sources)
        self.neurons = nn.ModuleList(AdaptiveLIF(population, tau_m_init, tau_adp_init, threshold, beta,
                                                 backend=alif_backend) for _ in range(pops))
        positions = torch.tensor(spec.sensor.positions, dtype=torch.float32)
        self.router = NeighbourTopKRouter(channels, nearest_neighbours(positions, min(neighbours, n - 1)), pops,
                                          population, route_ratio, gate_hidden)
        self.readout = nn.Sequential(_SpanConv2d(population * len(OUTPUTS), readout_channels, (readout_kernel, n)),
                                     nn.BatchNorm2d(readout_channels), nn.GELU())
        self.classifier = nn.Sequential(nn.Linear(readout_channels, hidden), nn.LayerNorm(hidden), nn.GELU(),
                                        nn.Linear(hidden, spec.num_classes))
        self.zoo_head = "classifier.3"
        self.bn_train_steps = bn_train_steps
        if bn_train_steps is not None:  # a buffer, so that a checkpoint remembers whether BatchNorm froze
            self.register_buffer("bn_steps_seen", torch.zeros((), dtype=torch.long))

    # ------------------------------------------------------------------------------------------ BatchNorm freezing
    def _bn_frozen(self) -> bool:
        return self.bn_train_steps is not None and int(self.bn_steps_seen) >= self.bn_train_steps

    def train(self, mode: bool = True) -> MultiBarrel:
        super().train(mode)
        if mode and self._bn_frozen():  # the source's model.eval() after the first epoch, never undone
            for m in self.modules():
                if isinstance(m, nn.modules.batchnorm._BatchNorm):
                    m.eval()
        return self

    # ------------------------------------------------------------------------------------------------- forward
    def _stochastic(self) -> bool:
        return self.training or self.eval_noise

    def initial_state(self, batch: int, like: Tensor) -> tuple[Tensor, Tensor]:
        """Membranes and spikes at the start, ``(P, B, N, S)`` each: U(0, 1) draws when the model is stochastic (in
        training; at test time with ``eval_noise``), else 0.5."""
        shape = (len(self.neurons), batch, self.spec.num_nodes, self.population)
        return _start(shape, like, self._stochastic())

    def compress(self, x: Tensor) -> Tensor:
        """The thalamic input ``(T', B, N, channels)`` of ``x (B, T, N, C)`` (zero-padded to :attr:`min_steps`)."""
        b, t, n, c = x.shape
        if t < self.min_steps:
            x = F.pad(x, (0, 0, 0, 0, 0, self.min_steps - t))
        h = self.compressor(x.permute(0, 2, 3, 1).reshape(b * n, c, -1))  # (B*N, channels, T')
        # time-major in memory, copied once: each step's (B, N, channels) block is then read by the gate and the 8
        # thalamic projections without a copy each (the same values; about 13 % of a training step on Ev-Objects)
        return h.reshape(b, n, h.shape[1], -1).permute(3, 0, 1, 2).contiguous()

    def columns(self, drive: Tensor, start: tuple[Tensor, Tensor] | None = None) -> Tensor:
        """The spikes of the output populations, ``(B, T', N, 4 * S)``, from the thalamic input ``(T', B, N, D)``;
        ``start``: the membranes and spikes ``(P, B, N, S)`` to begin from (default :meth:`initial_state`)."""
        steps, b, n, _ = drive.shape
        mems, spikes = start if start is not None else self.initial_state(b, drive)
        mems, spikes = list(mems.unbind(0)), list(spikes.unbind(0))
        traces = [drive.new_full((n, 1), self.init_b) for _ in self.neurons]
        noisy = self._stochastic() and self.noise_std > 0
        out = []
        # unbind, not drive[t]: the gradient of 35 selects is 35 zero-filled copies of the whole input, added up (about
        # 3 % of a training step); unbind's is one stack, with the same values
        for x_t in drive.unbind(0):  # (B, N, D)
            route = self.router.select(x_t)  # the same for every population of this step
            for i, neuron in enumerate(self.neurons):
                current = self.thalamic[i](x_t)  # the source's order of summation
                for j, link in zip(self.sources[i], self.links[i]):
                    current = current + link(spikes[j])
                current = current + self.router(torch.cat(spikes, dim=-1), route)
                noise = torch.randn_like(current) * self.noise_std if noisy else None
                mems[i], spikes[i], traces[i] = neuron.step(current, mems[i], spikes[i], traces[i], noise)
            out.append(torch.cat([spikes[i] for i in OUTPUTS], dim=-1))
        return torch.stack(out, dim=1)

    def forward_features(self, x: Tensor, g: Tensor | None = None, *, start: tuple[Tensor, Tensor] | None = None
                         ) -> Tensor:
        """The input of the final linear layer, ``(B, hidden)``; ``start`` as in :meth:`columns`."""
        check_inputs("multibarrel", self.spec, x, g)
        return self._features(self.columns(self.compress(x), start))

    def _features(self, spikes: Tensor) -> Tensor:
        if self.training and self.bn_train_steps is not None:
            self.train(True)  # BatchNorm stays in eval mode once frozen (a restored checkpoint included)
            self.bn_steps_seen += 1
        pooled = self.readout(spikes.permute(0, 3, 1, 2)).mean(dim=(2, 3))  # (B, readout_channels)
        return self.classifier[:-1](pooled)

    def forward_head(self, features: Tensor) -> Tensor:
        logits = self.classifier[-1](features)
        return logits.softmax(dim=1) if self.output == "softmax" else logits

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self.forward_head(self.forward_features(x, g))


#: the released ``SharedMultiBarrelModel``'s state-dict names -> ours (the 1x1 Conv1d weights lose their last axis)
_RELEASED_NAMES = (
    (r"compressor\.conv\.(\d+)\.(.+)", r"compressor.\1.\2"),
    (r"ThtoPops\.(\d+)\.conv\.(.+)", r"thalamic.\1.linear.\2"), (r"ThtoPops\.(\d+)\.bn\.(.+)", r"thalamic.\1.norm.\2"),
    (r"toPops\.(\d+)\.(\d+)\.conv\.(.+)", r"links.\1.\2.linear.\3"),
    (r"toPops\.(\d+)\.(\d+)\.bn\.(.+)", r"links.\1.\2.norm.\3"),
    (r"tau_adp\.(\d+)", r"neurons.\1.tau_adp"), (r"tau_m\.(\d+)", r"neurons.\1.tau_m"),
    (r"neighbor_agg\.gate_net\.0\.weight", "router.gate_w1"), (r"neighbor_agg\.gate_net\.0\.bias", "router.gate_b1"),
    (r"neighbor_agg\.gate_net\.1\.weight", "router.gate_ln_w"),
    (r"neighbor_agg\.gate_net\.1\.bias", "router.gate_ln_b"),
    (r"neighbor_agg\.gate_net\.3\.weight", "router.gate_w2"), (r"neighbor_agg\.gate_net\.3\.bias", "router.gate_b2"),
    (r"neighbor_agg\.aggregator\.0\.(.+)", r"router.aggregate.\1"),
    (r"neighbor_agg\.aggregator\.1\.(.+)", r"router.norm.\1"),
    (r"readout\.conv\.(\d+)\.(.+)", r"readout.\1.\2"), (r"readout\.classifier\.(\d+)\.(.+)", r"classifier.\1.\2"),
)


def convert_released(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """A state dict of the released ``SharedMultiBarrelModel`` (``torch.save(model.state_dict())`` in its training
    script) in :class:`MultiBarrel`'s names and shapes, for ``load_state_dict``; an unknown name is a
    :class:`ConfigError` naming it."""
    out: dict[str, Tensor] = {}
    for name, tensor in state.items():
        for pattern, target in _RELEASED_NAMES:
            if re.fullmatch(pattern, name):
                new = re.sub(pattern, target, name)
                out[new] = tensor.squeeze(-1) if new.endswith("linear.weight") else tensor
                break
        else:
            raise ConfigError(f"multibarrel: {name!r} is no parameter or buffer of the released SharedMultiBarrelModel")
    return out


def _start(shape: tuple[int, ...], like: Tensor, random: bool) -> tuple[Tensor, Tensor]:
    if random:  # the source draws membranes for every population, then spikes
        mems = torch.stack([torch.rand(shape[1:], device=like.device, dtype=like.dtype) for _ in range(shape[0])])
        spikes = torch.stack([torch.rand(shape[1:], device=like.device, dtype=like.dtype) for _ in range(shape[0])])
        return mems, spikes
    half = like.new_full(shape, 0.5)
    return half, half.clone()


class _SpanConv2d(nn.Conv2d):
    """A Conv2d (no padding, stride 1) whose kernel spans the whole width of its input: on CPU computed as one matrix
    product over the unfolded time windows, about 3x faster forward + backward than the CPU convolution at these
    shapes (the same function, rounded differently); elsewhere the ordinary convolution."""

    def forward(self, x: Tensor) -> Tensor:
        if x.device.type != "cpu" or x.shape[-1] != self.kernel_size[1]:
            return super().forward(x)
        b, steps = x.shape[0], x.shape[2] - self.kernel_size[0] + 1
        windows = x.unfold(2, self.kernel_size[0], 1)  # (B, C, T2, N, k)
        windows = windows.permute(0, 2, 1, 4, 3).reshape(b, steps, -1)  # (B, T2, C * k * N), the weight's order
        out = F.linear(windows, self.weight.reshape(self.out_channels, -1), self.bias)  # (B, T2, out)
        # contiguous: torch's CPU BatchNorm2d backward gets the bias gradient wrong on this permuted (channels-last)
        # layout (torch 2.13; the fidelity fixture caught it: tests/models/test_multibarrel_fidelity.py)
        return out.permute(0, 2, 1).unsqueeze(-1).contiguous()  # (B, out, T2, 1)


class _Link(nn.Module):
    """A projection between populations, shared by every column: Linear then BatchNorm over ``(B * N)`` rows (the
    source's 1x1 ``Conv1d`` and ``BatchNorm1d``). ``(B, N, in) -> (B, N, out)``."""

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.linear, self.norm = nn.Linear(in_features, out_features), nn.BatchNorm1d(out_features)

    def forward(self, x: Tensor) -> Tensor:
        b, n, _ = x.shape
        return self.norm(self.linear(x.reshape(b * n, -1))).reshape(b, n, -1)
