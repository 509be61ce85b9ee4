"""SGNet (TactileSGNet): the reference configuration, the per-step reference computation, streaming, backends."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.sgnet import SGNet
from tactile_zoo.registry import get_model_entry


def _spec(sensor: str = "neutouch", channels: int = 2, globals_: int = 0, classes: int = 6) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec(f"toy_{sensor}", classes, tuple(f"c{i}" for i in range(classes)), 20, s.num_nodes, channels,
                       globals_, s)


def _events(spec: DatasetSpec, batch: int, steps: int, seed: int = 0, dtype=torch.float64):
    gen = torch.Generator().manual_seed(seed)
    x = (torch.rand(batch, steps, spec.num_nodes, spec.num_channels, generator=gen) < 0.3).to(dtype)
    g = torch.randn(batch, steps, spec.num_globals, generator=gen, dtype=dtype)
    return x, (g if spec.num_globals else None)


def _lively(model: SGNet) -> SGNet:
    """Larger weights, so every layer spikes within a few steps and the comparisons cover spikes everywhere."""
    with torch.no_grad():
        for fc in model.fcs:
            fc.weight.mul_(3.0)
    return model


def test_reference_configuration_and_metadata() -> None:
    spec = _spec(globals_=3)
    model = SGNet(spec)
    assert model.gc.kind == "tag" and model.gc.conv.K == 3 and model.gc.out_channels == 64
    assert model.gc.backend == "dense"
    assert [(fc.in_features, fc.out_features) for fc in model.fcs] == [(39 * 64 + 3, 128), (128, 256), (256, 6)]
    for lif in model.lifs:
        assert (lif.beta, lif.threshold, lif.reset, lif.detach_reset) == (0.2, 0.5, "zero", False)
        assert (lif.surrogate.kind, lif.surrogate.param, lif.backend) == ("rect", 1.0, "fused")
    assert torch.equal(model.gc.edge_index, tz.get_sensor("neutouch").edge_index())  # the reference tree
    meta = get_model_entry("sgnet").meta
    assert meta["year"] == 2020 and set(meta["tags"]) - {"table1"} == {"spiking", "graph"}
    assert set(meta["inputs"]) == {"graph", "globals"} and meta["causal"] and meta["streaming"]
    recipe = meta["recipe"]
    assert (recipe["loss"], recipe["optimizer"], recipe["amsgrad"], recipe["lr"]) == ("mse_rate", "adam", True, 1e-3)
    assert recipe["schedule"] == {"type": "multistep", "milestones": [41, 81], "gamma": 0.1}  # x0.1 after epochs 41, 81
    assert recipe["max_epochs"] == 100 and recipe["patience"] is None and recipe["batch_size"] == 8


def _per_step_reference(model: SGNet, x: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
    """The public reference's structure: every layer called once per time step, one PyG call per sample and frame,
    the neuron written out as mem = 0.2 * mem * (1 - spike) + I, spike = mem > 0.5."""
    batch, steps = x.shape[:2]
    edge_index = model.gc.edge_index
    widths = [model.fcs[0].in_features - model.spec.num_globals] + [fc.out_features for fc in model.fcs]
    mems = [x.new_zeros(batch, w) for w in widths]
    spikes = [x.new_zeros(batch, w) for w in widths]
    count = x.new_zeros(batch, widths[-1])
    for t, x_t in enumerate(x.unbind(1)):
        current = torch.stack([model.gc.conv(frame, edge_index) for frame in x_t.unbind(0)]).reshape(batch, -1)
        for layer in range(len(widths)):
            if layer > 0:
                inp = spikes[layer - 1]
                if layer == 1 and g is not None:
                    inp = torch.cat([inp, g[:, t]], dim=-1)
                current = model.fcs[layer - 1](inp)
            mems[layer] = mems[layer] * 0.2 * (1.0 - spikes[layer]) + current
            spikes[layer] = (mems[layer] > 0.5).to(x.dtype)
        count = count + spikes[-1]
    return count / steps


@pytest.mark.parametrize("sensor,channels,globals_", [("neutouch", 2, 0), ("uskin_allegro", 3, 4)])
def test_forward_equals_the_per_step_reference(sensor: str, channels: int, globals_: int) -> None:
    spec = _spec(sensor, channels, globals_)
    torch.manual_seed(0)
    model = _lively(SGNet(spec)).double()
    x, g = _events(spec, 3, 15)
    with torch.no_grad():
        out = model(x, g)
        ref = _per_step_reference(model, x, g)
    assert out.shape == (3, spec.num_classes)
    assert 0 < out.sum() and torch.all((out * 15).round() == out * 15)  # rates: spike counts / T
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-12)


def test_streaming_equals_forward_at_every_step() -> None:
    spec = _spec("uskin_allegro", 3, 4)
    torch.manual_seed(1)
    model = _lively(SGNet(spec)).double()
    x, g = _events(spec, 2, 12, seed=2)
    state = model.init_state(2)
    with torch.no_grad():
        for t in range(12):
            scores, state = model.step(x[:, t], g[:, t], state)
            torch.testing.assert_close(scores, model(x[:, :t + 1], g[:, :t + 1]), rtol=0, atol=1e-12)
    assert state.steps == 12 and scores.sum() > 0


def test_backends_agree_on_outputs_and_gradients() -> None:
    spec = _spec()
    x, _ = _events(spec, 2, 10, seed=3)
    results = []
    for lif_backend, graph_backend in [("fused", "dense"), ("snntorch", "pyg")]:
        torch.manual_seed(4)
        model = _lively(SGNet(spec, lif_backend=lif_backend, graph_backend=graph_backend, compute="dense")).double()
        out = model(x)
        F.mse_loss(out, F.one_hot(torch.tensor([1, 4]), spec.num_classes).double()).backward()
        results.append((out.detach(), {n: p.grad for n, p in model.named_parameters()}))
    (out_a, grads_a), (out_b, grads_b) = results
    torch.testing.assert_close(out_a, out_b, rtol=0, atol=1e-12)
    assert grads_a.keys() == grads_b.keys()
    for name in grads_a:  # snnTorch's spike functions return float32, so its float64 gradients carry float32 rounding
        torch.testing.assert_close(grads_a[name], grads_b[name], rtol=1e-6, atol=1e-8, msg=name)
    assert any(g.abs().sum() > 0 for g in grads_a.values())


def test_fast_graph_weight_gradient_is_the_same_function() -> None:
    """graph_weight_grad="fast" (opt-in) changes only the summation order of the TAGConv weights' gradient: the same
    rates bit for bit, the same gradients to rounding."""
    spec = _spec("uskin_allegro", 3, 4)
    x, g = _events(spec, 3, 15, seed=7, dtype=torch.float32)
    results = []
    for weight_grad in ("autograd", "fast"):
        torch.manual_seed(8)
        model = _lively(SGNet(spec, graph_weight_grad=weight_grad, compute="dense"))  # the dense graph convolution
        out = model(x, g)
        F.mse_loss(out, F.one_hot(torch.tensor([0, 2, 5]), spec.num_classes).float()).backward()
        results.append((out.detach(), {n: p.grad for n, p in model.named_parameters()}))
    (out_a, grads_a), (out_f, grads_f) = results
    assert torch.equal(out_a, out_f) and out_a.sum() > 0
    for name in grads_a:
        torch.testing.assert_close(grads_f[name], grads_a[name], rtol=1e-4, atol=1e-6, msg=name)
    with pytest.raises(ConfigError, match="weight_grad"):
        SGNet(spec, graph_weight_grad="fast", graph_backend="pyg", compute="dense")


def test_bad_inputs_and_hparams() -> None:
    spec = _spec(globals_=2)
    model = SGNet(spec)
    x, g = _events(spec, 2, 5, dtype=torch.float32)
    with pytest.raises(ConfigError, match="global"):
        model(x)
    with pytest.raises(ConfigError):
        model(x[..., :1], g)
    with pytest.raises(ConfigError):
        SGNet(spec, hidden=())
    with pytest.raises(ConfigError):
        SGNet(spec, surrogate="tanh")


def test_trains_on_real_ev_objects(shared_data) -> None:
    """A handful of real Ev-Objects samples: finite rates in [0, 1], finite gradients, and the loss falls."""
    data = tz.load_dataset("ev_objects", root=shared_data, split="train")
    x, y = data.x[:4].float(), data.y[:4].long()
    torch.manual_seed(0)
    model = tz.create_model("sgnet", data.spec)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3, amsgrad=True)
    losses = []
    for _ in range(4):
        out = model(x)
        assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
        loss = F.mse_loss(out, F.one_hot(y, data.spec.num_classes).float())
        opt.zero_grad()
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in model.parameters())
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0]
