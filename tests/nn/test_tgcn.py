"""T-GCN cell (paper eqs. 10-13) against a step-by-step reference, attention over frames, streaming, TGCN2 option."""

from __future__ import annotations

import importlib.util

import pytest
import torch

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.tgcn import TemporalAttention, TemporalGraphAttention, TGCNCell

N = 6
EDGES = torch.tensor([[0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 0, 5], [1, 0, 2, 1, 3, 2, 4, 3, 5, 4, 5, 0]])  # a ring


def tgt_importable() -> tuple[bool, str]:
    if importlib.util.find_spec("torch_geometric_temporal") is None:
        return False, "torch-geometric-temporal is not installed"
    try:
        import torch_geometric_temporal.nn.recurrent  # noqa: F401
    except Exception as exc:  # its import needs torch-sparse, absent here
        return False, f"torch-geometric-temporal cannot be imported: {type(exc).__name__}: {exc}"
    return True, ""


TGT_OK, TGT_REASON = tgt_importable()


def test_cell_matches_step_by_step_reference_of_eqs_10_to_13() -> None:
    torch.manual_seed(0)
    cell = TGCNCell(3, 5, EDGES, N).double()
    x = torch.randn(7, 2, N, 3, dtype=torch.float64)
    hid = 5
    wx, bx = cell.lin_x.weight, cell.lin_x.bias  # (3H, F), the GC halves of W_u, W_r, W_c and their biases
    wh_ur, wh_c = cell.lin_h_ur.weight, cell.lin_h_c.weight
    # W_g of eqs. 10-12 acts on the concatenation [GC(A, X_t), h]: rebuild each one whole
    w_u = torch.cat([wx[:hid], wh_ur[:hid]], dim=1)
    w_r = torch.cat([wx[hid:2 * hid], wh_ur[hid:]], dim=1)
    w_c = torch.cat([wx[2 * hid:], wh_c], dim=1)
    b_u, b_r, b_c = bx[:hid], bx[hid:2 * hid], bx[2 * hid:]
    h = torch.zeros(2, N, hid, dtype=torch.float64)
    ref = []
    for t in range(x.shape[0]):
        gc = cell.gc(x[t])  # GC(A, X_t), one frame at a time
        u = torch.sigmoid(torch.cat([gc, h], -1) @ w_u.T + b_u)  # eq. 10
        r = torch.sigmoid(torch.cat([gc, h], -1) @ w_r.T + b_r)  # eq. 11
        c = torch.tanh(torch.cat([gc, r * h], -1) @ w_c.T + b_c)  # eq. 12
        h = u * h + (1 - u) * c  # eq. 13
        ref.append(h)
    hs, last = cell(x)
    torch.testing.assert_close(hs, torch.stack(ref))
    torch.testing.assert_close(last, ref[-1])
    # continuing from a state equals running whole
    a, h3 = cell(x[:3])
    b, _ = cell(x[3:], h3)
    torch.testing.assert_close(torch.cat([a, b]), hs)


def test_temporal_attention_weights_sum_to_one_and_weight_the_frames() -> None:
    torch.manual_seed(1)
    att = TemporalAttention(4, 8).double()
    f = torch.randn(9, 3, 4, dtype=torch.float64)
    out, alpha = att(f)
    assert alpha.shape == (9, 3)
    torch.testing.assert_close(alpha.sum(0), torch.ones(3, dtype=torch.float64))
    e = att.score(f).squeeze(-1)  # input-dependent scores
    torch.testing.assert_close(alpha, torch.exp(e) / torch.exp(e).sum(0))
    torch.testing.assert_close(out, (alpha[..., None] * f).sum(0))
    assert alpha.std(0).min() > 0  # not uniform: the weights depend on the frames
    # the online softmax over chunks equals the softmax over the whole sequence
    o1, st = att.update(f[:4], None)
    torch.testing.assert_close(o1, att(f[:4])[0])
    o2, _ = att.update(f[4:], st)
    torch.testing.assert_close(o2, out)


@pytest.mark.parametrize("pool", ["mean", "flatten"])
def test_branch_streams_frame_by_frame_and_gradients_are_finite(pool: str) -> None:
    torch.manual_seed(2)
    branch = TemporalGraphAttention(2, 4, EDGES, N, pool=pool, attn_dim=6).double()
    x = torch.randn(6, 2, N, 2, dtype=torch.float64)
    state = None
    for t in range(x.shape[0]):
        out, state = branch.run(x[t:t + 1], state)
        torch.testing.assert_close(out, branch(x[:t + 1]))
    assert out.shape == (2, branch.out_features) and branch.out_features == (N * 4 if pool == "flatten" else 4)
    branch.float()
    branch(x.float()).square().sum().backward()
    for name, p in branch.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


def test_bad_options_raise_config_error() -> None:
    with pytest.raises(ConfigError, match="temporal_backend"):
        TemporalGraphAttention(2, 4, EDGES, N, temporal_backend="cuda-magic")
    with pytest.raises(ConfigError, match="pool"):
        TemporalGraphAttention(2, 4, EDGES, N, pool="max")


@pytest.mark.skipif(TGT_OK, reason="torch-geometric-temporal imports here; the trains test covers it")
def test_tgt_backend_unavailable_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="torch-geometric-temporal"):
        TemporalGraphAttention(2, 4, EDGES, N, temporal_backend="tgt")


@pytest.mark.skipif(not TGT_OK, reason=TGT_REASON)
def test_tgt_backend_trains() -> None:  # pragma: no cover - runs only where the optional extra imports
    torch.manual_seed(3)
    branch = TemporalGraphAttention(2, 8, EDGES, N, temporal_backend="tgt")
    head = torch.nn.Linear(branch.out_features, 2)
    x = torch.randn(8, 5, N, 2)
    y = torch.tensor([0, 1, 0, 1, 1, 0, 1, 0])
    x[y == 1, :, :, 0] += 1.0  # a separable signal
    opt = torch.optim.Adam([*branch.parameters(), *head.parameters()], lr=1e-2)
    losses = []
    for _ in range(30):
        loss = torch.nn.functional.cross_entropy(head(branch(x.transpose(0, 1))), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.3 * losses[0]
