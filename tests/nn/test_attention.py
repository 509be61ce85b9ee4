"""MSA-SNN (paper eqs. 7-9) against a hand-written reference with the same weights."""

from __future__ import annotations

import math

import pytest
import torch

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.attention import SpikingSelfAttention
from tactile_zoo.nn.lif import LIFConfig

TAU, V_TH = 2.0, 0.3


def ref_lif(x: torch.Tensor) -> torch.Tensor:
    """The paper's LIF, eqs. 2-4, V_reset = 0, stepped by hand: H = V + (X - V)/tau, S = [H > V_th], V = H (1 - S)."""
    v = torch.zeros_like(x[0])
    out = []
    for x_t in x.unbind(0):
        h = v + (x_t - v) / TAU
        s = (h > V_TH).to(x.dtype)
        v = h * (1 - s)
        out.append(s)
    return torch.stack(out)


def ln(a: torch.Tensor, w: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    mu = a.mean(-1, keepdim=True)
    var = ((a - mu) ** 2).mean(-1, keepdim=True)
    return (a - mu) / torch.sqrt(var + 1e-5) * w + b


def ref_msa(m: SpikingSelfAttention, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    """Eqs. 7-9 written out: three separate Q/K/V chains, a Python loop over heads, explicit softmax."""
    d, heads = m.dim, m.num_heads
    dh = d // heads
    chains, spikes = [], []
    for j in range(3):  # Q, K, V: each LN(Linear(LIF(LN(Linear(X))))) with its own weights
        a = x @ m.qkv_in.weight[j * d:(j + 1) * d].T + m.qkv_in.bias[j * d:(j + 1) * d]
        s = ref_lif(ln(a, m.qkv_in_norm_w[j], m.qkv_in_norm_b[j]))
        spikes.append(s)
        z = s @ m.qkv_out_w[j].T + m.qkv_out_b[j, 0]
        chains.append(ln(z, m.qkv_out_norm_w[j, 0], m.qkv_out_norm_b[j, 0]))
    q, k, v = chains
    outs, weights = [], []
    for h in range(heads):
        sl = slice(h * dh, (h + 1) * dh)
        att = torch.softmax(q[..., sl] @ k[..., sl].transpose(-1, -2) / math.sqrt(dh), dim=-1)  # (T, B, L, L)
        weights.append(att)
        outs.append(att @ v[..., sl])
    s_out = ref_lif(torch.cat(outs, dim=-1))
    spikes.append(s_out)
    y = ln(s_out @ m.proj.weight.T + m.proj.bias, m.proj_norm.weight, m.proj_norm.bias)
    return y, torch.stack(weights, dim=-3), spikes


def make(dim: int = 16, heads: int = 4, seed: int = 0) -> SpikingSelfAttention:
    torch.manual_seed(seed)
    m = SpikingSelfAttention(dim, heads, LIFConfig(tau=TAU, v_th=V_TH)).double()
    with torch.no_grad():  # non-trivial LayerNorm affines, distinct per branch, so a mixed-up branch shows
        for name, p in m.named_parameters():
            if "norm" in name:
                p.copy_(torch.randn_like(p) * 0.3 + (1.0 if name.endswith("_w") or name.endswith("weight") else 0.0))
    return m


def test_matches_reference_of_eqs_7_to_9() -> None:
    m = make()
    x = torch.randn(6, 2, 5, 16, dtype=torch.float64)
    y_ref, w_ref, spikes = ref_msa(m, x)
    for s in spikes:  # the reference must exercise the neurons: some spikes, not all
        assert 0.05 < s.mean().item() < 0.95
    torch.testing.assert_close(m(x), y_ref)
    torch.testing.assert_close(m.attention_weights(x), w_ref)


def test_shapes_heads_and_weights_sum_to_one() -> None:
    m = SpikingSelfAttention(8, 2)
    x = torch.randn(3, 2, 4, 7, 8)  # (T, two batch dims, L, D)
    assert m(x).shape == x.shape
    w = m.attention_weights(x)
    assert w.shape == (3, 2, 4, 2, 7, 7)
    torch.testing.assert_close(w.sum(-1), torch.ones(w.shape[:-1]))
    with pytest.raises(ConfigError, match="multiple of num_heads"):
        SpikingSelfAttention(10, 4)


def test_gradients_finite_on_every_parameter() -> None:
    m = make(seed=1).float()
    x = torch.randn(5, 3, 6, 16, requires_grad=True)
    m(x).square().sum().backward()
    for name, p in m.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, f"no gradient reaches {name}"
    assert torch.isfinite(x.grad).all()


def test_pieces_equal_whole_and_frames_do_not_see_the_future() -> None:
    m = make(seed=2)
    x = torch.randn(7, 2, 5, 16, dtype=torch.float64)
    whole = m(x)
    first, state = m.run(x[:3])
    second, _ = m.run(x[3:], state)
    torch.testing.assert_close(torch.cat([first, second]), whole)
    x2 = x.clone()
    x2[4:] += torch.randn_like(x2[4:])  # change the future
    y2 = m(x2)
    torch.testing.assert_close(y2[:4], whole[:4])
    assert not torch.allclose(y2[4:], whole[4:])
