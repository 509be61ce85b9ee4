"""ConvLSTM: the Shi et al. update without peepholes, checked gate by gate; sequence forward equals stepping."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.convlstm import ConvLSTM, ConvLSTMCell, ConvLSTMConfig, _FusedRecurrence, _tap_index


def reference_step(cell: ConvLSTMCell, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """One step written gate by gate from the equations, with each gate's kernels sliced out of the layer."""
    hid = cell.hidden_channels
    wx, bx, wh = cell.input_conv.weight, cell.input_conv.bias, cell.hidden_conv.weight
    pad = wx.shape[-1] // 2

    def pre(k: int) -> torch.Tensor:  # gate k in the layer's order i, f, o, g
        sl = slice(k * hid, (k + 1) * hid)
        return F.conv2d(x, wx[sl], bx[sl], padding=pad) + F.conv2d(h, wh[sl], padding=pad)

    i, f, o, g = torch.sigmoid(pre(0)), torch.sigmoid(pre(1)), torch.sigmoid(pre(2)), torch.tanh(pre(3))
    c = f * c + i * g
    return o * torch.tanh(c), c


def test_step_follows_the_equations() -> None:
    torch.manual_seed(0)
    cell = ConvLSTMCell(3, 5, kernel_size=3).double()
    with torch.no_grad():  # random biases too, so a mix-up of gate slices cannot hide behind zero biases
        cell.input_conv.bias.normal_()
    x = torch.randn(2, 3, 4, 6, dtype=torch.float64)
    h, c = torch.randn(2, 5, 4, 6, dtype=torch.float64), torch.randn(2, 5, 4, 6, dtype=torch.float64)
    got = cell.step(x, (h, c))
    want = reference_step(cell, x, h, c)
    assert torch.allclose(got[0], want[0], atol=1e-12) and torch.allclose(got[1], want[1], atol=1e-12)


def test_sequence_forward_equals_stepping_and_is_causal() -> None:
    torch.manual_seed(1)
    net = ConvLSTM(ConvLSTMConfig(2, 4, num_layers=2)).double()
    x = torch.randn(3, 7, 2, 5, 4, dtype=torch.float64)  # (B, T, C, H, W)
    seq, states = net(x)
    assert seq.shape == (3, 7, 4, 5, 4) and len(states) == 2
    state = net.init_state(3, (5, 4))
    for t in range(7):
        h, state = net.step(x[:, t], state)
        assert torch.allclose(h, seq[:, t], atol=1e-12)
    for (h1, c1), (h2, c2) in zip(state, states):
        assert torch.allclose(h1, h2, atol=1e-12) and torch.allclose(c1, c2, atol=1e-12)
    x2 = x.clone()
    x2[:, 4] += 1.0  # a change at t = 4 leaves every earlier output alone and moves the later ones
    seq2, _ = net(x2)
    assert torch.equal(seq2[:, :4], seq[:, :4]) and not torch.allclose(seq2[:, 4:], seq[:, 4:])


def test_one_frame_forward_takes_the_step_path_with_the_same_result() -> None:
    torch.manual_seed(5)
    net = ConvLSTM(ConvLSTMConfig(2, 4, num_layers=2)).double()
    x = torch.randn(3, 5, 2, 5, 4, dtype=torch.float64)
    seq, _ = net(x)
    first, state = net(x[:, :1])  # from rest
    assert first.shape == (3, 1, 4, 5, 4) and torch.allclose(first[:, 0], seq[:, 0], atol=1e-12)
    _, state = net(x[:, 1:3], state)  # a sequence from that state
    last, _ = net(x[:, 3:4], state)  # then one frame from a carried state
    assert torch.allclose(last[:, 0], seq[:, 3], atol=1e-12)


def test_layers_stack_hidden_sequences() -> None:
    torch.manual_seed(2)
    net = ConvLSTM(ConvLSTMConfig(2, 3, num_layers=2))
    x = torch.randn(2, 5, 2, 3, 3)
    first, _ = net.layers[0](x)
    top, _ = net.layers[1](first)
    assert torch.allclose(net(x)[0], top, atol=1e-6)


def test_same_padding_keeps_tiny_grids_and_initial_state_is_zero() -> None:
    cell = ConvLSTMCell(4, 6)
    x = torch.randn(2, 3, 4, 1, 3)  # a 1x3 grid (OptoForce)
    seq, (h, c) = cell(x)
    assert seq.shape == (2, 3, 6, 1, 3)
    # from a zero state the first step only sees the input: passing zeros explicitly changes nothing
    zeros = (torch.zeros(2, 6, 1, 3), torch.zeros(2, 6, 1, 3))
    assert torch.allclose(cell(x[:, :1], zeros)[0], seq[:, :1])


