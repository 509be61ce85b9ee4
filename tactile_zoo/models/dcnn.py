"""D-CNN: a 2-D CNN over the time x feature image of a whole grasp (Maus et al., Augment8000; code:
github.com/philipmaus/Tactile_Object_Classification, Keras).

A sample becomes one single-channel image whose rows are time steps and whose columns are the features of a step:
on Augment8000 50 x 15 (3 OptoForce sensors x 4 force channels, then the 3 finger positions); on any other dataset
the ``N x C`` taxel channels flattened node-major, then the ``G`` globals (Ev-Objects: 250 x 78)::

    (B, T, N, C) [++ g] -> (B, 1, T, N*C + G)
    -> Conv 31 (1x2, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Conv 128 (2x3, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Conv 57 (3x1, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Flatten -> Dense 103 -> ReLU -> BN -> Dense 138 -> ReLU -> BN -> Dense K

Keras semantics in PyTorch: "same" convolution and pooling as TensorFlow pads, batch-norm epsilon 1e-3,
Glorot-uniform kernels and zero biases. The flatten size fixes the input length to ``spec.num_steps`` frames; the
model is not causal.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..registry import register_model
from ._inputs import check_inputs

__all__ = ["DCNN"]

KERAS_BN_MOMENTUM = 0.01  # Keras' BatchNormalization(momentum=0.99) in PyTorch terms
BN_EPS = 1e-3  # Keras' BatchNormalization epsilon


class _FirstBatchStats:
    """Batch norm whose running statistics start from the first training batch instead of (mean 0, var 1).

    The running averages are exponential moving averages; started at (0, 1) they carry that start for ~1/momentum
    updates. On Ev-Objects the first block's activation variance is ~0.003, so with Keras' momentum the eval-mode
    statistics stay hundreds of times too large for ~150 epochs (4 updates per epoch) and validation sits at chance.
    Taking the first batch's statistics whole (momentum 1 once) removes the start value, as bias correction does for
    Adam; every later update is the ordinary moving average.
    """

    momentum: float | None
    num_batches_tracked: Tensor | None

    def forward(self, x: Tensor) -> Tensor:
        if self.training and self.num_batches_tracked is not None and int(self.num_batches_tracked) == 0:
            momentum, self.momentum = self.momentum, 1.0
            try:
                return super().forward(x)  # type: ignore[misc]
            finally:
                self.momentum = momentum
        return super().forward(x)  # type: ignore[misc]


class _BatchNorm2d(_FirstBatchStats, nn.BatchNorm2d):
    pass


class _BatchNorm1d(_FirstBatchStats, nn.BatchNorm1d):
    pass


def _pooled(size: int, times: int) -> int:
    for _ in range(times):
        size = math.ceil(size / 2)
    return size


class _ConvBlock(nn.Sequential):
    """Conv ("same") -> ReLU -> BN -> 2x2 max pool ("same"): the unit the D-CNN stacks three times."""

    def __init__(self, cin: int, cout: int, kernel: tuple[int, int], bn_momentum: float) -> None:
        (kh, kw) = kernel
        # Keras/TF "same": total padding k - 1, the odd cell of an even kernel after (right/bottom)
        pad = (((kw - 1) // 2), kw - 1 - (kw - 1) // 2, (kh - 1) // 2, kh - 1 - (kh - 1) // 2)
        super().__init__(nn.ZeroPad2d(pad), nn.Conv2d(cin, cout, kernel), nn.ReLU(inplace=True),
                         _BatchNorm2d(cout, eps=BN_EPS, momentum=bn_momentum), nn.MaxPool2d(2, ceil_mode=True))


@register_model(
    "dcnn",
    paper="Tactile Object Classification (D-CNN on the Augment8000 OptoForce grasp data)",
    citation="P. Maus et al., D-CNN for tactile object classification; code: "
             "github.com/philipmaus/Tactile_Object_Classification",
    url="https://github.com/philipmaus/Tactile_Object_Classification",
    description="2-D CNN over the time x feature image of a grasp: three conv/ReLU/BN/max-pool blocks (31, 128, 57 "
                "filters), dense 103 and 138 with BN, linear classifier.",
    tags=["convolutional"],
    inputs=["globals"],
    recipe={"loss": "ce", "optimizer": "adam", "lr": 1e-2, "weight_decay": 0.0, "amsgrad": False, "schedule": None,
            "max_epochs": 300, "patience": 30, "batch_size": 128},
    causal=False,
    streaming=False,
    revision=1,
)
class DCNN(nn.Module):
    """D-CNN of Maus et al.: three conv blocks and two dense layers over the time x feature image.

    Departure (ours): batch-norm running statistics start from the first training batch and then average with
    momentum 0.1, not Keras' 0.01 (``bn_momentum=0.01`` restores Keras' averaging); a prefix shorter than
    ``num_steps`` is zero-padded at the end. Model card: docs/models.md, section "`dcnn`: D-CNN (Maus et al.)".

    Args:
        spec: the dataset's :class:`DatasetSpec` (fixes the image size ``num_steps x (N*C + G)``).
        filters: output channels of the three conv layers (source: 31, 128, 57).
        kernels: their kernel sizes (source: 1x2, 2x3, 3x1).
        dense: widths of the two hidden dense layers (source: 103, 138).
        bn_momentum: PyTorch momentum of the batch-norm running statistics (Keras: 0.01; default 0.1, see the card).

    Shapes:
        ``x (B, T, N, C)`` with ``T <= num_steps``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``.
    """

    def __init__(self, spec: DatasetSpec, filters: tuple[int, int, int] = (31, 128, 57),
                 kernels: tuple[tuple[int, int], ...] = ((1, 2), (2, 3), (3, 1)),
                 dense: tuple[int, int] = (103, 138), bn_momentum: float = 0.1) -> None:
        super().__init__()
        if len(filters) != 3 or len(kernels) != 3 or len(dense) != 2:
            raise ConfigError(f"dcnn: need 3 filters, 3 kernels and 2 dense widths, got {filters}, {kernels}, {dense}")
        if not 0.0 < bn_momentum <= 1.0:
            raise ConfigError(f"dcnn: bn_momentum must lie in (0, 1], got {bn_momentum}")
        bn = {"eps": BN_EPS, "momentum": bn_momentum}
        self.spec = spec
        self.num_steps = spec.num_steps
        self.num_features = spec.num_nodes * spec.num_channels + spec.num_globals
        chans = (1, *filters)
        self.features = nn.Sequential(*(_ConvBlock(chans[i], chans[i + 1], tuple(kernels[i]), bn_momentum)
                                        for i in range(3)))
        flat = filters[-1] * _pooled(self.num_steps, 3) * _pooled(self.num_features, 3)
        self.classifier = nn.Sequential(
            nn.Flatten(),
            nn.Linear(flat, dense[0]), nn.ReLU(inplace=True), _BatchNorm1d(dense[0], **bn),
            nn.Linear(dense[0], dense[1]), nn.ReLU(inplace=True), _BatchNorm1d(dense[1], **bn),
            nn.Linear(dense[1], spec.num_classes),
        )
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)
        # channels-last convolution weights make every activation channels-last: CPU max pooling and batch norm
        # run several times faster on that layout than on NCHW (measured on Ev-Objects-sized images)
        self.features.to(memory_format=torch.channels_last)

    def image(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """The model's input image ``(B, 1, num_steps, N*C + G)`` of a batch."""
        g = check_inputs("dcnn", self.spec, x, g)
        b, t = x.shape[:2]
        if t > self.num_steps:
            raise ConfigError(f"dcnn: built for {self.num_steps} time steps (its dense layer depends on it), "
                              f"got {t}; build it for a spec with num_steps >= {t}")
        rows = x.reshape(b, t, -1)  # (B, T, N*C), node-major
        if g is not None:
            rows = torch.cat([rows, g], dim=-1)  # (B, T, N*C + G)
        rows = F.pad(rows, (0, 0, 0, self.num_steps - t))  # (B, num_steps, F): a prefix reads as zeros after it
        return rows.unsqueeze(1)  # (B, 1, num_steps, F)

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self.classifier(self.features(self.image(x, g)))
