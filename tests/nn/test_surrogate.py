"""Surrogate gradients: each derivative equals the snnTorch surrogate's backward; the spike is u > 0."""

from __future__ import annotations

import math

import pytest
import torch
from snntorch import surrogate as snn_surrogate

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.surrogate import make_surrogate, open_interval_mask


def _snntorch_grad(fn, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    leaf = u.clone().requires_grad_(True)
    spikes = fn(leaf)
    (grad,) = torch.autograd.grad(spikes.sum(), leaf)
    return spikes.detach(), grad


U = torch.cat([torch.linspace(-3, 3, 241), torch.tensor([-0.5, 0.5, 0.0, -1e-7, 1e-7])])


@pytest.mark.parametrize("name,kw,reference", [
    ("rect", dict(width=1.0), None),
    ("rect", dict(width=0.3), None),
    ("atan", dict(alpha=2.0), snn_surrogate.atan(alpha=2.0)),
    ("atan", dict(alpha=5.0), snn_surrogate.atan(alpha=5.0)),
    ("sigmoid", dict(slope=5.0), snn_surrogate.sigmoid(slope=5.0)),
    ("sigmoid", dict(slope=25.0), snn_surrogate.sigmoid(slope=25.0)),
])
def test_grad_equals_snntorch_backward(name: str, kw: dict, reference) -> None:
    sur = make_surrogate(name, **kw)
    spikes, grad = _snntorch_grad(sur.spike_fn, U)
    assert torch.equal(spikes, (U > 0).float())
    if reference is not None:  # the named snnTorch surrogate itself
        ref_spikes, ref_grad = _snntorch_grad(reference, U)
        assert torch.equal(spikes, ref_spikes)
        torch.testing.assert_close(grad, ref_grad, rtol=1e-5, atol=1e-7)
    else:  # TactileSGNet's rectangle: 1 strictly inside the window
        assert torch.equal(grad, (U.abs() < kw["width"] / 2).float())
    torch.testing.assert_close(sur.grad(U), grad, rtol=1e-5, atol=1e-7)
    out = torch.empty_like(U)
    assert sur.grad(U, out=out) is out


def test_sigmoid_stays_finite_where_snntorch_overflows() -> None:
    far = torch.tensor([-10.0, -50.0])
    _, nan = _snntorch_grad(snn_surrogate.sigmoid(slope=25), far)
    assert torch.isnan(nan).all()
    grad = make_surrogate("sigmoid").grad(far)
    assert torch.isfinite(grad).all() and (grad >= 0).all()


def test_custom_callable() -> None:
    fn = snn_surrogate.fast_sigmoid(slope=10)
    sur = make_surrogate(fn)
    assert sur.kind == "custom" and sur.spike_fn is fn
    torch.testing.assert_close(sur.grad(U), 1 / (10 * U.abs() + 1) ** 2)


def test_open_interval_mask() -> None:
    u = torch.tensor([-1.0, 0.5, 0.50000006, 2.0, math.inf])
    assert open_interval_mask(u, 0.5, math.inf).tolist() == [0, 0, 1, 1, 0]
    assert open_interval_mask(u.double(), -1.0, 2.0).dtype == torch.float64


@pytest.mark.parametrize("args", [("tanh",), ("rect", 0.0), ("atan", 1.0, -2.0)])
def test_bad_surrogate(args: tuple) -> None:
    with pytest.raises(ConfigError):
        make_surrogate(*args)
