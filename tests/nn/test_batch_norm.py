"""Batch norm with accurate training statistics (tactile_zoo.nn.batch_norm) against float64 ``nn.BatchNorm``."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.batch_norm import BatchNorm1d, BatchNorm2d


def _pair(cls: type, ref_cls: type, momentum: float | None) -> tuple[nn.Module, nn.Module]:
    torch.manual_seed(0)
    ours = cls(6, eps=1e-3, momentum=momentum, stats="two_pass")
    ref = ref_cls(6, eps=1e-3, momentum=momentum).double()
    with torch.no_grad():
        for p in (ours.weight, ours.bias):
            p.uniform_(0.5, 2.0)
        ref.load_state_dict(ours.state_dict())
    return ours, ref.double()


@pytest.mark.parametrize("momentum", [0.1, None])
@pytest.mark.parametrize("layout", ["nchw", "channels_last", "rows", "sequence"])
@pytest.mark.parametrize("stats", ["two_pass", "float64"])
def test_training_matches_float64_batch_norm(stats: str, layout: str, momentum: float | None) -> None:
    one_d = layout in ("rows", "sequence")
    cls, ref_cls = (BatchNorm1d, nn.BatchNorm1d) if one_d else (BatchNorm2d, nn.BatchNorm2d)
    ours, ref = _pair(cls, ref_cls, momentum)
    ours.stats = type(ours.stats)(stats)
    for step in range(2):  # the running statistics over two batches (the cumulative average needs two)
        shape = {"rows": (40, 6), "sequence": (5, 6, 8)}.get(layout, (3, 6, 9, 7))
        x = (torch.randn(shape) * torch.linspace(0.01, 3, 6).view(1, 6, *([1] * (len(shape) - 2))) + 5 * step)
        if layout == "channels_last":
            x = x.contiguous(memory_format=torch.channels_last)
        x64 = x.double().requires_grad_()
        x = x.requires_grad_()
        dy = torch.randn(shape)
        y, y64 = ours(x), ref(x64)
        assert y.shape == x.shape and y.stride() == x.stride()  # the layout goes through
        y.backward(dy)
        y64.backward(dy.double())
        assert torch.allclose(y.double(), y64, atol=1e-5)
        assert torch.allclose(x.grad.double(), x64.grad, atol=1e-5 * x64.grad.abs().max().item())
        for a, b in ((ours.weight.grad, ref.weight.grad), (ours.bias.grad, ref.bias.grad)):
            assert torch.allclose(a.double(), b, rtol=0, atol=1e-5 * b.abs().max().item())
        assert torch.allclose(ours.running_mean.double(), ref.running_mean, rtol=1e-5, atol=1e-7)
        assert torch.allclose(ours.running_var.double(), ref.running_var, rtol=1e-5, atol=1e-7)
        assert int(ours.num_batches_tracked) == int(ref.num_batches_tracked) == step + 1
        ours.zero_grad()
        ref.zero_grad()


def test_native_and_evaluation_are_torch_bit_for_bit() -> None:
    torch.manual_seed(0)
    x = torch.randn(4, 6, 5, 5).contiguous(memory_format=torch.channels_last)
    native, torch_bn = BatchNorm2d(6), nn.BatchNorm2d(6)
    assert torch.equal(native(x), torch_bn(x)) and torch.equal(native.running_var, torch_bn.running_var)
    accurate = BatchNorm2d(6, stats="float64")
    accurate.load_state_dict(torch_bn.state_dict())
    assert torch.equal(accurate.eval()(x), torch_bn.eval()(x))


def test_an_unknown_choice_names_the_layer_and_the_keyword() -> None:
    with pytest.raises(ConfigError, match=r"BatchNorm2d: stats must be one of 'native', 'two_pass', 'float64'"):
        BatchNorm2d(3, stats="double")