def test_keras_style_initialisation() -> None:
    cell = ConvLSTMCell(2, 16, kernel_size=3)
    bias = cell.input_conv.bias.detach()
    assert torch.equal(bias[16:32], torch.ones(16))  # forget gate (unit_forget_bias)
    assert torch.equal(torch.cat([bias[:16], bias[32:]]), torch.zeros(48))
    w = cell.hidden_conv.weight.detach().flatten(1)  # (64, 144): orthogonal rows
    assert torch.allclose(w @ w.t(), torch.eye(64), atol=1e-5)
    assert cell.hidden_conv.bias is None  # one bias per gate, on the input side


@pytest.mark.parametrize("backend", ["fused", "autograd"])
def test_gradients_match_finite_differences(backend: str) -> None:
    torch.manual_seed(3)
    cell = ConvLSTMCell(1, 2, backend=backend).double()
    x = torch.randn(1, 3, 1, 2, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda inp: cell(inp)[0], (x,))


def test_fused_time_loop_gradcheck_on_every_input() -> None:
    torch.manual_seed(4)
    hid = 2
    b, height, width = 2, 3, 2
    cols = b * height * width  # the fused loop works channel-major: one column per (sample, cell)
    xz = torch.randn(4, 4 * hid, cols, dtype=torch.float64, requires_grad=True)  # (T, 4h, B*H*W)
    w = (0.5 * torch.randn(4 * hid, hid, 3, 3, dtype=torch.float64)).requires_grad_()
    h0 = torch.randn(hid, cols, dtype=torch.float64, requires_grad=True)
    c0 = torch.randn(hid, cols, dtype=torch.float64, requires_grad=True)
    # both outputs, the whole hidden sequence and the last cell state, carry gradient
    assert torch.autograd.gradcheck(lambda *a: _FusedRecurrence.apply(*a, (b, height, width)), (xz, w, h0, c0))


def test_tap_index_gathers_the_im2col_matrix_of_a_same_convolution() -> None:
    torch.manual_seed(6)
    b, hid, height, width, k = 2, 3, 4, 5, 3
    h = torch.randn(b, hid, height, width, dtype=torch.float64)
    w = torch.randn(4 * hid, hid, k, k, dtype=torch.float64)
    rows = torch.cat([h.transpose(0, 1).reshape(hid, -1), torch.zeros(hid, 1, dtype=torch.float64)], 1)
    cols = rows[:, _tap_index(b, height, width, k)].reshape(hid * k * k, -1)  # (h*k*k, B*H*W)
    out = w.reshape(4 * hid, -1) @ cols  # (4h, B*H*W)
    want = F.conv2d(h, w, padding=1).transpose(0, 1).reshape(4 * hid, -1)
    assert torch.allclose(out, want, atol=1e-12)


def test_fused_backend_equals_the_autograd_reference() -> None:
    torch.manual_seed(5)
    cfg = {"in_channels": 2, "hidden_channels": 4, "num_layers": 2}
    fused = ConvLSTM(ConvLSTMConfig(**cfg, backend="fused")).double()
    ref = ConvLSTM(ConvLSTMConfig(**cfg, backend="autograd")).double()
    ref.load_state_dict(fused.state_dict())
    x = torch.randn(3, 9, 2, 4, 5, dtype=torch.float64)
    outs = []
    for net in (fused, ref):
        xi = x.clone().requires_grad_()
        seq, states = net(xi)
        # a loss on the sequence and on the last states of both layers, so every gradient path is exercised
        loss = (seq * torch.linspace(-1, 1, seq.numel(), dtype=torch.float64).view_as(seq)).sum()
        loss = loss + sum((h ** 2).sum() + c.sin().sum() for h, c in states)
        loss.backward()
        outs.append((seq.detach(), xi.grad, [p.grad for p in net.parameters()]))
    (s1, g1, p1), (s2, g2, p2) = outs
    assert torch.allclose(s1, s2, atol=1e-12) and torch.allclose(g1, g2, atol=1e-10)
    assert all(torch.allclose(a, b, atol=1e-10) for a, b in zip(p1, p2))
    with torch.no_grad():  # the inference path (no buffers for backward) gives the same sequence
        assert torch.allclose(fused(x)[0], s1, atol=1e-12)


@pytest.mark.parametrize("kwargs", [{"kernel_size": 2}, {"kernel_size": 0}, {"hidden_channels": 0},
                                    {"backend": "cuda-graphs"}])
def test_bad_arguments_are_config_errors(kwargs: dict) -> None:
    args = {"in_channels": 2, "hidden_channels": 4, **kwargs}
    with pytest.raises(ConfigError):
        ConvLSTMCell(**args)


def test_bad_shapes_and_layer_counts_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="num_layers"):
        ConvLSTM(ConvLSTMConfig(2, 4, num_layers=0))
    with pytest.raises(ConfigError, match="B, T, C, H, W"):
        ConvLSTM(ConvLSTMConfig(2, 4))(torch.randn(2, 2, 3, 3))
