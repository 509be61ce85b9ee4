"""event_linear: the event-driven ``x W^T + b`` equals ``F.linear`` to rounding, builds the right event lists, and
is ``F.linear`` itself where the event path does not apply."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import tactile_zoo.nn.event_linear as el
from tactile_zoo.nn import backend
from tactile_zoo.nn.event_linear import event_linear, events_of


def _spikes(shape: tuple[int, ...], rate: float, seed: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.rand(*shape, generator=gen) < rate).to(dtype)


def _grads(fn, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None, grad: torch.Tensor):
    x, weight = x.clone().requires_grad_(), weight.clone().requires_grad_()
    bias = None if bias is None else bias.clone().requires_grad_()
    out = fn(x, weight, bias)
    out.backward(grad)
    return out.detach(), x.grad, weight.grad, None if bias is None else bias.grad


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
@pytest.mark.parametrize("values", [False, True])
def test_equals_the_dense_product_and_its_gradients(dtype: torch.dtype, tol: float, values: bool) -> None:
    """Spikes (all values 1) and weighted events, with leading dimensions: outputs and every gradient equal
    F.linear's within ``tol`` relative to their largest entry."""
    x = _spikes((7, 5, 300), 0.06, seed=0, dtype=dtype)
    if values:  # non-binary events: the sums weight each selected column by its value
        x = x * torch.randn(x.shape, generator=torch.Generator().manual_seed(1), dtype=dtype)
    gen = torch.Generator().manual_seed(2)
    weight = torch.randn(40, 300, generator=gen, dtype=dtype)
    bias = torch.randn(40, generator=gen, dtype=dtype)
    grad = torch.randn(7, 5, 40, generator=gen, dtype=dtype)
    ref = _grads(F.linear, x, weight, bias, grad)
    got = _grads(event_linear, x, weight, bias, grad)
    assert got[0].shape == (7, 5, 40)
    for name, a, b in zip(("out", "x", "weight", "bias"), got, ref):
        scale = b.abs().max()
        assert scale > 0
        assert float((a - b).abs().max() / scale) <= tol, name
    assert not torch.equal(got[2], torch.zeros_like(got[2]))


def test_without_bias_and_with_empty_rows() -> None:
    x = _spikes((20, 50), 0.05, seed=3)
    x[:5] = 0  # leading, trailing and inner rows with no event at all
    x[-3:] = 0
    x[9] = 0
    weight = torch.randn(8, 50, generator=torch.Generator().manual_seed(4))
    ref = _grads(F.linear, x, weight, None, torch.ones(20, 8))
    got = _grads(event_linear, x, weight, None, torch.ones(20, 8))
    for a, b in zip(got[:3], ref[:3]):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
    assert torch.equal(got[0][:5], torch.zeros(5, 8)) and torch.equal(got[0][9], torch.zeros(8))


def test_a_second_order_gradient_raises_instead_of_being_wrong() -> None:
    x = _spikes((6, 20), 0.3, seed=13).requires_grad_()
    weight = torch.randn(4, 20, generator=torch.Generator().manual_seed(14), requires_grad=True)
    (gx,) = torch.autograd.grad(event_linear(x, weight).pow(2).sum(), x, create_graph=True)
    with pytest.raises(RuntimeError, match="once_differentiable|twice"):
        gx.sum().backward()


