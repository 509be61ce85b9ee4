"""The residual block of a temporal convolutional network.

Paper: S. Bai, J. Z. Kolter, V. Koltun, "An Empirical Evaluation of Generic Convolutional and Recurrent Networks for
Sequence Modeling", arXiv:1803.01271, 2018 (section 3.3, figure 1b).

Update rule::

    h = Dropout(ReLU(CausalConv_d(x)))
    h = Dropout(ReLU(CausalConv_d(h)))
    y = ReLU(h + skip(x))            skip = 1x1 convolution when the widths differ, identity otherwise

The dropout is spatial (a whole channel is zeroed for the whole sequence), as the paper describes; the authors'
released code uses element-wise dropout instead. Dropout is the identity in evaluation mode, which is where
:meth:`TemporalBlock.step` is meant to be used.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .causal_conv import CausalConv1d

__all__ = ["TemporalBlock"]

BlockState = tuple[torch.Tensor, torch.Tensor]


class TemporalBlock(nn.Module):
    """Two dilated causal convolutions with ReLU and dropout, plus a residual connection.

    Args:
        in_channels: input width.
        out_channels: output width.
        kernel_size: taps of both convolutions.
        dilation: dilation of both convolutions (``2 ** level`` in a TCN).
        dropout: channel dropout probability after each convolution.
        weight_norm: weight-normalise both convolutions.

    Shapes:
        - forward: ``x (B, C_in, T)`` -> ``(B, C_out, T)``
        - step: ``x_t (B, C_in, 1)`` and the state of :meth:`init_state` -> ``(B, C_out, 1)``, new state
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, dilation: int, dropout: float = 0.0,
                 weight_norm: bool = True) -> None:
        super().__init__()
        self.conv1 = CausalConv1d(in_channels, out_channels, kernel_size, dilation, weight_norm)
        self.conv2 = CausalConv1d(out_channels, out_channels, kernel_size, dilation, weight_norm)
        self.drop = nn.Dropout1d(dropout)  # (B, C, T): zeroes whole channels
        self.skip = nn.Conv1d(in_channels, out_channels, 1) if in_channels != out_channels else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.drop(F.relu(self.conv1(x)))
        h = self.drop(F.relu(self.conv2(h)))
        return F.relu(h + self.skip(x))

    def init_state(self, batch_size: int, device: torch.device | None = None,
                   dtype: torch.dtype | None = None) -> BlockState:
        return (self.conv1.init_state(batch_size, device, dtype), self.conv2.init_state(batch_size, device, dtype))

    def step(self, x_t: torch.Tensor, state: BlockState) -> tuple[torch.Tensor, BlockState]:
        h, s1 = self.conv1.step(x_t, state[0])
        h, s2 = self.conv2.step(self.drop(F.relu(h)), state[1])
        return F.relu(self.drop(F.relu(h)) + self.skip(x_t)), (s1, s2)
