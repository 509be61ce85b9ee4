"""A temporal convolutional network (TCN) baseline for tactile recognition.

Paper: S. Bai, J. Z. Kolter, V. Koltun, "An Empirical Evaluation of Generic Convolutional and Recurrent Networks for
Sequence Modeling", arXiv:1803.01271, 2018.

The TCN treats a tactile recording as a multichannel time series: every taxel x channel value (plus the global
features, such as joint angles) is one input channel, and a stack of residual blocks of dilated causal convolutions
(dilation ``2 ** level``) runs over time. It ignores where the taxels are, which is exactly why it is a useful
baseline next to the graph and image models of the zoo: what it gains over them is what time alone explains.

Choices this implementation makes where the paper leaves room (or tunes per task):

- ``levels=None`` picks the fewest levels whose receptive field ``1 + 2 (k - 1) (2 ** levels - 1)`` covers the whole
  recording, so the last step sees the first one;
- the input is normalised per channel (BatchNorm without affine parameters), because the sensor families of the zoo
  differ by orders of magnitude in scale (event counts, electrode impedance drops, forces) and one recipe must fit
  them all;
- classification reads out the mean of the top block's features over time (``readout="mean"``) or its last step
  (``readout="last"``, the paper's choice for sequential MNIST). Both are causal: the score after ``t`` steps depends
  on ``x[:t+1]`` only, which :meth:`TCN.step` exploits to stream.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import recipe_file

from .temporal_block import TemporalBlock

__all__ = ["TCN", "receptive_field"]

MAX_LEVELS = 12  # 2 ** 12 dilation: receptive field > 16k steps with k = 3, more than any tactile recording


def receptive_field(kernel_size: int, levels: int) -> int:
    """Time steps one output of a ``levels``-block TCN sees (two convolutions per block)."""
    return 1 + 2 * (kernel_size - 1) * (2 ** levels - 1)


class TCN(nn.Module):
    """Temporal convolutional network over the flattened taxel x channel features (+ globals).

    Args:
        spec: the dataset's :class:`~tactile_zoo.data.spec.DatasetSpec`.
        hidden: channels of every residual block.
        levels: residual blocks, dilations ``1, 2, ..., 2 ** (levels - 1)``; ``None``: enough to cover ``num_steps``.
        kernel_size: taps of every causal convolution (>= 2).
        dropout: channel dropout after every convolution.
        weight_norm: weight-normalise the convolutions (Bai et al. do).
        readout: ``"mean"`` (average over time) or ``"last"`` (last time step).
        input_norm: normalise each input channel (see the module docstring).

    Shapes:
        - forward: ``x (B, T, N, C)``, ``g (B, T, G)`` or None -> logits ``(B, K)``
        - step: ``x_t (B, N, C)``, ``g_t (B, G)`` or None, state -> logits ``(B, K)`` after ``t + 1`` steps, state
    """

    zoo_meta = {
        "paper": "An Empirical Evaluation of Generic Convolutional and Recurrent Networks for Sequence Modeling",
        "citation": "S. Bai, J. Z. Kolter, V. Koltun. An Empirical Evaluation of Generic Convolutional and Recurrent "
                    "Networks for Sequence Modeling. arXiv:1803.01271, 2018.",
        "year": 2018,
        "url": "https://arxiv.org/abs/1803.01271",
        "description": "Temporal convolutional network baseline: dilated causal 1-D convolutions in residual blocks "
                       "over the flattened taxel x channel features (plus globals); ignores taxel layout.",
        "tags": ["convolutional", "temporal"],
        "inputs": ["globals"],
        "causal": True,
        "streaming": True,
        "revision": 1,  # computational revision (part of every cell hash): bump when what the model computes changes
        # the training recipe is data: tactile_zoo_tcn/recipes/tcn.yaml, shipped as package data
        **recipe_file("tactile_zoo_tcn", "tcn"),
    }

    def __init__(self, spec: Any, hidden: int = 64, levels: int | None = None, kernel_size: int = 3,
                 dropout: float = 0.1, weight_norm: bool = True, readout: str = "mean",
                 input_norm: bool = True) -> None:
        super().__init__()
        if kernel_size < 2 or hidden < 1 or not 0.0 <= dropout < 1.0:
            raise ConfigError(f"tcn: need kernel_size >= 2, hidden >= 1 and 0 <= dropout < 1; got kernel_size="
                              f"{kernel_size}, hidden={hidden}, dropout={dropout}")
        if readout not in ("mean", "last"):
            raise ConfigError(f"tcn: readout must be 'mean' or 'last', got {readout!r}")
        if levels is None:
            levels = 1
            while receptive_field(kernel_size, levels) < spec.num_steps and levels < MAX_LEVELS:
                levels += 1
        if levels < 1:
            raise ConfigError(f"tcn: levels must be >= 1, got {levels}")
        self.num_nodes, self.num_channels, self.num_globals = spec.num_nodes, spec.num_channels, spec.num_globals
        self.readout, self.levels, self.kernel_size = readout, levels, kernel_size
        in_features = spec.num_nodes * spec.num_channels + spec.num_globals
        self.norm = nn.BatchNorm1d(in_features, affine=False) if input_norm else nn.Identity()
        widths = [in_features] + [hidden] * levels
        self.blocks = nn.ModuleList(
            TemporalBlock(widths[i], widths[i + 1], kernel_size, 2 ** i, dropout, weight_norm) for i in range(levels))
        self.head = nn.Linear(hidden, spec.num_classes)

    @property
    def receptive_field(self) -> int:
        return receptive_field(self.kernel_size, self.levels)

    def _features(self, x: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
        """``x (B, T, N, C)`` (+ ``g (B, T, G)``) -> normalised channels-first features ``(B, F, T)``."""
        if x.dim() != 4 or tuple(x.shape[2:]) != (self.num_nodes, self.num_channels):
            raise ConfigError(f"tcn: x must be (B, T, {self.num_nodes}, {self.num_channels}), got {tuple(x.shape)}")
        b, t = x.shape[:2]
        feats = x.reshape(b, t, self.num_nodes * self.num_channels)  # (B, T, N*C)
        if self.num_globals > 0:
            if g is None or tuple(g.shape) != (b, t, self.num_globals):
                got = None if g is None else tuple(g.shape)
                raise ConfigError(f"tcn: this dataset has {self.num_globals} global features per step; g must be "
                                  f"({b}, {t}, {self.num_globals}), got {got}")
            feats = torch.cat([feats, g.to(feats.dtype)], dim=-1)  # (B, T, N*C + G)
        return self.norm(feats.transpose(1, 2))  # (B, F, T)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        h = self._features(x, g)
        for block in self.blocks:
            h = block(h)  # (B, hidden, T)
        pooled = h.mean(dim=-1) if self.readout == "mean" else h[..., -1]  # (B, hidden)
        return self.head(pooled)

    def init_state(self, batch_size: int) -> dict[str, Any]:
        """Streaming state before the first step (evaluation mode: BatchNorm and dropout then act per step)."""
        ref = self.head.weight
        return {"blocks": [blk.init_state(batch_size, ref.device, ref.dtype) for blk in self.blocks],
                "sum": torch.zeros(batch_size, self.head.in_features, device=ref.device, dtype=ref.dtype),
                "steps": 0}

    def step(self, x_t: torch.Tensor, g_t: torch.Tensor | None, state: dict[str, Any]
             ) -> tuple[torch.Tensor, dict[str, Any]]:
        """One more time step: the scores ``forward`` would give on the prefix seen so far, and the new state."""
        h = self._features(x_t.unsqueeze(1), None if g_t is None else g_t.unsqueeze(1))  # (B, F, 1)
        blocks = []
        for block, block_state in zip(self.blocks, state["blocks"]):
            h, block_state = block.step(h, block_state)  # (B, hidden, 1)
            blocks.append(block_state)
        h = h.squeeze(-1)  # (B, hidden)
        total, steps = state["sum"] + h, state["steps"] + 1
        pooled = total / steps if self.readout == "mean" else h
        return self.head(pooled), {"blocks": blocks, "sum": total, "steps": steps}