def test_no_events_at_all() -> None:
    x = torch.zeros(5, 30)
    weight = torch.randn(4, 30, generator=torch.Generator().manual_seed(11))
    bias = torch.randn(4, generator=torch.Generator().manual_seed(12))
    ref = _grads(F.linear, x, weight, bias, torch.ones(5, 4))
    got = _grads(event_linear, x, weight, bias, torch.ones(5, 4))
    for a, b in zip(got, ref):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def _dense(events: el.EventList, shape: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """The matrix the row-major list describes, and the one the column-major list describes."""
    rows_n, cols_n = shape
    counts = torch.diff(torch.cat([events.row_offsets, torch.tensor([len(events.cols)])]))
    rows = torch.repeat_interleave(torch.arange(rows_n), counts)
    vals = torch.ones(len(events.cols)) if events.values is None else events.values
    by_row = torch.zeros(shape).index_put_((rows, events.cols), vals)
    ccounts = torch.diff(torch.cat([events.col_offsets, torch.tensor([len(events.rows_by_col)])]))
    cols = torch.repeat_interleave(torch.arange(cols_n), ccounts)
    cvals = torch.ones(len(cols)) if events.values_by_col is None else events.values_by_col
    by_col = torch.zeros(shape).index_put_((events.rows_by_col, cols), cvals)
    return by_row, by_col


@pytest.mark.parametrize("weighted", [False, True])
def test_event_lists_describe_the_matrix_compiled_and_torch_alike(monkeypatch: pytest.MonkeyPatch,
                                                                  weighted: bool) -> None:
    x = _spikes((30, 40), 0.1, seed=5)
    if weighted:
        x = x * 0.5
    compiled = events_of(x)
    if backend.event_kernels() is None:
        pytest.skip("numba is not installed: only the torch path exists")
    monkeypatch.setattr(backend, "event_kernels", lambda: None)
    fallback = events_of(x)
    for a, b in zip(compiled, fallback):
        assert (a is None and b is None) or torch.equal(a, b)
    assert (compiled.values is None) is (not weighted)
    for listed in _dense(compiled, (30, 40)):
        assert torch.equal(listed, x)
    assert torch.all(torch.diff(compiled.rows_by_col[compiled.col_offsets[3]:compiled.col_offsets[4]]) > 0)
    # a producer's row-major list (a LIF kernel's spike indices) completes to the same lists, either way
    for done in (el.events_from_rows(compiled.cols, compiled.row_offsets, 40, compiled.values), fallback):
        for a, b in zip(done, compiled):
            assert (a is None and b is None) or torch.equal(a, b)
    monkeypatch.undo()
    for a, b in zip(el.events_from_rows(compiled.cols, compiled.row_offsets, 40, compiled.values), compiled):
        assert (a is None and b is None) or torch.equal(a, b)


def test_a_given_event_list_is_the_one_used() -> None:
    """A producer's event list (e.g. a LIF kernel's spike indices) replaces the scan of ``x``."""
    x, other = _spikes((6, 20), 0.2, seed=6), _spikes((6, 20), 0.2, seed=7)
    weight = torch.randn(4, 20, generator=torch.Generator().manual_seed(8))
    torch.testing.assert_close(event_linear(x, weight, events=events_of(other)), F.linear(other, weight))


def test_the_dense_path_where_events_do_not_apply(monkeypatch: pytest.MonkeyPatch) -> None:
    """Off CPU (meta here, CUDA below) and for tracer tensors the call is F.linear; on plain CPU tensors it is not."""
    calls = []
    apply = el._EventLinear.apply
    monkeypatch.setattr(el._EventLinear, "apply", lambda *a: calls.append(1) or apply(*a))
    weight = torch.nn.Parameter(torch.randn(4, 20))
    x = _spikes((6, 20), 0.2, seed=9)
    event_linear(x, weight)
    assert calls == [1]  # a Parameter weight takes the event path
    assert event_linear(x.to("meta"), weight.to("meta")).shape == (6, 4) and calls == [1]
    assert not el.uses_events(x.to(torch.float16), weight.to(torch.float16))
    from torch._subclasses.fake_tensor import FakeTensorMode

    mode = FakeTensorMode()
    assert not el.uses_events(mode.from_tensor(x), mode.from_tensor(weight.detach()))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_runs_the_dense_product() -> None:
    x = _spikes((6, 20), 0.2, seed=10).cuda()
    weight = torch.randn(4, 20, device="cuda")
    assert not el.uses_events(x, weight)
    assert torch.equal(event_linear(x, weight), F.linear(x, weight))
