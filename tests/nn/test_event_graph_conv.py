"""event_graph_conv: TAGConv / GCNConv over binary input events equals the dense backend (its oracle) to rounding,
outputs and gradients, and is the dense backend itself where the event path does not apply."""

from __future__ import annotations

import copy

import pytest
import torch

import tactile_zoo.nn.event_linear as el
from tactile_zoo.data.sensors import NEUTOUCH, USKIN_ALLEGRO
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.event_graph_conv import event_graph_conv
from tactile_zoo.nn.graph import FrameGraphConv


def _events(shape: tuple[int, ...], seed: int, dtype: torch.dtype) -> torch.Tensor:
    return (torch.rand(*shape, generator=torch.Generator().manual_seed(seed)) < 0.13).to(dtype)


def _run(fn, conv: FrameGraphConv, x: torch.Tensor, grad: torch.Tensor):
    conv.zero_grad(set_to_none=True)
    x = x.clone().requires_grad_()
    out = fn(x)
    out.backward(grad)
    return out.detach(), x.grad, {n: p.grad.clone() for n, p in conv.named_parameters()}


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
@pytest.mark.parametrize("kind,sensor,f_in,f_out,kw", [
    ("tag", NEUTOUCH, 2, 64, {}), ("tag", USKIN_ALLEGRO, 3, 16, {"K": 2}), ("gcn", NEUTOUCH, 2, 8, {}),
    ("tag", NEUTOUCH, 8, 4, {"normalize": False}),  # F_in > F_out: the dense backend applies the weights first
])
def test_equals_the_dense_backend(dtype: torch.dtype, tol: float, kind: str, sensor, f_in: int, f_out: int,
                                  kw: dict) -> None:
    torch.manual_seed(0)
    conv = FrameGraphConv(f_in, f_out, sensor.edge_index(), sensor.num_nodes, kind=kind, **kw).to(dtype)
    x = _events((5, 3, sensor.num_nodes, f_in), seed=1, dtype=dtype)
    grad = torch.randn(5, 3, sensor.num_nodes, f_out, dtype=dtype, generator=torch.Generator().manual_seed(2))
    ref = _run(conv, conv, x, grad)
    got = _run(lambda v: event_graph_conv(conv, v), conv, x, grad)
    pairs = [("out", got[0], ref[0]), ("x", got[1], ref[1])] + [(n, got[2][n], ref[2][n]) for n in ref[2]]
    for name, a, b in pairs:
        assert a.shape == b.shape and b.abs().max() > 0, name
        assert float((a - b).abs().max() / b.abs().max()) <= tol, name


def test_runs_one_event_product_and_falls_back_where_promised(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    apply = el._EventLinear.apply
    monkeypatch.setattr(el._EventLinear, "apply", lambda *a: calls.append(a[1].shape) or apply(*a))
    n = NEUTOUCH.num_nodes
    dense = FrameGraphConv(2, 8, NEUTOUCH.edge_index(), n)
    x = _events((4, n, 2), seed=3, dtype=torch.float32)
    event_graph_conv(dense, x)
    assert calls == [(n * 2, n * 8)]  # one product over the whole frame (E: N * F_in rows)
    pyg = FrameGraphConv(2, 8, NEUTOUCH.edge_index(), n, backend="pyg")
    pyg.load_state_dict(dense.state_dict())
    assert torch.equal(event_graph_conv(pyg, x), pyg(x)) and len(calls) == 1  # no hop matrices: the layer itself
    meta = copy.deepcopy(dense).to("meta")  # off CPU (CUDA in use): the dense backend
    assert event_graph_conv(meta, x.to("meta")).shape == (4, n, 8) and len(calls) == 1
    with pytest.raises(ConfigError, match="expects"):
        event_graph_conv(dense, x[..., :1])  # a wrong shape raises as the dense layer does
