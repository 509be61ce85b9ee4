"""ConvLSTM backend "compiled" (numba kernels per step): equal to the fused and autograd backends within float32
rounding, forward and every gradient, on grids down to 1x3 and kernels 1, 3, 5; its gather and scatter kernels
against the fused backend's index; its float32 sigmoid and tanh against float64."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.nn.convlstm import ConvLSTM, ConvLSTMCell, ConvLSTMConfig, _tap_index
from tactile_zoo.nn.convlstm_compiled import CompiledRecurrence

pytest.importorskip("numba")
from tactile_zoo.nn._kernels import convlstm as kern  # noqa: E402  (after the skip: it imports numba)

# (batch, in channels, hidden, height, width, kernel)
SHAPES = [(3, 2, 4, 4, 5, 3), (2, 3, 5, 1, 3, 1), (2, 2, 3, 1, 3, 3), (2, 1, 4, 3, 4, 5), (4, 2, 16, 9, 13, 3)]


def _run(net: ConvLSTM, x: torch.Tensor) -> list[torch.Tensor]:
    """Sequence, last states and the gradients of the input and every parameter under a loss that reaches all."""
    xi = x.clone().requires_grad_()
    seq, states = net(xi)
    loss = (seq * torch.linspace(-1, 1, seq.numel(), dtype=x.dtype).view_as(seq)).sum()
    loss = loss + sum((h ** 2).sum() + c.sin().sum() for h, c in states)
    loss.backward()
    return [seq.detach(), *(v.detach() for s in states for v in s), xi.grad, *(p.grad for p in net.parameters())]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: "B{}_C{}_h{}_{}x{}_k{}".format(*s))
def test_compiled_equals_fused_and_autograd_forward_and_every_gradient(shape: tuple[int, ...]) -> None:
    b, c_in, hid, height, width, k = shape
    torch.manual_seed(sum(shape))
    nets = {backend: ConvLSTM(ConvLSTMConfig(c_in, hid, num_layers=2, kernel_size=k, backend=backend))
            for backend in ("compiled", "fused", "autograd")}
    with torch.no_grad():  # biases across the gates' range and a larger recurrent kernel: saturated gates too
        for layer in nets["fused"].layers:
            layer.input_conv.bias.copy_(torch.linspace(-2, 2, 4 * hid))
            layer.hidden_conv.weight.mul_(2.0)
    for net in nets.values():
        net.load_state_dict(nets["fused"].state_dict())
    x = 2 * torch.randn(b, 7, c_in, height, width)
    got = _run(nets["compiled"], x)
    for other in ("fused", "autograd"):
        for a, want in zip(got, _run(nets[other], x)):
            torch.testing.assert_close(a, want)
    with torch.no_grad():  # the inference path (no buffers kept) gives the same sequence
        torch.testing.assert_close(nets["compiled"](x)[0], got[0])


def test_compiled_time_loop_gradcheck_on_every_input() -> None:
    torch.manual_seed(4)
    hid, b, height, width = 2, 2, 3, 2
    cols = b * height * width
    xz = torch.randn(4, 4 * hid, cols, dtype=torch.float64, requires_grad=True)  # (T, 4h, B*H*W)
    w = (0.5 * torch.randn(4 * hid, hid, 3, 3, dtype=torch.float64)).requires_grad_()
    h0 = torch.randn(hid, cols, dtype=torch.float64, requires_grad=True)
    c0 = torch.randn(hid, cols, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda *a: CompiledRecurrence.apply(*a, (b, height, width)), (xz, w, h0, c0))


@pytest.mark.parametrize("grid", [(2, 4, 5, 3), (3, 1, 3, 3), (2, 1, 3, 1), (2, 3, 4, 5), (1, 2, 2, 5)])
def test_im2col_and_col2im_are_the_fused_gather_and_its_transpose(grid: tuple[int, int, int, int]) -> None:
    b, height, width, k = grid
    hid, n = 3, b * height * width
    torch.manual_seed(7)
    h = torch.randn(hid, n)
    idx = _tap_index(b, height, width, k)
    want = torch.cat([h, torch.zeros(hid, 1)], 1)[:, idx].reshape(hid * k * k, n)
    cols = torch.full((hid * k * k, n), float("nan"))  # every position must be written, the padding with 0
    for j in range(hid):
        kern.im2col(h[j].numpy(), cols.numpy(), j, b, height, width, k)
    assert torch.equal(cols, want)
    d_cols = torch.randn(hid * k * k, n)
    d_h = torch.zeros(hid, n + 1).index_add_(1, idx, d_cols.view(hid, -1))[:, :n]
    got = torch.zeros(hid, n)
    for j in range(hid):
        kern.col2im(d_cols.clone().numpy(), got[j].numpy(), j, b, height, width, k)
    torch.testing.assert_close(got, d_h, rtol=0, atol=1e-6)


def test_float32_sigmoid_and_tanh_within_two_ulp() -> None:
    x = torch.cat([torch.linspace(-100, 100, 20001), torch.logspace(-8, 0, 200), -torch.logspace(-8, 0, 200),
                   torch.tensor([0.0, 0.625, -0.625, 87.0, 88.0, 89.0, float("inf"), -float("inf")])])
    want_sig, want_tanh = torch.sigmoid(x.double()), torch.tanh(x.double())
    sig, tanh = x.clone(), x.clone()
    kern._sigmoid_row(sig.numpy())
    kern._tanh_row(tanh.numpy())
    # 2 ulp of the true value, and a floor at the smallest normal float (sigmoid far below 0 flushes towards 0)
    for got, want in ((sig, want_sig), (tanh, want_tanh)):
        err = (got.double() - want).abs()
        bound = 2 * torch.finfo(torch.float32).eps * want.abs() + torch.finfo(torch.float32).tiny
        assert bool((err <= bound).all()), float((err / bound).max())


def test_compiled_backend_through_the_model_and_the_default_stays_fused() -> None:
    from tactile_zoo.data.sensors import NEUTOUCH
    from tactile_zoo.data.spec import DatasetSpec

    spec = DatasetSpec("ev_objects", 4, ("a", "b", "c", "d"), 20, NEUTOUCH.num_nodes, 2, 0, NEUTOUCH)
    torch.manual_seed(3)
    fused = tz.create_model("convlstm", spec)
    assert all(layer.backend == "fused" for layer in fused.convlstm.layers)
    compiled = tz.create_model("convlstm", spec, backend="compiled")
    assert all(layer.backend == "compiled" for layer in compiled.convlstm.layers)
    compiled.load_state_dict(fused.state_dict())
    x, y = (torch.rand(4, 20, 39, 2) < 0.3).float(), torch.tensor([0, 1, 2, 3])
    outs = []
    for model in (fused, compiled):
        logits = model(x)
        torch.nn.functional.cross_entropy(logits, y).backward()
        outs.append([logits.detach(), *(p.grad for p in model.parameters())])
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b)


def test_other_dtypes_fall_back_to_the_fused_loop() -> None:
    torch.manual_seed(2)
    cells = [ConvLSTMCell(2, 3, backend=backend).to(torch.bfloat16) for backend in ("compiled", "fused")]
    cells[0].load_state_dict(cells[1].state_dict())
    x = torch.randn(2, 4, 2, 3, 3, dtype=torch.bfloat16)
    assert torch.equal(cells[0](x)[0], cells[1](x)[0])  # bfloat16: no kernel, the same torch loop


def test_the_default_fused_loop_reads_the_input_convolution_in_place(monkeypatch: pytest.MonkeyPatch) -> None:
    """Adding the compiled backend once made the default path copy ``xz`` to a contiguous tensor. That changed the
    layout of the gradient the input convolution's backward receives, and with it every committed ConvLSTM cell in
    the last bits (found by ``tools.check_cells --compare``). The fused loop must get a view of the convolution's
    output, not a copy."""
    import tactile_zoo.nn.convlstm as module

    seen: dict[str, int] = {}
    apply = module._FusedRecurrence.apply

    def spy(xz_cm: torch.Tensor, *rest: object) -> object:
        seen["loop"] = xz_cm.untyped_storage().data_ptr()
        return apply(xz_cm, *rest)

    monkeypatch.setattr(module._FusedRecurrence, "apply", spy)
    torch.manual_seed(0)
    cell = ConvLSTMCell(2, 3)
    cell.input_conv.register_forward_hook(
        lambda _m, _i, out: seen.__setitem__("conv", out.untyped_storage().data_ptr()))
    cell(torch.randn(2, 5, 2, 3, 4, requires_grad=True))[0].sum().backward()
    assert seen["loop"] == seen["conv"]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_fused_loop_gives_the_same_bits_with_numba_taps_as_with_the_index(monkeypatch: pytest.MonkeyPatch,
                                                                               dtype: torch.dtype) -> None:
    """The default loop gathers and scatters with the numba kernels where they run; the numbers must be the index
    path's bit for bit (the committed revision-1 cells depend on it), on the model's layout: ``xz`` a transposed
    view of a channels-last convolution output, the gradient arriving in the same layout."""
    import tactile_zoo.nn.convlstm as module

    torch.manual_seed(11)
    steps, hid, grid = 6, 4, (3, 4, 5)
    n = grid[0] * grid[1] * grid[2]
    base = torch.randn(steps, n, 4 * hid, dtype=dtype)  # (T, B*H*W, 4h): channels-last memory
    w = 0.4 * torch.randn(4 * hid, hid, 3, 3, dtype=dtype)
    h0, c0 = torch.randn(hid, n, dtype=dtype), torch.randn(hid, n, dtype=dtype)
    d_hs = torch.randn(steps, hid, n, dtype=dtype)

    def run() -> list[torch.Tensor]:
        leaves = [v.clone().requires_grad_() for v in (base, w, h0, c0)]
        hs, c = module._FusedRecurrence.apply(leaves[0].transpose(1, 2), *leaves[1:], grid)
        torch.autograd.backward([hs, c], [d_hs, torch.ones_like(c)])
        return [hs.detach(), c.detach(), *(v.grad for v in leaves)]  # views: the pool must not reuse them

    assert module._Taps(grid, 3, base, w).kern is not None
    with_kernels = run()
    again = run()  # a second call reuses the pooled buffers: the first call's outputs must be untouched
    monkeypatch.setattr(module, "_kernels_for", lambda *tensors: None)
    assert module._Taps(grid, 3, base, w).kern is None
    with_index = run()
    for a, b, c in zip(with_kernels, again, with_index):
        assert torch.equal(a, b) and torch.equal(a, c)


def test_the_compiled_loop_gives_the_same_bits_on_the_convolutions_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    """Revision 2 once copied ``xz`` to a contiguous channel-major tensor, and its gradient came back in that layout,
    two full-size transposes a step. It now reads the convolution's view and returns the gradient in the
    convolution's layout; every output and gradient of a cell must stay what the copying version computed."""
    import tactile_zoo.nn.convlstm_compiled as module

    torch.manual_seed(12)
    cell = ConvLSTMCell(2, 4, backend="compiled")
    x = torch.randn(3, 6, 2, 4, 5)

    def run() -> list[torch.Tensor]:
        xi = x.clone().requires_grad_()
        hs, (h, c) = cell(xi)
        (hs * torch.linspace(-1, 1, hs.numel()).view_as(hs)).sum().add(c.sin().sum()).backward()
        grads = [xi.grad, *(p.grad.clone() for p in cell.parameters())]
        cell.zero_grad()
        return [hs.detach(), c.detach(), *grads]

    seen: list[tuple[bool, tuple[int, ...]]] = []
    apply = module.CompiledRecurrence.apply

    def spy(xz: torch.Tensor, *rest: object) -> object:
        seen.append((xz.is_contiguous(), xz.stride()))
        return apply(xz, *rest)

    monkeypatch.setattr(module.CompiledRecurrence, "apply", spy)
    on_view = run()
    assert seen and not seen[-1][0]  # the loop got the convolution's strided view, not a copy
    monkeypatch.setattr(module.CompiledRecurrence, "apply", lambda xz, *rest: apply(xz.contiguous(), *rest))
    copied = run()
    for a, b in zip(on_view, copied):
        assert torch.equal(a, b)
