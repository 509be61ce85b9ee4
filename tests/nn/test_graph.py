"""FrameGraphConv: the dense backend equals PyG's TAGConv / GCNConv (outputs, gradients, state_dict)."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo.nn.graph as graph_module
from tactile_zoo.data.sensors import BIOTAC_SP, NEUTOUCH, OPTOFORCE3, USKIN_ALLEGRO
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.graph import FrameGraphConv


def _random_graph(n: int, p: float, seed: int, symmetric: bool = True) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    adj = torch.rand(n, n, generator=gen) < p
    adj.fill_diagonal_(False)
    if symmetric:
        adj = adj | adj.t()
    return adj.nonzero().t().contiguous()


GRAPHS = {
    "neutouch_mst": (NEUTOUCH.edge_index(), NEUTOUCH.num_nodes),
    "neutouch_knn": (NEUTOUCH.edge_index("knn", k=4), NEUTOUCH.num_nodes),
    "biotac_sp": (BIOTAC_SP.edge_index(), BIOTAC_SP.num_nodes),
    "optoforce3": (OPTOFORCE3.edge_index(), OPTOFORCE3.num_nodes),
    "uskin_allegro": (USKIN_ALLEGRO.edge_index(), USKIN_ALLEGRO.num_nodes),
    "random_dense": (_random_graph(17, 0.4, 0), 17),
    "random_sparse_isolated": (_random_graph(23, 0.05, 1), 23),  # isolated nodes: zero degree
    "random_directed": (_random_graph(11, 0.3, 2, symmetric=False), 11),
}


def _pair(kind: str, f_in: int, f_out: int, edge_index: torch.Tensor, n: int, **kw):
    torch.manual_seed(0)
    dense = FrameGraphConv(f_in, f_out, edge_index, n, kind=kind, backend="dense", **kw)
    pyg = FrameGraphConv(f_in, f_out, edge_index, n, kind=kind, backend="pyg", **kw)
    pyg.load_state_dict(dense.state_dict())  # same keys: the dense backend holds the PyG module
    with torch.no_grad():  # a non-zero bias, so its gradient and broadcast are checked too
        for p in dense.parameters():
            if p.dim() == 1:
                p.normal_()
        pyg.load_state_dict(dense.state_dict())
    return dense, pyg


def _check(dense: FrameGraphConv, pyg: FrameGraphConv, shape: tuple[int, ...], dtype=torch.float32) -> None:
    dense, pyg = dense.to(dtype), pyg.to(dtype)
    gen = torch.Generator().manual_seed(5)
    x = torch.randn(shape, generator=gen, dtype=dtype)
    results = []
    for conv in (dense, pyg):
        xi = x.clone().requires_grad_(True)
        out = conv(xi)
        w = torch.randn(out.shape, generator=torch.Generator().manual_seed(6), dtype=dtype)
        grads = torch.autograd.grad((out * w).sum(), [xi, *conv.parameters()])
        results.append((out, grads))
    (out_d, grads_d), (out_p, grads_p) = results
    tol = dict(rtol=1e-4, atol=1e-5) if dtype == torch.float32 else dict(rtol=1e-9, atol=1e-10)
    torch.testing.assert_close(out_d, out_p, **tol)
    for gd, gp in zip(grads_d, grads_p):
        torch.testing.assert_close(gd, gp, **tol)


@pytest.mark.parametrize("graph", list(GRAPHS))
@pytest.mark.parametrize("kind", ["tag", "gcn"])
@pytest.mark.parametrize("f_in,f_out", [(2, 16), (12, 3)])  # hops before / after the weights
def test_dense_equals_pyg(graph: str, kind: str, f_in: int, f_out: int) -> None:
    edge_index, n = GRAPHS[graph]
    dense, pyg = _pair(kind, f_in, f_out, edge_index, n)
    _check(dense, pyg, (3, 5, n, f_in))


@pytest.mark.parametrize("kind", ["tag", "gcn"])
@pytest.mark.parametrize("f_in,f_out", [(2, 16), (12, 3)])
def test_dense_transposed_path_equals_pyg(monkeypatch: pytest.MonkeyPatch, kind: str, f_in: int, f_out: int) -> None:
    """The hop without the Kronecker factor (wide features) agrees too."""
    monkeypatch.setattr(graph_module, "KRON_LIMIT", 0)
    edge_index, n = GRAPHS["neutouch_mst"]
    _check(*_pair(kind, f_in, f_out, edge_index, n), (2, 4, n, f_in))


@pytest.mark.parametrize("kind,kw", [("tag", dict(K=0)), ("tag", dict(K=5)), ("tag", dict(normalize=False)),
                                     ("tag", dict(bias=False)), ("gcn", dict(improved=True)),
                                     ("gcn", dict(add_self_loops=False)), ("gcn", dict(normalize=False)),
                                     ("gcn", dict(flow="target_to_source"))])
def test_dense_follows_pyg_options(kind: str, kw: dict) -> None:
    edge_index, n = GRAPHS["random_directed"]
    _check(*_pair(kind, 3, 8, edge_index, n, **kw), (4, n, 3), dtype=torch.float64)


def test_edge_weights() -> None:
    edge_index, n = GRAPHS["neutouch_knn"]
    weight = torch.rand(edge_index.shape[1], generator=torch.Generator().manual_seed(1)) + 0.5
    for kind in ("tag", "gcn"):
        _check(*_pair(kind, 2, 8, edge_index, n, edge_weight=weight), (6, n, 2))


def test_batched_pyg_call_equals_per_frame_calls() -> None:
    """The premise of the single call: PyG aggregates along node_dim=-2 with leading batch dimensions."""
    edge_index, n = GRAPHS["neutouch_mst"]
    for kind in ("tag", "gcn"):
        conv = FrameGraphConv(2, 8, edge_index, n, kind=kind, backend="pyg")
        x = torch.randn(6, n, 2)
        per_frame = torch.stack([conv.conv(frame, edge_index) for frame in x.unbind(0)])
        torch.testing.assert_close(conv(x), per_frame, rtol=1e-5, atol=1e-6)


def test_leading_dimensions_and_state_dict_interchange() -> None:
    edge_index, n = GRAPHS["neutouch_mst"]
    dense = FrameGraphConv(2, 4, edge_index, n)
    assert dense.backend == "dense"
    x = torch.randn(2, 3, 5, n, 2)
    out = dense(x)
    assert out.shape == (2, 3, 5, n, 4)
    torch.testing.assert_close(dense(x[1, 2, 3]), out[1, 2, 3])  # a single frame (N, F)
    pyg = FrameGraphConv(2, 4, edge_index, n, backend="pyg")
    pyg.load_state_dict(dense.state_dict())
    torch.testing.assert_close(pyg(x), out, rtol=1e-5, atol=1e-6)
    assert set(dense.state_dict()) == {f"conv.lins.{k}.weight" for k in range(4)} | {"conv.bias"}


def _outputs_and_grads(conv: FrameGraphConv, x: torch.Tensor) -> list[torch.Tensor]:
    xi = x.clone().requires_grad_(True)
    out = conv(xi)
    up = torch.randn(out.shape, generator=torch.Generator().manual_seed(6), dtype=x.dtype)
    return [out, *torch.autograd.grad((out * up).sum(), [xi, *conv.parameters()])]


@pytest.mark.parametrize("kind,kw", [("tag", {}), ("tag", dict(bias=False)), ("gcn", {})])
@pytest.mark.parametrize("f_in,f_out", [(2, 64), (12, 3), (1, 16)])  # weights last / first; gcn: a one-column weight
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dense_weight_gradient_is_autograds_bit_for_bit(monkeypatch: pytest.MonkeyPatch, kind: str, kw: dict,
                                                        f_in: int, f_out: int, dtype: torch.dtype) -> None:
    """The dense backend's linear step copies the transposed output gradient before the weight gradient's product
    (MKL's fast path): outputs and every gradient equal plain F.linear under autograd bit for bit, on SGnet's 78000
    rows (2000 frames of 39 taxels), where MKL's slow path would be taken. weight_grad="fast" sums in another
    order: equal to rounding. (Bit-identity is MKL's behaviour, x86 builds of PyTorch; another BLAS may differ.)"""
    edge_index, n = GRAPHS["neutouch_mst"]
    torch.manual_seed(0)
    conv = FrameGraphConv(f_in, f_out, edge_index, n, kind=kind, **kw).to(dtype)
    x = (torch.rand(2000, n, f_in, generator=torch.Generator().manual_seed(5)) < 0.3).to(dtype)
    ours = _outputs_and_grads(conv, x)
    conv.weight_grad = "fast"
    fast = _outputs_and_grads(conv, x)
    with monkeypatch.context() as m:
        m.setattr(graph_module, "_tall_linear", lambda a, w, b, _mode="autograd": torch.nn.functional.linear(a, w, b))
        plain = _outputs_and_grads(conv, x)
    assert len(ours) == len(plain) and all(torch.equal(a, b) for a, b in zip(ours, plain))
    assert torch.equal(fast[0], plain[0])  # the forward is the same call
    rel = 1e-5 if dtype == torch.float32 else 1e-13  # sums of 78000 terms: relative to the largest entry
    for a, b in zip(fast[1:], plain[1:]):
        assert (a - b).abs().max() <= rel * b.abs().max()


def test_bad_arguments() -> None:
    edge_index, n = GRAPHS["neutouch_mst"]
    with pytest.raises(ConfigError, match="kind"):
        FrameGraphConv(2, 4, edge_index, n, kind="gat")
    with pytest.raises(ConfigError, match="backend"):
        FrameGraphConv(2, 4, edge_index, n, backend="sparse")
    with pytest.raises(ConfigError, match="weight_grad"):
        FrameGraphConv(2, 4, edge_index, n, weight_grad="fast", backend="pyg")
    with pytest.raises(ConfigError, match="weight_grad"):
        FrameGraphConv(2, 4, edge_index, n, weight_grad="exact")
    with pytest.raises(ConfigError, match="outside"):
        FrameGraphConv(2, 4, edge_index, 10)
    with pytest.raises(ConfigError, match="edge_index"):
        FrameGraphConv(2, 4, edge_index.t(), n)
    with pytest.raises(ConfigError, match="aggr"):
        FrameGraphConv(2, 4, edge_index, n, aggr="max")
    with pytest.raises(ConfigError, match="PyG arguments"):
        FrameGraphConv(2, 4, edge_index, n, kind="gcn", normalize=False, add_self_loops=True)
    conv = FrameGraphConv(2, 4, edge_index, n)
    with pytest.raises(ConfigError, match=f"\\(..., {n}, 2\\)"):
        conv(torch.randn(3, n, 3))
    with pytest.raises(ConfigError):
        conv(torch.randn(3, n - 1, 2))
