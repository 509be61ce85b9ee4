"""ConvLSTM tactile classifier (Zapata-Impata, Gil & Torres, "Learning Spatio Temporal Tactile Features with a
ConvLSTM for the Direction Of Slip Detection", Sensors 19(3):523, 2019; code: github.com/yayaneath/BioTacSP-DoS).

Each frame becomes a sensor image (:class:`~tactile_zoo.nn.sensor_grid.SensorGrid`: 12x11 with two fill passes for the
BioTac SP, as in the source; the sensor's own grid elsewhere, 9x13 for NeuTouch), consecutive images are averaged in
bins so that the recurrence sees at most ``max_frames`` of them, a stack of ConvLSTM layers reads the binned sequence,
and the last hidden state of the top layer is averaged over the grid and classified::

    (B, T, N, C) -> mean of every k frames (B, T' = ceil(T/k), N, C) -> grid (B, T', C, H, W)
    -> ConvLSTM 16 ch 3x3 -> ConvLSTM 16 ch 3x3 -> h_T (B, 16, H, W)
    -> global average pool (B, 16) [++ g_T (B, G)] -> FC 16 + ReLU -> FC K

Cell (Shi et al. 2015, no peepholes): ``i, f, o = sigmoid(W_x * X_t + W_h * H_{t-1} + b)``, ``g = tanh(...)``,
``C_t = f C_{t-1} + i g``, ``H_t = o tanh(C_t)``. The model is causal: the scores after frame t depend on frames
0..t only, and :meth:`ConvLSTMNet.step` streams them (an open last bin counts its missing frames as zeros).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn import backend as switch
from ..nn.backend import ConvLSTMBackend
from ..nn.convlstm import ConvLSTM, ConvLSTMConfig
from ..registry import recipe_file, register_model
from ._binned import BinnedStreamer, bins_for
from ._inputs import sensor_grid

__all__ = ["ConvLSTMNet", "FRAME_NORMS", "READOUTS"]

FRAME_NORMS = (None, "minmax")
READOUTS = ("gap", "taxels")


@register_model(
    "convlstm",
    paper="Learning Spatio Temporal Tactile Features with a ConvLSTM for the Direction Of Slip Detection",
    citation="B. S. Zapata-Impata, P. Gil, F. Torres. Sensors 19(3):523, 2019. doi:10.3390/s19030523",
    year=2019,
    url="https://github.com/yayaneath/BioTacSP-DoS",
    description="Frames as sensor images averaged into at most 50 bins, two ConvLSTM layers (16 channels, 3x3, no "
                "peepholes), global average pooling of the last hidden state, FC 16 + ReLU, FC classes.",
    tags=["recurrent", "convolutional", "table1"],
    inputs=["grid", "globals"],
    display_name="ConvLSTM",
    family="convolutional LSTM on sensor images",
    reference={"type": "article", "authors": ["Zapata-Impata, Brayan S.", "Gil, Pablo", "Torres, Fernando"],
               "journal": "Sensors", "volume": 19, "issue": 3, "doi": "10.3390/s19030523",
               "notes": "the BioTac-DoS dataset"},
    **recipe_file("tactile_zoo", "convlstm"),
    causal=True,
    streaming=True,
    # 2: the recurrence's numba kernels (backend "compiled"), selectable, 1.52x revision 1 since 2026-12-08
    # (vs_fcddbe0_convlstm.csv); not the default until Table I has its cells (benchmarks/studies/convlstm-r2.yaml)
    revision=1,
    revisions={1: {"backend": "fused"}, 2: {"backend": "compiled"}},
)
class ConvLSTMNet(BinnedStreamer):
    """ConvLSTM classifier of Zapata-Impata et al. (2019): sensor images, two ConvLSTM layers, pooled last state.

    Departures (ours, defaults): frames averaged into at most ``max_frames`` bins (cost), Keras-style initialisation,
    no per-frame min-max scaling of the image, our epoch budget; ``init="torch"`` and ``frame_norm="minmax"`` give the
    source's PyTorch notebook (with the dataset's raw readings). Model card: docs/models.md, section "`convlstm`:
    ConvLSTM (Zapata-Impata et al., 2019)".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        hidden_channels: ConvLSTM state channels (source: 16).
        num_layers: stacked ConvLSTM layers (source: 2).
        kernel_size: ConvLSTM kernel side (source: 3).
        fc_units: width of the hidden fully connected layer (source: 16).
        fill_passes: empty-cell fill passes of the sensor image; ``None`` takes the sensor's (BioTac SP: 2).
        backend: the recurrence's implementation, ``"fused"`` (default), ``"autograd"`` (the reference) or
            ``"compiled"`` (opt-in: numba kernels per step on CPU, equal to ``"fused"`` within float32 rounding,
            not bit for bit: revision 2, ``create_model("convlstm", spec, revision=2)``); see
            :mod:`tactile_zoo.nn.convlstm`.
        max_frames: the recurrence reads ``ceil(T / k)`` bins of ``k = ceil(T / max_frames)`` averaged frames, ``T``
            the spec's ``num_steps`` (ours, 50); ``None`` reads every frame, as the source did.
        frame_norm: ``None`` (default) feeds the image as is; ``"minmax"`` rescales every image (each frame, or bin,
            and channel) to [0, 1] by its own minimum and maximum over the grid, filled cells included, as the
            source's preprocessing did (a constant image becomes 0).
        init: ConvLSTM initialisation, ``"keras"`` (default: Glorot / orthogonal, forget bias 1) or ``"torch"``
            (PyTorch's ``nn.Conv2d`` default, the source's); see :mod:`tactile_zoo.nn.convlstm`.
        dropout: dropout after the hidden FC layer's ReLU (default 0.0; the source's read-out has the layer, its
            released run sets 0.0).
        readout: what the FC layers read of the top layer's last hidden state: ``"gap"`` (default, the source's)
            averages it over the whole image, which keeps what was felt but not where; ``"taxels"`` keeps its
            channels at each taxel's own cell (``hidden_channels * N`` features), so where on the sensor the activity
            was survives, and the always-empty cells of a sparse layout (78 of NeuTouch's 117) do not dilute it.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``; streaming:
        ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> ``(B, num_classes)``.
    """

    #: the final classifier layer, which ``create_model(..., pretrained=..., new_head=True)`` starts afresh
    zoo_head = "head"

    def __init__(self, spec: DatasetSpec, hidden_channels: int = 16, num_layers: int = 2, kernel_size: int = 3,
                 fc_units: int = 16, fill_passes: int | None = None, backend: str = "fused",
                 max_frames: int | None = 50, frame_norm: str | None = None, init: str = "keras",
                 dropout: float = 0.0, readout: str = "gap") -> None:
        super().__init__()
        if frame_norm not in FRAME_NORMS:
            raise ConfigError(f"convlstm: frame_norm must be one of {FRAME_NORMS}, got {frame_norm!r}")
        if readout not in READOUTS:
            raise ConfigError(f"convlstm: readout must be one of {READOUTS}, got {readout!r}")
        if not 0.0 <= dropout < 1.0:
            raise ConfigError(f"convlstm: dropout must be in [0, 1), got {dropout!r}")
        backend = switch.resolve(ConvLSTMBackend, backend, "backend", "convlstm")
        self.frame_norm, self.readout = frame_norm, readout
        self.name, self.spec, self.bin_size = "convlstm", spec, bins_for("convlstm", spec.num_steps, max_frames)
        self.grid = sensor_grid(spec, fill_passes)
        self.convlstm = ConvLSTM(ConvLSTMConfig(spec.num_channels, hidden_channels, num_layers, kernel_size,
                                                backend=backend, init=init))
        pooled = hidden_channels * (spec.num_nodes if readout == "taxels" else 1)
        self.fc = nn.Linear(pooled + spec.num_globals, fc_units)
        self.drop = nn.Dropout(dropout)
        self.head = nn.Linear(fc_units, spec.num_classes)

    def _features(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        # bins arrive summed, (T', B, N, C); their mean is the image, and an open bin's missing frames count as zeros
        frames = self.grid(xb / self.bin_size).transpose(0, 1)  # (B, T', C, H, W)
        if self.frame_norm == "minmax":  # every image to [0, 1] by its own range (the source's feature scaling)
            low = frames.amin(dim=(-2, -1), keepdim=True)
            frames = (frames - low) / (frames.amax(dim=(-2, -1), keepdim=True) - low).clamp_min(1e-12)
        _, states = self.convlstm(frames, core)
        top = states[-1][0]  # (B, hidden, H, W): the top layer's h_T
        if self.readout == "taxels":
            feats = top.flatten(2).index_select(2, self.grid.taxel_cells).flatten(1)  # (B, hidden * N)
        else:
            feats = top.mean(dim=(-2, -1))  # (B, hidden): global average pooling
        if gb is not None:  # globals join after pooling: the last bin's mean (the last step's values when unbinned)
            feats = torch.cat([feats, gb[-1]], dim=-1)  # (B, hidden + G)
        return torch.relu(self.fc(feats)), states

    def forward_head(self, features: Tensor) -> Tensor:
        if self.drop.p > 0:  # skipped at 0, so the default draws nothing from the RNG
            features = self.drop(features)
        return self.head(features)
