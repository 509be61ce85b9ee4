"""Issue 30, item 2: the work of a recurrence that does not depend on its state runs once over all T frames.

Each check counts the calls of the input-side module over one forward of ``T`` frames: one call (all frames in one
batched op) passes, one per frame fails. The values themselves are checked against stepped references elsewhere
(tests/nn/test_convlstm.py, test_tgcn.py, test_attention.py).
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from tactile_zoo.nn.attention import SpikingSelfAttention
from tactile_zoo.nn.convlstm import ConvLSTM, ConvLSTMConfig
from tactile_zoo.nn.tgcn import TGCNCell

T, B = 6, 2


def _count_calls(module: nn.Module) -> list[int]:
    calls = [0]
    module.register_forward_hook(lambda *_: calls.__setitem__(0, calls[0] + 1))
    return calls


@pytest.mark.parametrize("backend", ["fused", "autograd", "compiled"])
def test_convlstm_input_convolutions_run_once_per_layer(backend: str) -> None:
    net = ConvLSTM(ConvLSTMConfig(in_channels=2, hidden_channels=4, num_layers=2, backend=backend))
    inputs = [_count_calls(layer.input_conv) for layer in net.layers]
    hidden = [_count_calls(layer.hidden_conv) for layer in net.layers]
    net(torch.randn(B, T, 2, 3, 5))  # (B, T, C, H, W)
    assert [c[0] for c in inputs] == [1, 1]  # all T*B frames in one convolution per layer
    # only the state-dependent part steps: the reference steps the hidden conv, the fused loop its own product
    assert [c[0] for c in hidden] == ([T, T] if backend == "autograd" else [0, 0])


def test_tgcn_graph_convolution_and_input_projection_run_once() -> None:
    edges = torch.tensor([[0, 1, 1, 2], [1, 0, 2, 1]])
    cell = TGCNCell(2, 4, edges, num_nodes=3)
    gc, lin_x, lin_h = _count_calls(cell.gc), _count_calls(cell.lin_x), _count_calls(cell.lin_h_ur)
    hs, _ = cell(torch.randn(T, B, 3, 2))  # (T, B, N, C)
    assert hs.shape == (T, B, 3, 4)
    assert (gc[0], lin_x[0]) == (1, 1)
    assert lin_h[0] == T  # the hidden halves of the gates are what steps


def test_spatial_attention_folds_time_into_the_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    attn = SpikingSelfAttention(dim=8, num_heads=2)
    seen: list[tuple[int, ...]] = []
    sdpa = F.scaled_dot_product_attention

    def counting(q: torch.Tensor, *args: object, **kwargs: object) -> torch.Tensor:
        seen.append(tuple(q.shape))
        return sdpa(q, *args, **kwargs)

    monkeypatch.setattr(F, "scaled_dot_product_attention", counting)
    out = attn(torch.randn(T, B, 5, 8))  # (T, B, L, D)
    assert out.shape == (T, B, 5, 8)
    assert seen == [(T * B, 2, 5, 4)]  # one call, frames as batch: (T*B, heads, L, d_k)
