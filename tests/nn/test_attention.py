"""MSA-SNN (paper eqs. 7-9) against a hand-written reference with the same weights, and its two implementations of
eq. 8 (``attention="fused"``: SDPA; ``"explicit"``: :func:`explicit_attention`) against each other."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn import attention as attention_module
from tactile_zoo.nn.attention import SpikingSelfAttention, explicit_attention
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


def make(dim: int = 16, heads: int = 4, seed: int = 0, **kwargs: object) -> SpikingSelfAttention:
    torch.manual_seed(seed)
    m = SpikingSelfAttention(dim, heads, LIFConfig(tau=TAU, v_th=V_TH), **kwargs).double()
    with torch.no_grad():  # non-trivial LayerNorm affines, distinct per branch, so a mixed-up branch shows
        for name, p in m.named_parameters():
            if "norm" in name:
                p.copy_(torch.randn_like(p) * 0.3 + (1.0 if name.endswith("_w") or name.endswith("weight") else 0.0))
    return m


@pytest.mark.parametrize("attention", ["fused", "explicit"])
def test_matches_reference_of_eqs_7_to_9(attention: str) -> None:
    m = make(attention=attention)
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


# ------------------------------------------------------------------------------- eq. 8: explicit against fused
def qkv(shape: tuple[int, ...] = (6, 39, 4, 16), dtype: torch.dtype = torch.float64, seed: int = 0
        ) -> list[torch.Tensor]:
    """Q, K, V laid out as the block lays them out: transposed views ``(B, heads, L, d_k)`` of ``(B, L, heads, d_k)``,
    so a kernel that assumes contiguous input gets the heads mixed up."""
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=g, dtype=dtype).transpose(1, 2).requires_grad_() for _ in range(3)]


def test_explicit_attention_equals_sdpa_with_gradients() -> None:
    q, k, v = qkv()
    grad = torch.randn(q.shape, dtype=q.dtype)
    outs = []
    for fn in (explicit_attention, F.scaled_dot_product_attention):
        o = fn(q, k, v)
        g = torch.autograd.grad(o, (q, k, v), grad)
        outs.append((o, g))
    (o, g), (o_ref, g_ref) = outs
    assert o.shape == o_ref.shape == (6, 4, 39, 16)
    torch.testing.assert_close(o, o_ref)
    for a, b in zip(g, g_ref):  # dQ, dK, dV: the hand-written backward against SDPA's
        torch.testing.assert_close(a, b)


def test_explicit_attention_backward_passes_gradcheck_and_any_batch_dims() -> None:
    q, k, v = qkv((2, 5, 3, 4))
    assert torch.autograd.gradcheck(explicit_attention, (q, k, v))
    q, k, v = (torch.randn(shape, dtype=torch.float64) for shape in [(2, 3, 7, 8)] * 3)  # batch dims (2, 3), L = 7
    torch.testing.assert_close(explicit_attention(q, k, v), F.scaled_dot_product_attention(q, k, v))
    torch.testing.assert_close(explicit_attention(q[0, 0], k[0, 0], v[0, 0]),  # no batch dims
                               F.scaled_dot_product_attention(q[0, 0], k[0, 0], v[0, 0]))
    with pytest.raises(ConfigError, match="one shape"):  # self-attention only: Q, K and V packed together
        explicit_attention(q, k, v[..., :5])


def test_explicit_attention_float32_close_to_sdpa_at_tacformer_shape() -> None:
    """Float32 at Tacformer's shape (39 tokens, 4 heads of 16): the same to float32 rounding, not bit for bit."""
    q, k, v = qkv((40, 39, 4, 16), dtype=torch.float32, seed=3)
    o, o_ref = explicit_attention(q, k, v), F.scaled_dot_product_attention(q, k, v)
    torch.testing.assert_close(o, o_ref, rtol=1e-5, atol=1e-5)
    g = torch.autograd.grad(o.square().sum(), (q, k, v))
    g_ref = torch.autograd.grad(o_ref.square().sum(), (q, k, v))
    for a, b in zip(g, g_ref):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_explicit_attention_dropout_is_on_the_probabilities() -> None:
    q, k, v = qkv((3, 6, 2, 4))
    torch.manual_seed(5)
    o = explicit_attention(q, k, v, dropout_p=0.4)
    torch.manual_seed(5)  # the same mask, applied by hand to softmax(Q K^T / sqrt(d_k))
    p = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(q.shape[-1]), dim=-1)
    ref = F.dropout(p.reshape(-1, 6, 6), 0.4, training=True).view(p.shape) @ v
    torch.testing.assert_close(o, ref)
    assert not torch.allclose(o, explicit_attention(q, k, v))  # the mask did something
    grad = torch.randn(o.shape, dtype=o.dtype)
    grads = torch.autograd.grad(o, (q, k, v), grad)  # the hand-written backward through the mask, against autograd's
    for g, g_ref in zip(grads, torch.autograd.grad(ref, (q, k, v), grad)):
        torch.testing.assert_close(g, g_ref)


def test_the_block_explicit_equals_fused_outputs_and_gradients(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole MSA-SNN block, float64, same weights: output, every parameter's gradient and the input's; and each
    kind really runs its own kernel (a block that ignored ``attention`` would pass the comparison)."""
    calls: list[str] = []
    sdpa = F.scaled_dot_product_attention
    packed = attention_module._packed_attention
    monkeypatch.setattr(attention_module, "_packed_attention",
                        lambda *a, **kw: calls.append("explicit") or packed(*a, **kw))
    monkeypatch.setattr(attention_module.F, "scaled_dot_product_attention",
                        lambda *a, **kw: calls.append("fused") or sdpa(*a, **kw))
    results = []
    for attention in ("fused", "explicit"):
        m = make(seed=4, attention=attention)
        x = torch.randn(5, 2, 7, 16, dtype=torch.float64, generator=torch.Generator().manual_seed(1),
                        requires_grad=True)
        y = m(x)
        assert calls == [attention]
        calls.clear()
        y.backward(torch.cos(torch.arange(y.numel(), dtype=y.dtype)).view(y.shape))
        results.append((y, x.grad, {n: p.grad for n, p in m.named_parameters()}))
    (y_f, gx_f, gp_f), (y_e, gx_e, gp_e) = results
    torch.testing.assert_close(y_e, y_f)
    torch.testing.assert_close(gx_e, gx_f)
    assert gp_e.keys() == gp_f.keys()
    for name in gp_f:
        torch.testing.assert_close(gp_e[name], gp_f[name], msg=name)
    assert gp_f["qkv_out_w"].abs().sum() > 0  # gradients pass through the attention into the Q/K/V chains


def test_the_block_applies_attention_dropout_only_in_training_for_both_kinds() -> None:
    x = torch.randn(4, 2, 6, 16, dtype=torch.float64)
    for attention in ("fused", "explicit"):
        m = make(seed=6, attention=attention)
        plain = m(x)
        m.attn_dropout = 0.5
        m.eval()
        torch.testing.assert_close(m(x), plain)  # eval: no dropout
        m.train()
        torch.manual_seed(0)
        assert not torch.allclose(m(x), plain), attention


def test_a_bad_attention_kind_is_a_config_error_naming_the_argument() -> None:
    with pytest.raises(ConfigError, match=r"attention must be one of 'fused', 'explicit', got 'flash'"):
        SpikingSelfAttention(16, 4, attention="flash")
