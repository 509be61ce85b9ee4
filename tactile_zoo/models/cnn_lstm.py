"""CNN-LSTM: a small CNN encodes every frame's sensor image, an LSTM reads the frame codes in time order.

Source: the CNN-LSTM family as cited in the related work of "X-Tacformer: Spatio-temporal Attention Model for
Tactile Recognition" (per-frame CNN features fed in sequence to an LSTM, Li et al.), without layer sizes, so every
layer below is our choice, sized for sensor images of 3 to 132 cells and a 60 s Ev-Objects epoch::

    (B, T, N, C) -> mean of every k frames, k = ceil(T / 50) -> grid (B*T', C, H, W), T' = ceil(T / k) <= 50
    -> Conv 3x3 C->16 "same" + ReLU -> MaxPool 2x2 (ceil: a 1-row grid survives) -> Conv 3x3 16->32 "same" + ReLU
    -> flatten (B*T', 32*ceil(H/2)*ceil(W/2)) -> Linear 64 + ReLU  ->  (B, T', 64) [++ g (B, T', G)]
    -> LSTM 64 (one layer) -> h_T (B, 64) -> Linear K

No batch norm or dropout inside the frame encoder, so a frame's code does not depend on the other frames of the batch
and streaming one frame at a time (:meth:`CNNLSTM.step`, through :class:`._binned.BinnedStreamer`) gives the scores
of the full forward on every prefix, an open last bin included.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..registry import recipe_file, register_model
from ._binned import BinnedStreamer, bins_for
from ._inputs import sensor_grid

__all__ = ["CNNLSTM", "FrameEncoder"]


class FrameEncoder(nn.Module):
    """Two "same" 3x3 conv layers with a 2x2 max pool between them, then a linear projection: one sensor image ->
    one feature vector.

    Shapes: ``(F, C, H, W) -> (F, out_features)`` for any number of frames ``F``.
    """

    def __init__(self, in_channels: int, grid_shape: tuple[int, int], channels: tuple[int, int] = (16, 32),
                 out_features: int = 64) -> None:
        super().__init__()
        c1, c2 = channels
        self.convs = nn.Sequential(
            nn.Conv2d(in_channels, c1, 3, padding=1), nn.ReLU(),
            # pooling between the convs, not after them: the wider second conv runs on a quarter of the cells
            nn.MaxPool2d(2, ceil_mode=True),
            nn.Conv2d(c1, c2, 3, padding=1), nn.ReLU(),
        )
        h, w = (math.ceil(s / 2) for s in grid_shape)
        self.proj = nn.Linear(c2 * h * w, out_features)
        # channels-last weights carry the layout through the convs and the pool: ~20 % faster on CPU (measured)
        self.convs.to(memory_format=torch.channels_last)

    def forward(self, frames: Tensor) -> Tensor:
        z = self.convs(frames)  # (F, c2, ceil(H/2), ceil(W/2))
        return torch.relu(self.proj(z.flatten(1)))  # (F, out_features)


@register_model(
    "cnn_lstm",
    paper="CNN-LSTM baseline (per-frame CNN features in sequence to an LSTM), as cited in X-Tacformer's related work",
    citation="Family described in the related work of 'X-Tacformer: Spatio-temporal Attention Model for Tactile "
             "Recognition' (Li et al.); layers are tactile-zoo's own, see docs/models.md",
    year=2024,
    description="Per-frame CNN on the sensor image (conv 3x3, max pool, conv 3x3, linear 64) of frames averaged into "
                "at most 50 bins, LSTM 64 over the frame codes, linear classifier on the last hidden state.",
    tags=["recurrent", "convolutional", "table1"],
    inputs=["grid", "globals"],
    display_name="CNN-LSTM",
    family="per-frame CNN + LSTM",
    **recipe_file("tactile_zoo", "cnn_lstm"),
    causal=True,
    streaming=True,
    revision=1,
)
class CNNLSTM(BinnedStreamer):
    """CNN-LSTM classifier: a per-frame CNN code of the sensor image, an LSTM over the codes, a linear read-out.

    Departures: not a reproduction, the source names the family only, so every layer size is ours, as are the bins
    of at most ``max_frames`` averaged frames. Model card: docs/models.md, section "`cnn_lstm`: CNN-LSTM".

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        conv_channels: channels of the two conv layers.
        frame_features: width of a frame's code.
        hidden: LSTM hidden size.
        fill_passes: empty-cell fill passes of the sensor image; ``None`` takes the sensor's (BioTac SP: 2).
        max_frames: average every ``k = ceil(T / max_frames)`` frames (and their globals) into one, ``T`` the spec's
            ``num_steps``, so the LSTM reads at most ``max_frames`` steps (50); ``None`` reads every frame.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``; streaming:
        ``x_t (B, N, C)``, ``g_t (B, G)`` or None -> ``(B, num_classes)``.
    """

    #: the final classifier layer, which ``create_model(..., pretrained=..., new_head=True)`` starts afresh
    zoo_head = "head"

    def __init__(self, spec: DatasetSpec, conv_channels: tuple[int, int] = (16, 32), frame_features: int = 64,
                 hidden: int = 64, fill_passes: int | None = None, max_frames: int | None = 50) -> None:
        super().__init__()
        if len(conv_channels) != 2 or min(conv_channels) < 1 or frame_features < 1 or hidden < 1:
            raise ConfigError(f"cnn_lstm: need two positive conv widths and positive sizes, got "
                              f"conv_channels={conv_channels}, frame_features={frame_features}, hidden={hidden}")
        self.name, self.spec, self.bin_size = "cnn_lstm", spec, bins_for("cnn_lstm", spec.num_steps, max_frames)
        self.grid = sensor_grid(spec, fill_passes)
        self.encoder = FrameEncoder(spec.num_channels, spec.sensor.grid_shape, tuple(conv_channels), frame_features)
        self.lstm = nn.LSTM(frame_features + spec.num_globals, hidden, batch_first=True)
        self.head = nn.Linear(hidden, spec.num_classes)

    def _features(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        # bins arrive summed, (T', B, N, C); their mean is the frame, an open bin's missing frames count as zeros
        codes = self.encoder(self.grid((xb / self.bin_size).flatten(0, 1)))  # (T' * B, features): one call
        codes = codes.view(*xb.shape[:2], -1)  # (T', B, features)
        if gb is not None:  # globals join every step's code (a bin's mean globals)
            codes = torch.cat([codes, gb], dim=-1)  # (T', B, features + G)
        _, (h, c) = self.lstm(codes.transpose(0, 1), core)  # h: (1, B, hidden), the last step's hidden state
        return h[-1], (h, c)  # the classifier (forward_head) reads the last hidden state
