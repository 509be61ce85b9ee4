"""ConvLSTM tactile classifier (Zapata-Impata, Gil & Torres, "Learning Spatio Temporal Tactile Features with a
ConvLSTM for the Direction Of Slip Detection", Sensors 19(3):523, 2019; code: github.com/yayaneath/BioTacSP-DoS).

Each frame becomes a sensor image (:class:`~tactile_zoo.nn.grid.SensorGrid`: 12x11 with two fill passes for the
BioTac SP, as in the source; the sensor's own grid elsewhere, 9x13 for NeuTouch), consecutive images are averaged in
bins so that the recurrence sees at most ``max_frames`` of them, a stack of ConvLSTM layers reads the binned sequence,
and the last hidden state of the top layer is averaged over the grid and classified::

    (B, T, N, C) -> grid (B, T, C, H, W) -> bins of k frames (B, ceil(T/k), C, H, W)
    -> ConvLSTM 16 ch 3x3 -> ConvLSTM 16 ch 3x3 -> h_T (B, 16, H, W)
    -> global average pool (B, 16) [++ g_T (B, G)] -> FC 16 + ReLU -> FC K

Why bins: the source classified windows of a few BioTac frames; a 250-step event recording (Ev-Objects) costs
~114 s per epoch on one core unbinned, and gradients fade over 250 LSTM steps; k = 5 keeps 50
frames of 100 ms (docs/models.md). An open bin at the end of a prefix counts its missing frames as zeros, so
:meth:`ConvLSTMNet.step` (one call per raw frame) equals the forward pass on every prefix.

The model is causal: the scores after frame t depend on frames 0..t only, and :meth:`ConvLSTMNet.step` streams them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn.convlstm import ConvLSTM, ConvLSTMConfig
from ..nn.grid import SensorGrid
from ..registry import register_model
from ._inputs import check_inputs

__all__ = ["ConvLSTMNet"]



class State(NamedTuple):
    """Streaming state: the committed ``(h, c)`` of every layer after the last full bin, and the open bin."""

    layers: list[tuple[Tensor, Tensor]]  # (B, hidden, H, W) each
    partial: Tensor  # (B, C, H, W): sum of the open bin's frames
    filled: int  # frames in the open bin, 0 <= filled < k


@register_model(
    "convlstm",
    paper="Learning Spatio Temporal Tactile Features with a ConvLSTM for the Direction Of Slip Detection",
    citation="B. S. Zapata-Impata, P. Gil, F. Torres. Sensors 19(3):523, 2019. doi:10.3390/s19030523",
    year=2019,
    url="https://github.com/yayaneath/BioTacSP-DoS",
    description="Frames as sensor images averaged into at most 50 bins, two ConvLSTM layers (16 channels, 3x3, no "
                "peepholes), global average pooling of the last hidden state, FC 16 + ReLU, FC classes.",
    tags=["recurrent", "convolutional"],
    inputs=["grid", "globals"],
    # the source gives Adam 1e-3, batch 32, cross-entropy; epochs and patience are ours (docs/models.md)
    recipe={"loss": "ce", "optimizer": "adam", "lr": 1e-3, "weight_decay": 0.0, "amsgrad": False, "schedule": None,
            "max_epochs": 100, "patience": 20, "batch_size": 32, "grad_clip": 1.0},
    causal=True,
    streaming=True,
)
class ConvLSTMNet(nn.Module):
    """ConvLSTM classifier of Zapata-Impata et al. (2019); model card in docs/models.md.

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        hidden_channels: ConvLSTM state channels (source: 16).
        num_layers: stacked ConvLSTM layers (source: 2).
        kernel_size: ConvLSTM kernel side (source: 3).
        fc_units: width of the hidden fully connected layer (source: 16).
        fill_passes: empty-cell fill passes of the sensor image; ``None`` takes the sensor's (BioTac SP: 2).
        backend: the recurrence's implementation, ``"fused"`` (default) or ``"autograd"`` (the reference); same
            results, see :mod:`tactile_zoo.nn.convlstm`.
        max_frames: the recurrence reads ``ceil(T / k)`` bins of ``k = ceil(T / max_frames)`` averaged frames, ``T``
            the spec's ``num_steps`` (ours, 50); ``None`` reads every frame, as the source did on its short windows.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``; streaming:
        ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> ``(B, num_classes)``.
    """

    def __init__(self, spec: DatasetSpec, hidden_channels: int = 16, num_layers: int = 2, kernel_size: int = 3,
                 fc_units: int = 16, fill_passes: int | None = None, backend: str = "fused",
                 max_frames: int | None = 50) -> None:
        super().__init__()
        if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, int)
                                       or max_frames < 1):
            raise ConfigError(f"convlstm: max_frames must be a positive integer or None, got {max_frames!r}")
        self.spec = spec
        self.time_bin = 1 if max_frames is None else max(1, math.ceil(spec.num_steps / max_frames))
        self.grid = SensorGrid(spec.sensor, fill_passes)
        self.convlstm = ConvLSTM(ConvLSTMConfig(spec.num_channels, hidden_channels, num_layers, kernel_size,
                                                backend=backend))
        self.fc = nn.Linear(hidden_channels + spec.num_globals, fc_units)
        self.head = nn.Linear(fc_units, spec.num_classes)

    def _classify(self, h: Tensor, g_t: Tensor | None) -> Tensor:
        feats = h.mean(dim=(-2, -1))  # (B, hidden): global average pooling over the grid
        if g_t is not None:  # globals join after pooling, at the step being classified
            feats = torch.cat([feats, g_t], dim=-1)  # (B, hidden + G)
        return self.head(torch.relu(self.fc(feats)))

    def _bin(self, frames: Tensor) -> Tensor:
        k = self.time_bin
        if k == 1:
            return frames
        b, t = frames.shape[:2]
        pad = -t % k  # an open last bin averages over k with zeros for its missing frames, as step() does
        if pad:
            frames = torch.cat([frames, frames.new_zeros(b, pad, *frames.shape[2:])], dim=1)
        return frames.reshape(b, (t + pad) // k, k, *frames.shape[2:]).mean(dim=2)  # (B, ceil(T/k), C, H, W)

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        g = check_inputs("convlstm", self.spec, x, g)
        frames = self._bin(self.grid(x))  # (B, ceil(T/k), C, H, W)
        _, states = self.convlstm(frames)
        return self._classify(states[-1][0], None if g is None else g[:, -1])

    def init_state(self, batch_size: int) -> State:
        layers = self.convlstm.init_state(batch_size, self.grid.grid_shape)
        partial = layers[0][0].new_zeros(batch_size, self.spec.num_channels, *self.grid.grid_shape)
        return State(layers, partial, 0)

    def step(self, x_t: Tensor, g_t: Tensor | None, state: State) -> tuple[Tensor, State]:
        g_t = check_inputs("convlstm", self.spec, x_t, g_t, per_step=True)
        partial, filled = state.partial + self.grid(x_t), state.filled + 1  # (B, C, H, W)
        # the scores read the open bin as forward() would on this prefix; the layers commit only when it is full
        h, layers = self.convlstm.step(partial / self.time_bin, state.layers)  # (B, hidden, H, W)
        if filled == self.time_bin:
            return self._classify(h, g_t), State(layers, torch.zeros_like(partial), 0)
        return self._classify(h, g_t), State(state.layers, partial, filled)

