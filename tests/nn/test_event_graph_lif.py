"""event_graph_lif: SGnet's graph convolution -> LIF -> spike list fused in one compiled loop gives, bit for bit, the
spikes, the spike list and the gradients of the two layers apart (event_graph_conv, then MultiStepLIF, then a scan of
the spikes), and is the two layers apart wherever it does not apply."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo.nn.event_graph_lif as egl
from tactile_zoo.data.sensors import NEUTOUCH
from tactile_zoo.nn import backend
from tactile_zoo.nn.event_graph_conv import event_graph_conv
from tactile_zoo.nn.event_linear import events_of
from tactile_zoo.nn.graph import FrameGraphConv
from tactile_zoo.nn.lif import MultiStepLIF

pytestmark = pytest.mark.skipif(backend.graph_lif_kernels() is None or backend.lif_kernels() is None,
                                reason="the fused loop needs numba and the compiled LIF kernels (x86-64, AVX2/AVX512)")

N = NEUTOUCH.num_nodes


def _layers(f_out: int = 64, seed: int = 0, **lif_kw) -> tuple[FrameGraphConv, MultiStepLIF]:
    torch.manual_seed(seed)
    conv = FrameGraphConv(2, f_out, NEUTOUCH.edge_index(), N)
    with torch.no_grad():  # currents around the threshold, so that spikes and surrogate windows are both common
        for lin in conv.conv.lins:
            lin.weight.mul_(3.0)
    return conv, MultiStepLIF(beta=0.2, threshold=0.5, reset="zero", **lif_kw)


def _events(shape: tuple[int, ...], seed: int, density: float = 0.13) -> torch.Tensor:
    return (torch.rand(*shape, generator=torch.Generator().manual_seed(seed)) < density).float()


def _apart(conv: FrameGraphConv, lif: MultiStepLIF, x: torch.Tensor) -> torch.Tensor:
    steps, batch = x.shape[:2]
    return lif(event_graph_conv(conv, x).reshape(steps, batch, -1))


def _train(fn, conv: FrameGraphConv, x: torch.Tensor, grad: torch.Tensor):
    conv.zero_grad(set_to_none=True)
    spikes = fn(x)
    spikes.backward(grad)
    return spikes.detach().clone(), {n: p.grad.clone() for n, p in conv.named_parameters()}


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("steps,batch,f_out,lif_kw", [
    (250, 8, 64, {}),  # SGnet's Ev-Objects shapes: the backward's 26-step blocks end inside the sequence
    (250, 8, 64, {"surrogate": "atan"}),  # there too: a surrogate whose values round (rect's are 0 and 1)
    (37, 3, 16, {"surrogate": "atan"}),  # a sequence that is not a whole number of checkpoint windows
    (40, 1, 64, {"detach_reset": True}),  # one batch row: the serial build
])
def test_bit_for_bit_the_layers_apart(threads: int, steps: int, batch: int, f_out: int, lif_kw: dict) -> None:
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        conv, lif = _layers(f_out, **lif_kw)
        x = _events((steps, batch, N, 2), seed=1)
        grad = torch.randn(steps, batch, N * f_out, generator=torch.Generator().manual_seed(2))
        spikes, ref_grads = _train(lambda v: _apart(conv, lif, v), conv, x, grad)
        got, grads = _train(lambda v: egl.event_graph_lif(conv, lif, v)[0], conv, x, grad)
        fused_events = egl.event_graph_lif(conv, lif, x)[1]
    finally:
        torch.set_num_threads(before)
    assert 0.02 < float(spikes.mean()) < 0.5  # spiking, not saturated: the comparison means something
    assert torch.equal(got, spikes)
    for name, ref in ref_grads.items():
        assert ref.abs().max() > 0 and torch.equal(grads[name], ref), name
    scanned = events_of(spikes.reshape(-1, N * f_out))
    assert fused_events is not None
    for field in ("cols", "row_offsets", "rows_by_col", "col_offsets"):
        assert torch.equal(getattr(fused_events, field), getattr(scanned, field)), field
    assert fused_events.values is None


def test_without_gradient_the_same_spikes() -> None:
    conv, lif = _layers()
    x = _events((30, 2, N, 2), seed=3)
    with torch.no_grad():
        spikes, events = egl.event_graph_lif(conv, lif, x)
        assert events is not None and torch.equal(spikes, _apart(conv, lif, x))


@pytest.mark.parametrize("case", ["counts", "subtract", "snntorch", "float64", "kernel_env", "hook", "subclass"])
def test_the_layers_apart_where_it_does_not_apply(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    conv, lif = _layers(8)
    x = _events((12, 2, N, 2), seed=4)
    if case == "counts":  # not 0/1: the event product multiplies, which the fused loop does not
        x = x * 2
    elif case == "subtract":
        lif = MultiStepLIF(beta=0.2, threshold=0.5, reset="subtract")
    elif case == "snntorch":
        lif = MultiStepLIF(beta=0.2, threshold=0.5, reset="zero", backend="snntorch")
    elif case == "float64":
        conv, x = conv.double(), x.double()
    elif case == "kernel_env":
        monkeypatch.setenv(backend.LIF_KERNEL_ENV, "torch")
    elif case == "hook":  # a hook recording the LIF's spikes sees them: the LIF runs as a module
        seen = []
        lif.register_forward_hook(lambda _m, _i, out: seen.append(out))
    else:
        lif.__class__ = type("OwnLIF", (MultiStepLIF,), {})  # a subclass may have its own forward
    launched = []
    monkeypatch.setattr(egl, "_forward", lambda *a, **k: launched.append(1))
    spikes, events = egl.event_graph_lif(conv, lif, x)
    assert events is None and not launched
    assert torch.equal(spikes, _apart(conv, lif, x))
    if case == "hook":
        assert len(seen) == 2 and torch.equal(seen[0], spikes)


def test_sgnet_trains_through_it_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo import create_model
    from tactile_zoo.data.datasets.ev import EV_OBJECTS_CLASSES
    from tactile_zoo.data.spec import DatasetSpec

    spec = DatasetSpec("ev_objects", len(EV_OBJECTS_CLASSES), EV_OBJECTS_CLASSES, 60, N, 2, 0, NEUTOUCH)
    torch.manual_seed(0)
    model = create_model("sgnet", spec)
    x = _events((4, 60, N, 2), seed=5, density=0.2)
    calls = []
    fused = egl._EventGraphLIF.apply
    monkeypatch.setattr(egl._EventGraphLIF, "apply", lambda *a: calls.append(1) or fused(*a))

    def step() -> tuple[torch.Tensor, dict]:
        model.zero_grad(set_to_none=True)
        out = model(x)
        (out * torch.arange(out.shape[1])).sum().backward()
        return out.detach(), {n: p.grad.clone() for n, p in model.named_parameters()}

    got, grads = step()
    assert calls == [1]
    monkeypatch.setattr(egl, "_fusable", lambda *a: None)
    ref, ref_grads = step()
    assert calls == [1] and torch.equal(got, ref)
    assert all(torch.equal(grads[n], g) for n, g in ref_grads.items())
