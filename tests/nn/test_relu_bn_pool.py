"""relu_bn_pool: D-CNN's ReLU -> training-mode batch norm -> 2x2 "same" max pool fused in compiled loops, held to a
float64 copy of the three layers (outputs, input, weight and bias gradients, statistics), on odd map sizes (the
ceil-mode windows at the edges), negative batch-norm weights (the window's smallest value then wins) and maps with
many ReLU zeros (ties); and the D-CNN block and batch-norm module that use it."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tactile_zoo.nn import backend
from tactile_zoo.nn.batch_norm import BatchNorm2d
from tactile_zoo.nn.relu_bn_pool import fusable, relu_bn_pool

pytestmark = pytest.mark.skipif(backend.bn_pool_kernels() is None, reason="the fused kernels need numba")

EPS = 1e-3


def _map(shape: tuple[int, ...], seed: int, shift: float = 0.0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(shape, generator=gen) + shift).to(memory_format=torch.channels_last)


def _reference(x: torch.Tensor, w: torch.Tensor, b: torch.Tensor, grad: torch.Tensor):
    xr, wr, br = (t.detach().double().requires_grad_() for t in (x, w, b))
    out = F.max_pool2d(F.batch_norm(F.relu(xr), None, None, wr, br, training=True, eps=EPS), 2, 2, ceil_mode=True)
    out.backward(grad.double())
    r = F.relu(xr.detach())
    return out.detach(), xr.grad, wr.grad, br.grad, r.mean((0, 2, 3)), r.var((0, 2, 3), unbiased=False)


def _rel(a: torch.Tensor, ref: torch.Tensor) -> float:
    return float((a.detach().double() - ref).abs().max() / ref.abs().max())


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("shape,shift", [((4, 8, 9, 7), 0.0), ((3, 16, 10, 13), -0.8), ((2, 5, 1, 6), 0.5),
                                         ((1, 3, 7, 1), 0.0)])
def test_float64_accurate(threads: int, shape: tuple[int, ...], shift: float) -> None:
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        x = _map(shape, seed=0, shift=shift)  # shift -0.8: most of the map is ReLU zeros, so windows tie
        chans = shape[1]
        w = torch.randn(chans, generator=torch.Generator().manual_seed(1))
        w[0] = -w[0].abs()  # a negative weight: the smallest value of each window is the largest output
        b = torch.randn(chans, generator=torch.Generator().manual_seed(2))
        xf, wf, bf = x.clone().requires_grad_(), w.clone().requires_grad_(), b.clone().requires_grad_()
        assert fusable(xf, wf)
        out, mean, var = relu_bn_pool(xf, wf, bf, EPS)
        grad = torch.randn(out.shape, generator=torch.Generator().manual_seed(3))
        out.backward(grad)
    finally:
        torch.set_num_threads(before)
    ref_out, ref_x, ref_w, ref_b, ref_mean, ref_var = _reference(x, w, b, grad)
    assert out.shape == ref_out.shape and out.is_contiguous(memory_format=torch.channels_last)
    assert xf.grad.is_contiguous(memory_format=torch.channels_last)
    for name, got, ref in (("out", out, ref_out), ("dx", xf.grad, ref_x), ("dw", wf.grad, ref_w),
                           ("db", bf.grad, ref_b), ("mean", mean, ref_mean), ("var", var, ref_var)):
        assert _rel(got, ref) < 1e-6, name
    assert mean.dtype == var.dtype == torch.float64


def test_threads_do_not_change_the_numbers() -> None:
    x, w, b = _map((6, 12, 11, 9), seed=4), torch.randn(12), torch.randn(12)
    results = []
    before = torch.get_num_threads()
    for threads in (1, 2):
        torch.set_num_threads(threads)
        xf = x.clone().requires_grad_()
        out = relu_bn_pool(xf, w, b, EPS)[0]
        out.backward(torch.ones_like(out))
        results.append((out.detach(), xf.grad))
    torch.set_num_threads(before)
    assert all(torch.equal(a, c) for a, c in zip(*results))


def test_fusable_only_where_the_kernels_apply() -> None:
    x, w = _map((2, 4, 6, 6), seed=5), torch.ones(4)
    assert fusable(x, w)
    assert not fusable(x.contiguous(), w)  # NCHW: the kernels read channels-last memory
    assert not fusable(x.double(), w)
    assert not fusable(x, None)  # no affine weights


def test_the_batch_norm_module_updates_its_running_statistics_as_forward_does() -> None:
    x = _map((4, 6, 8, 10), seed=6)
    fused, apart = BatchNorm2d(6, eps=EPS, momentum=0.3), BatchNorm2d(6, eps=EPS, momentum=0.3, stats="float64")
    for _ in range(2):
        out = fused.relu_pool(x)
        ref = F.max_pool2d(apart(F.relu(x)), 2, 2, ceil_mode=True)
        assert out is not None and _rel(out, ref.double()) < 1e-5
    assert int(fused.num_batches_tracked) == 2
    for name in ("running_mean", "running_var"):
        assert _rel(getattr(fused, name), getattr(apart, name).double()) < 1e-6, name
    assert fused.eval().relu_pool(x) is None  # evaluation reads the running statistics: the layers apart


def test_a_dcnn_block_runs_the_layers_apart_for_a_hook_and_in_evaluation(monkeypatch: pytest.MonkeyPatch) -> None:
    import tactile_zoo.nn.batch_norm as bn_module
    from tactile_zoo.models.dcnn import _ConvBlock

    calls = []
    fused_op = bn_module.relu_bn_pool
    monkeypatch.setattr(bn_module, "relu_bn_pool", lambda *a: calls.append(1) or fused_op(*a))
    block = _ConvBlock(1, 4, (2, 3), 0.1, fused=True).to(memory_format=torch.channels_last)
    x = _map((3, 1, 12, 9), seed=7)
    out = block(x)
    assert calls == [1] and out.shape == (3, 4, 6, 5)
    seen = []
    hook = block[2].register_forward_hook(lambda _m, _i, o: seen.append(o))
    block(x)
    hook.remove()
    assert calls == [1] and len(seen) == 1  # the ReLU module ran: the hook saw it
    with torch.no_grad():
        block.eval()(x)
    assert calls == [1]
