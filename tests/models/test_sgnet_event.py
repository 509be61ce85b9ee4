"""SGnet's event-driven computation (``compute="event"``, the default since revision 3; revision 2 computes
densely): the dense model's spikes, its gradients to rounding, and its own cell hash."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import tactile_zoo as tz
import tactile_zoo.nn.event_graph_lif as egl
import tactile_zoo.nn.event_linear as el
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.sgnet import SGNet


def _spec(sensor: str = "neutouch", channels: int = 2, globals_: int = 0, classes: int = 6) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec(f"toy_{sensor}", classes, tuple(f"c{i}" for i in range(classes)), 20, s.num_nodes, channels,
                       globals_, s)


def _pair(spec: DatasetSpec, seed: int) -> tuple[SGNet, SGNet]:
    """A dense and an event-driven model with the same (livelier: every layer spikes) weights."""
    torch.manual_seed(seed)
    dense = SGNet(spec, compute="dense")
    with torch.no_grad():
        for fc in dense.fcs:
            fc.weight.mul_(3.0)
    event = SGNet(spec, compute="event")
    event.load_state_dict(dense.state_dict())
    return dense, event


def _inputs(spec: DatasetSpec, batch: int, steps: int, seed: int) -> tuple[torch.Tensor, torch.Tensor | None]:
    gen = torch.Generator().manual_seed(seed)
    x = (torch.rand(batch, steps, spec.num_nodes, spec.num_channels, generator=gen) < 0.13).float()
    g = torch.randn(batch, steps, spec.num_globals, generator=gen) if spec.num_globals else None
    return x, g


def _step(model: SGNet, x: torch.Tensor, g: torch.Tensor | None, y: torch.Tensor):
    model.zero_grad(set_to_none=True)
    spikes = model.forward_features(x, g)
    out = model.forward_head(spikes)
    F.mse_loss(out, F.one_hot(y, model.spec.num_classes).float()).backward()
    return spikes.detach(), out.detach(), {n: p.grad for n, p in model.named_parameters()}


@pytest.mark.parametrize("sensor,channels,globals_", [("neutouch", 2, 0), ("uskin_allegro", 3, 4)])
def test_same_spikes_and_gradients_as_the_dense_model(sensor: str, channels: int, globals_: int) -> None:
    """Fixed seeds, float32, a few training steps: identical spikes and rates at every step, every weight gradient
    within 1e-5 of the dense one relative to its largest entry, and the two models stay together under SGD (Adam
    would not do as a check: it divides gradient entries near zero, whose rounding differs, by their own size)."""
    spec = _spec(sensor, channels, globals_)
    dense, event = _pair(spec, seed=0)
    opts = [torch.optim.SGD(m.parameters(), lr=0.5) for m in (dense, event)]
    y = torch.tensor([0, 3, 5])
    for step in range(3):
        x, g = _inputs(spec, 3, 25, seed=10 + step)
        spikes_d, out_d, grads_d = _step(dense, x, g, y)
        spikes_e, out_e, grads_e = _step(event, x, g, y)
        assert torch.equal(spikes_e, spikes_d) and torch.equal(out_e, out_d), step
        assert spikes_d.sum() > 0 and out_d.sum() > 0
        for name, ref in grads_d.items():
            assert ref.abs().max() > 0, name
            assert float((grads_e[name] - ref).abs().max() / ref.abs().max()) <= 1e-5, (step, name)
        for opt in opts:
            opt.step()


def test_streaming_equals_forward() -> None:
    spec = _spec("uskin_allegro", 3, 4)
    _, model = _pair(spec, seed=1)
    x, g = _inputs(spec, 2, 10, seed=2)
    state = model.init_state(2)
    with torch.no_grad():
        for t in range(10):
            scores, state = model.step(x[:, t], g[:, t], state)
            torch.testing.assert_close(scores, model(x[:, :t + 1], g[:, :t + 1]), rtol=0, atol=0)
    assert scores.sum() > 0


def test_event_products_run_only_where_promised(monkeypatch: pytest.MonkeyPatch) -> None:
    """compute="event" on CPU: the graph convolution fused with the first LIF (its spike list handed on), then one
    event product (the first linear layer); with the layers apart (a hook on the first LIF), two event products; the
    dense model: none; under a TorchScript trace and off CPU (meta here) the event model runs the dense products."""
    calls, fused, scans = [], [], []
    apply, forward, scan = el._EventLinear.apply, egl._forward, el.events_of
    monkeypatch.setattr(el._EventLinear, "apply", lambda *a: calls.append(a[1].shape) or apply(*a))
    monkeypatch.setattr(el, "events_of", lambda x: scans.append(x.shape) or scan(x))
    monkeypatch.setattr(egl, "_forward", lambda *a, **k: fused.append(1) or forward(*a, **k))
    spec = _spec()
    dense, event = _pair(spec, seed=3)
    x, _ = _inputs(spec, 2, 6, seed=4)
    n = spec.num_nodes
    with torch.no_grad():
        dense(x)
        assert calls == [] and fused == []
        event(x)
        assert fused == [1] and calls == [(n * 64, 128)] and scans == []  # the fused loop's spike list: no scan
        hook = event.lifs[0].register_forward_hook(lambda *_: None)
        event(x)
        hook.remove()
    assert fused == [1] and calls[1:] == [(n * 2, n * 64), (n * 64, 128)] and scans == [(12, n * 2), (12, n * 64)]
    # a TorchScript trace (what the exporter writes) records the dense products
    traced = torch.jit.trace(event, (x,), check_trace=False)
    assert len(calls) == 3 and fused == [1] and torch.equal(traced(x), dense(x))
    meta = event.to("meta")
    assert meta(x.to("meta")).shape == (2, spec.num_classes) and len(calls) == 3 and fused == [1]


def test_default_is_event_and_the_option_is_checked() -> None:
    spec = _spec()
    assert SGNet(spec).compute == "event"
    with pytest.raises(ConfigError, match="compute"):
        SGNet(spec, compute="sparse")
    with pytest.raises(ConfigError, match="with it, pass compute='dense'"):
        SGNet(spec, graph_backend="pyg")  # the event product needs the dense hop matrices
    assert SGNet(spec, compute="dense", graph_backend="pyg").compute == "dense"


def test_its_cells_hash_apart() -> None:
    """The default is revision 3's event path; revision 2's dense cells, and a cell that names ``compute`` as an
    hparam, each have a hash of their own (the default cell's configuration names no ``compute`` at all)."""
    from tactile_zoo.engine.config import config_hash, resolve_cell

    default = resolve_cell("sgnet", "sim_evtouch")
    dense = resolve_cell("sgnet", "sim_evtouch", model_revision=2)
    event = resolve_cell("sgnet", "sim_evtouch", hparams={"compute": "event"})
    assert "compute" not in default.hparams and event.hparams["compute"] == "event"
    assert (default.model_revision, dense.model_revision) == (3, 2)
    assert len({config_hash(c) for c in (default, dense, event)}) == 3
    assert config_hash(resolve_cell("sgnet", "sim_evtouch", hparams={"compute": "dense"})) != config_hash(dense)


def test_trains_on_real_ev_objects_like_the_dense_model(shared_data) -> None:
    """Real Ev-Objects events (12.8 % dense): the same rates as the dense model and weight gradients within 1e-5."""
    data = tz.load_dataset("ev_objects", root=shared_data, split="train")
    x, y = data.x[:2].float(), data.y[:2].long()
    torch.manual_seed(0)
    dense = tz.create_model("sgnet", data.spec, revision=2)
    event = tz.create_model("sgnet", data.spec)
    event.load_state_dict(dense.state_dict())
    spikes_d, out_d, grads_d = _step(dense, x, None, y)
    spikes_e, out_e, grads_e = _step(event, x, None, y)
    assert torch.equal(spikes_e, spikes_d) and torch.equal(out_e, out_d) and spikes_d.sum() > 0
    for name, ref in grads_d.items():
        if ref.abs().max() > 0:
            assert float((grads_e[name] - ref).abs().max() / ref.abs().max()) <= 1e-5, name
