"""Dilated causal 1-D convolution, the building block of a temporal convolutional network.

Paper: S. Bai, J. Z. Kolter, V. Koltun, "An Empirical Evaluation of Generic Convolutional and Recurrent Networks for
Sequence Modeling", arXiv:1803.01271, 2018 (section 3.2).

Update rule, for kernel size ``k`` and dilation ``d``::

    y[t] = b + sum_{i=0}^{k-1} W_i x[t - i * d]        (x[t] = 0 for t < 0)

so ``y[t]`` depends on ``x[0..t]`` only. The layer pads ``(k - 1) * d`` zeros on the left (where the authors' code pads
both sides and chops the right end off: the same numbers without the wasted right half).

The causal structure makes streaming exact: :meth:`CausalConv1d.step` keeps the last ``(k - 1) * d`` inputs as its
state and produces, one step at a time, the same outputs as :meth:`CausalConv1d.forward` on the whole sequence.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.parametrizations import weight_norm as _weight_norm

__all__ = ["CausalConv1d"]


class CausalConv1d(nn.Module):
    """Dilated causal convolution over time, optionally weight-normalised.

    Args:
        in_channels: input features per time step.
        out_channels: output features per time step.
        kernel_size: taps of the filter (``k``).
        dilation: spacing of the taps in time (``d``).
        weight_norm: reparametrise the filter as ``g * v / ||v||`` (Salimans & Kingma 2016), as Bai et al. do.

    Shapes:
        - forward: ``x (B, C_in, T)`` -> ``(B, C_out, T)``
        - step: ``x_t (B, C_in, 1)``, state ``(B, C_in, (k - 1) * d)`` -> ``(B, C_out, 1)``, new state
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, dilation: int = 1,
                 weight_norm: bool = True) -> None:
        super().__init__()
        self.in_channels = in_channels
        self.history = (kernel_size - 1) * dilation  # how many past inputs one output sees besides the current one
        conv = nn.Conv1d(in_channels, out_channels, kernel_size, dilation=dilation)
        nn.init.normal_(conv.weight, 0.0, 0.01)  # the initialisation Bai et al. use
        self.conv = _weight_norm(conv) if weight_norm else conv

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(F.pad(x, (self.history, 0)))  # (B, C_in, history + T) -> (B, C_out, T)

    def init_state(self, batch_size: int, device: torch.device | None = None,
                   dtype: torch.dtype | None = None) -> torch.Tensor:
        """The zeros :meth:`forward` pads with: the inputs 'before' the first step."""
        return torch.zeros(batch_size, self.in_channels, self.history, device=device, dtype=dtype)

    def step(self, x_t: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        window = torch.cat([state, x_t], dim=-1)  # (B, C_in, history + 1): exactly the taps of the newest output
        return self.conv(window), window[..., 1:]
