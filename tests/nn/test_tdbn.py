"""Threshold-dependent batch norm: the paper's rule (statistics per channel over time, batch and space, scaled by
alpha * V_th) in training and evaluation mode, its running estimates, its gradients and its accuracy."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.tdbn import TdBatchNorm


def _reference(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, threshold: float = 0.5, alpha: float = 1.0,
               eps: float = 1e-5) -> torch.Tensor:
    """The rule written out (as DeepTactile's source does, channels last): biased batch statistics over every
    dimension but the last."""
    dims = tuple(range(x.dim() - 1))
    mean, var = x.mean(dims), x.var(dims, unbiased=False)
    return alpha * threshold * (x - mean) / torch.sqrt(var + eps) * weight + bias


def _layer(channels: int, seed: int = 0, **kw: float) -> TdBatchNorm:
    torch.manual_seed(seed)
    layer = TdBatchNorm(channels, **kw)
    with torch.no_grad():  # away from the (1, 0) start, so that a weight or bias left out would show
        layer.weight.uniform_(0.5, 1.5)
        layer.bias.uniform_(-0.3, 0.3)
    return layer


def test_training_mode_is_the_rule_to_float32_accuracy_with_its_gradients() -> None:
    # A (T, B, N, F) batch with a large mean: the rows' statistics must be summed accurately. torch's CPU batch_norm
    # of (M, F) rows is off by 3e-6 here (its float32 running sums), 8x the bound below.
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(30, 4, 39, 64, generator=gen) * 3 + 5
    layer = _layer(64, threshold=0.5, alpha=0.7)
    xa = x.clone().requires_grad_(True)
    out = layer(xa)
    xd = x.double().requires_grad_(True)
    wd, bd = (p.detach().double().requires_grad_(True) for p in (layer.weight, layer.bias))
    ref = _reference(xd, wd, bd, 0.5, 0.7)
    assert out.shape == x.shape and (out.double() - ref).abs().max() < 1e-6
    upstream = torch.randn(x.shape, generator=gen)
    out.backward(upstream)
    ref.backward(upstream.double())
    torch.testing.assert_close(xa.grad.double(), xd.grad, rtol=0, atol=1e-6)
    torch.testing.assert_close(layer.weight.grad.double(), wd.grad, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(layer.bias.grad.double(), bd.grad, rtol=1e-5, atol=1e-4)


def test_running_estimates_follow_the_batch_and_serve_evaluation() -> None:
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(12, 3, 5, 8, generator=gen) * 2 + 1
    layer = _layer(8, momentum=0.1)
    layer(x)
    rows = x.reshape(-1, 8).double()
    torch.testing.assert_close(layer.running_mean.double(), 0.1 * rows.mean(0), rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(layer.running_var.double(), 0.9 + 0.1 * rows.var(0, unbiased=True), rtol=1e-6,
                               atol=1e-7)  # the running variance is unbiased, as nn.BatchNorm's
    assert int(layer.num_batches_tracked) == 1
    layer.eval()
    frame = torch.randn(2, 5, 8, generator=gen)  # one frame: evaluation is an affine map per channel
    want = 0.5 * (frame - layer.running_mean) / torch.sqrt(layer.running_var + layer.eps) * layer.weight + layer.bias
    torch.testing.assert_close(layer(frame), want, rtol=1e-6, atol=1e-6)
    assert int(layer.num_batches_tracked) == 1  # evaluation leaves the estimates alone
    cumulative = _layer(8, momentum=None)  # nn.BatchNorm's momentum=None: the plain average of the batches
    cumulative(x)
    cumulative(2 * x)
    torch.testing.assert_close(cumulative.running_mean.double(), 1.5 * rows.mean(0), rtol=1e-6, atol=1e-6)


def test_the_statistics_pool_every_leading_dimension_whatever_the_layout() -> None:
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(6, 4, 7, 5, generator=gen)  # (T, B, N, F)
    time_major = _layer(5)(x)
    batch_major = _layer(5)(x.transpose(0, 1).contiguous())  # (B, T, N, F)
    torch.testing.assert_close(batch_major.transpose(0, 1), time_major, rtol=1e-6, atol=1e-6)
    per_frame = _layer(5)(x[0])  # a different batch: different statistics, so the pooling really spans T
    assert not torch.allclose(per_frame, time_major[0], atol=1e-3)


def test_it_shares_batchnorm1ds_state_dict() -> None:
    ours, theirs = TdBatchNorm(6), nn.BatchNorm1d(6)
    assert ours.state_dict().keys() == theirs.state_dict().keys()
    ours.load_state_dict(theirs.state_dict())
    plain = TdBatchNorm(6, affine=False)
    x = torch.randn(10, 6)
    torch.testing.assert_close(plain(x), _reference(x, torch.ones(6), torch.zeros(6)), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(("build", "x", "culprit"), [
    (lambda: TdBatchNorm(4), torch.zeros(3, 5), r"expects \(\.\.\., 4\) inputs, got \(3, 5\)"),
    (lambda: TdBatchNorm(4), torch.zeros(1, 1, 4), "at least 2 values per channel"),
    (lambda: TdBatchNorm(4, threshold=0.0), None, "threshold > 0"),
])
def test_bad_input_is_one_clear_error(build, x: torch.Tensor | None, culprit: str) -> None:
    with pytest.raises(ConfigError, match=culprit):
        build()(x)
