"""Convolutional LSTM (Shi et al., "Convolutional LSTM Network", NeurIPS 2015), without peephole connections.

Update rule for one layer, ``*`` a 2-D convolution with "same" zero padding and ``o`` the element-wise product::

    i_t = sigmoid(W_xi * X_t + W_hi * H_{t-1} + b_i)
    f_t = sigmoid(W_xf * X_t + W_hf * H_{t-1} + b_f)
    o_t = sigmoid(W_xo * X_t + W_ho * H_{t-1} + b_o)
    g_t = tanh(W_xg * X_t + W_hg * H_{t-1} + b_g)
    C_t = f_t o C_{t-1} + i_t o g_t
    H_t = o_t o tanh(C_t)

Shi et al. also add peephole terms ``W_c o C`` to the gates; the ConvLSTM source of the tactile model
(yayaneath/BioTacSP-DoS, Keras ``ConvLSTM2D``) has none, and neither has this layer. Initial states are zero.

Speed: the input-side convolutions ``W_x* * X_t`` do not depend on the recurrence, so one convolution computes them
for all ``B*T`` frames at once; only the hidden-side convolution and the gates run once per step (5 ops: one conv,
one add, one sigmoid over the three sigmoid gates, which are stored next to each other, and the cell/hidden update).
A stacked network runs layer by layer, so layer ``l+1``'s input convolution is again one call over all frames.

Initialisation follows Keras' ``ConvLSTM2D`` defaults, the framework of the source: Glorot-uniform input kernels,
orthogonal recurrent kernels, zero biases except 1 on the forget gate (``unit_forget_bias``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ..errors import ConfigError

__all__ = ["ConvLSTMCell", "ConvLSTM", "ConvLSTMConfig"]

State = tuple[Tensor, Tensor]  # (h, c), each (B, hidden, H, W)


def _gates(z: Tensor, c: Tensor) -> State:
    """The LSTM cell update from the pre-activations ``z = (i, f, o, g)`` stacked on dim 1."""
    hidden = c.shape[1]
    ifo = torch.sigmoid(z[:, : 3 * hidden])
    i, f, o = ifo.chunk(3, dim=1)
    g = torch.tanh(z[:, 3 * hidden:])
    c = torch.addcmul(f * c, i, g)
    return o * torch.tanh(c), c


class ConvLSTMCell(nn.Module):
    """One ConvLSTM layer.

    Args:
        in_channels: channels of the input frames.
        hidden_channels: channels of the hidden and cell state.
        kernel_size: odd side of the square kernels ("same" padding keeps the grid size, also on a 1x3 grid).
        forget_bias: initial forget-gate bias.

    Shapes:
        :meth:`forward`: ``x [B, T, C_in, H, W]`` -> ``(h_seq [B, T, hidden, H, W], (h_T, c_T))``.
        :meth:`step`: ``x_t [B, C_in, H, W]`` -> ``(h_t, c_t)``, each ``[B, hidden, H, W]``.
    """

    def __init__(self, in_channels: int, hidden_channels: int, kernel_size: int = 3, forget_bias: float = 1.0) -> None:
        super().__init__()
        if kernel_size % 2 != 1 or kernel_size < 1:
            raise ConfigError(f"ConvLSTM kernel_size must be a positive odd integer, got {kernel_size}")
        if in_channels < 1 or hidden_channels < 1:
            raise ConfigError(f"ConvLSTM channels must be positive, got in={in_channels}, hidden={hidden_channels}")
        self.hidden_channels = hidden_channels
        pad = kernel_size // 2
        # gate order along the output channels: i, f, o (sigmoid, adjacent: one op), then g (tanh)
        self.input_conv = nn.Conv2d(in_channels, 4 * hidden_channels, kernel_size, padding=pad, bias=True)
        self.hidden_conv = nn.Conv2d(hidden_channels, 4 * hidden_channels, kernel_size, padding=pad, bias=False)
        self.reset_parameters(forget_bias)

    def reset_parameters(self, forget_bias: float = 1.0) -> None:
        nn.init.xavier_uniform_(self.input_conv.weight)
        nn.init.orthogonal_(self.hidden_conv.weight)
        nn.init.zeros_(self.input_conv.bias)
        with torch.no_grad():
            self.input_conv.bias[self.hidden_channels: 2 * self.hidden_channels] = forget_bias

    def init_state(self, batch_size: int, grid_shape: tuple[int, int]) -> State:
        w = self.hidden_conv.weight
        h = w.new_zeros(batch_size, self.hidden_channels, *grid_shape)
        return h, h.clone()

    def forward(self, x: Tensor, state: State | None = None) -> tuple[Tensor, State]:
        b, t = x.shape[:2]
        h, c = self.init_state(b, x.shape[-2:]) if state is None else state
        xz = self.input_conv(x.flatten(0, 1))  # (B*T, 4*hidden, H, W): every frame in one call
        hs = []
        for z_x in xz.unflatten(0, (b, t)).unbind(1):  # (B, 4*hidden, H, W) per step
            h, c = _gates(z_x + self.hidden_conv(h), c)
            hs.append(h)
        return torch.stack(hs, dim=1), (h, c)  # (B, T, hidden, H, W)

    def step(self, x_t: Tensor, state: State) -> State:
        h, c = state
        return _gates(self.input_conv(x_t) + self.hidden_conv(h), c)


@dataclass
class ConvLSTMConfig:
    """A stack of ConvLSTM layers (the source's model: 16 channels, 3x3 kernels, 2 layers)."""

    in_channels: int
    hidden_channels: int = 16
    num_layers: int = 2
    kernel_size: int = 3
    forget_bias: float = 1.0


class ConvLSTM(nn.Module):
    """Stacked ConvLSTM layers, each layer's hidden sequence the next layer's input.

    Args:
        config: a :class:`ConvLSTMConfig`.

    Shapes:
        :meth:`forward`: ``x [B, T, C, H, W]`` -> ``(h_seq [B, T, hidden, H, W]`` of the top layer, states per layer).
        :meth:`step`: ``x_t [B, C, H, W]`` and the per-layer states -> ``(h_t [B, hidden, H, W], new states)``.
    """

    def __init__(self, config: ConvLSTMConfig) -> None:
        super().__init__()
        if config.num_layers < 1:
            raise ConfigError(f"ConvLSTM num_layers must be >= 1, got {config.num_layers}")
        self.config = config
        widths = [config.in_channels] + [config.hidden_channels] * config.num_layers
        self.layers = nn.ModuleList(
            ConvLSTMCell(widths[i], config.hidden_channels, config.kernel_size, config.forget_bias)
            for i in range(config.num_layers))

    def init_state(self, batch_size: int, grid_shape: tuple[int, int]) -> list[State]:
        return [layer.init_state(batch_size, grid_shape) for layer in self.layers]

    def forward(self, x: Tensor, state: list[State] | None = None) -> tuple[Tensor, list[State]]:
        if x.dim() != 5:
            raise ConfigError(f"ConvLSTM expects frames [B, T, C, H, W], got {tuple(x.shape)}")
        states = []
        for i, layer in enumerate(self.layers):  # layer by layer: each layer's input convs batch over all frames
            x, s = layer(x, None if state is None else state[i])
            states.append(s)
        return x, states

    def step(self, x_t: Tensor, state: list[State]) -> tuple[Tensor, list[State]]:
        states = []
        for layer, s in zip(self.layers, state):
            s = layer.step(x_t, s)
            x_t = s[0]
            states.append(s)
        return x_t, states
