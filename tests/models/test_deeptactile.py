"""DeepTactile against the facts of its source (GuoFM/DeepTactile: model.py, tdlayer.py, to_graph.py, main.py).

The central check writes the source's forward pass out the way its code runs it: layout ``(B, N, C, T)``, PyG's
TAGConv called once per time step, tdBN statistics over ``(B, N, T)`` per channel scaled by the threshold, the
membrane update ``mem * 0.2 * (1 - spike) + I`` stepped in a loop with a rectangular surrogate, and the spiking MLP
stepped frame by frame, on our model's own parameters: outputs and parameter gradients must agree.
"""

from __future__ import annotations

import pytest
import torch
from test_zoo import make_batch

import tactile_zoo as tz
from tactile_zoo.data.sensors import NEUTOUCH_HAND_EDGES
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.engine.config import resolve_model_recipe
from tactile_zoo.errors import ConfigError
from tactile_zoo.models._binned import bin_frames
from tactile_zoo.models.deeptactile import DeepTactile, _DenseLayer, _Transition
from tactile_zoo.nn.lif import MultiStepLIF
from tactile_zoo.nn.tdbn import TdBatchNorm
from tactile_zoo.registry import get_model_entry

THRESH, DECAY, LENS = 0.5, 0.2, 0.5  # tdlayer.py's constants


def ev_spec(num_classes: int = 36, steps: int = 6, sensor: str = "neutouch") -> DatasetSpec:
    """Ev-Objects-shaped (NeuTouch: 39 taxels, ON/OFF channels), with few steps."""
    s = tz.get_sensor(sensor)
    return DatasetSpec(f"ev_like_{sensor}", num_classes, tuple(f"c{i}" for i in range(num_classes)), steps,
                       s.num_nodes, len(s.channels) or 2, 0, s)


def test_widths_and_parameter_count_are_the_sources_with_the_first_linear_sized_for_39_taxels() -> None:
    model = DeepTactile(ev_spec(36))
    assert sum(p.numel() for p in model.parameters()) == 1_209_588  # about 1.2M, the figure
    assert sum(p.numel() for p in DeepTactile(ev_spec(20)).parameters()) == 1_205_476  # Ev-Containers' 20 classes
    dense = [u for u in model.features if isinstance(u, _DenseLayer)]
    (transition,) = [u for u in model.features if isinstance(u, _Transition)]
    assert [u.conv1.in_channels for u in dense] == [64, 96, 128, 80, 112, 144]  # growth 32, two blocks of 3
    assert {(u.conv1.out_channels, u.conv2.in_channels, u.conv2.out_channels) for u in dense} == {(128, 128, 32)}
    assert (transition.conv.in_channels, transition.conv.out_channels) == (160, 80)  # compression 0.5
    assert model.out_norm.num_features == 176
    hops = {model.stem.conv.K, transition.conv.conv.K, *(u.conv1.conv.K for u in dense)}
    assert hops == {1} and {u.conv2.conv.K for u in dense} == {3}  # TAGConv K=1 everywhere but the growth conv
    assert [(fc.in_features, fc.out_features) for fc in model.fcs] == [(39 * 176, 128), (128, 256), (256, 36)]
    norms = [m for m in model.modules() if isinstance(m, TdBatchNorm)]
    assert len(norms) == 15 and {(n.threshold, n.alpha, n.eps, n.momentum) for n in norms} == {(0.5, 1.0, 1e-5, 0.1)}
    lifs = [m for m in model.modules() if isinstance(m, MultiStepLIF)]
    assert len(lifs) == 18 and {(m.beta, m.threshold, m.reset, m.surrogate.kind, m.surrogate.param, m.detach_reset)
                                for m in lifs} == {(DECAY, THRESH, "zero", "rect", 2 * LENS, False)}


def test_the_neutouch_graph_is_the_hand_made_one_and_other_sensors_keep_theirs() -> None:
    edges = DeepTactile(ev_spec()).stem.edge_index
    assert edges.shape == (2, 146)  # to_graph.py's k=0 lists: 146 directed pairs, 73 undirected edges
    assert {tuple(sorted(e)) for e in edges.t().tolist()} == set(NEUTOUCH_HAND_EDGES)
    assert sorted(b for a, b in NEUTOUCH_HAND_EDGES if a == 20) == [22, 23, 26]  # taxel 21 (1-based): 6 neighbours
    assert sum(20 in e for e in NEUTOUCH_HAND_EDGES) == 6
    spec = ev_spec(sensor="biotac_sp")
    assert torch.equal(DeepTactile(spec).stem.edge_index, spec.sensor.edge_index())
    mst = DeepTactile(ev_spec(), graph="default").stem.edge_index  # the sensor's default (SGnet's tree) on request
    assert mst.shape == (2, 76)


class _Act(torch.autograd.Function):
    """tdlayer.py's ActFun: spike where ``mem > 0.5``; gradient passed where ``|mem - 0.5| < 0.5``."""

    @staticmethod
    def forward(ctx, mem: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        ctx.save_for_backward(mem)
        return mem.gt(THRESH).to(mem.dtype)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        (mem,) = ctx.saved_tensors
        return grad * ((mem - THRESH).abs() < LENS).to(grad.dtype)


def _lif(x: torch.Tensor) -> torch.Tensor:
    """LIFSpike over the last (time) dimension, the reset through the previous spike, not detached."""
    mem = spike = torch.zeros_like(x[..., 0])
    out = []
    for t in range(x.shape[-1]):
        mem = mem * DECAY * (1 - spike) + x[..., t]
        spike = _Act.apply(mem)
        out.append(spike)
    return torch.stack(out, -1)


def _bn(norm: TdBatchNorm, x: torch.Tensor) -> torch.Tensor:
    """EBNorm in training mode on ``(B, N, C, T)``: statistics over dims 0, 1, 3, scaled by the threshold."""
    mean, var = x.mean([0, 1, 3]), x.var([0, 1, 3], unbiased=False)
    col = (None, None, slice(None), None)
    return THRESH * (x - mean[col]) / torch.sqrt(var[col] + norm.eps) * norm.weight[col] + norm.bias[col]


def _conv(layer, x: torch.Tensor) -> torch.Tensor:
    """TF_Layer: the PyG TAGConv once per time step on ``(B, N, C)``."""
    return torch.stack([layer.conv(x[..., t], layer.edge_index) for t in range(x.shape[-1])], -1)


def _source_forward(model: DeepTactile, data: torch.Tensor) -> torch.Tensor:
    """model.py's DeepTactile.forward on ``data (B, N, C, T)`` with ``model``'s parameters."""
    x = _lif(_bn(model.stem_norm, _conv(model.stem, data)))
    for unit in model.features:
        if isinstance(unit, _DenseLayer):
            new = _conv(unit.conv1, _lif(_bn(unit.norm1, x)))
            new = _conv(unit.conv2, _lif(_bn(unit.norm2, new)))
            x = torch.cat([x, new], dim=2)
        else:
            x = _conv(unit.conv, _lif(_bn(unit.norm, x)))
    x = _lif(_bn(model.out_norm, x))
    batch, steps = data.shape[0], data.shape[-1]
    mems = [torch.zeros(batch, fc.out_features, dtype=data.dtype) for fc in model.fcs]
    spikes = [torch.zeros_like(m) for m in mems]
    total = torch.zeros_like(mems[-1])
    for t in range(steps):  # mem_update_FC, one frame at a time
        inp = x[..., t].reshape(batch, -1)
        for i, fc in enumerate(model.fcs):
            mems[i] = mems[i] * DECAY * (1 - spikes[i]) + fc(inp)
            spikes[i] = inp = _Act.apply(mems[i])
        total = total + spikes[-1]
    return total / steps


def test_forward_and_gradients_equal_the_source_written_out_step_by_step() -> None:
    spec = ev_spec(5, steps=10)
    torch.manual_seed(2)  # a seed whose output layer fires at the start, so that the rates compare something
    model = DeepTactile(spec).double().train()
    x, _, y = make_batch(spec, 3, seed=1)
    x = x.double()
    ours = model(x)
    source = _source_forward(model, x.permute(0, 2, 3, 1))  # (B, T, N, C) -> the source's (B, N, C, T)
    assert 0 < ours.sum() and torch.equal(ours, source)  # rates: exact counts of the same spikes
    target = torch.nn.functional.one_hot(y, 5).double()
    params = [p for p in model.parameters()]
    mine = torch.autograd.grad(torch.nn.functional.mse_loss(ours, target), params)
    theirs = torch.autograd.grad(torch.nn.functional.mse_loss(source, target), params)
    assert sum(float(g.abs().sum()) for g in theirs) > 0
    for (name, _), a, b in zip(model.named_parameters(), mine, theirs):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12, msg=name)


def test_batch_statistics_pool_the_batch_in_training_and_evaluation_is_per_sample() -> None:
    spec = ev_spec(5, steps=8)
    torch.manual_seed(1)
    model = DeepTactile(spec)
    x, _, _ = make_batch(spec, 4, seed=2)
    spikes: list[torch.Tensor] = []
    model.stem_lif.register_forward_hook(lambda _m, _i, out: spikes.append(out[0] if isinstance(out, tuple) else out))
    with torch.no_grad():
        model.train()(x)
        assert set(spikes[-1].unique().tolist()) <= {0.0, 1.0} and 0 < float(spikes[-1].mean()) < 1
        # training mode normalises with the batch's own statistics: sample 0 alone gets other spikes than in the batch
        alone = model(x[:1])
        assert not torch.equal(spikes[-1], spikes[-2][:, :1])
        assert int(model.stem_norm.num_batches_tracked) == 2
        model.eval()  # evaluation: the running estimates, so a sample's output does not depend on its batch
        rates = model(x)
        assert torch.equal(model(x[:1]), rates[:1])
        assert torch.equal(rates * spec.num_steps, (rates * spec.num_steps).round())  # spike counts / T
        assert alone.shape == (1, 5)


def test_the_recipes_are_the_source_as_released_and_the_zoo_protocol_on_it() -> None:
    meta = get_model_entry("deeptactile").meta
    assert meta["default_recipe"] == "zoo" and set(meta["recipes"]) == {"source", "zoo", "full"}
    source = resolve_model_recipe(meta, "source", "ev_objects")
    r = source.recipe
    assert (r.loss, r.optimizer, r.amsgrad, r.lr, r.weight_decay, r.schedule) == ("mse_rate", "adam", False, 1e-3,
                                                                                  0.0, None)
    assert (r.max_epochs, r.patience, r.batch_size) == (100, None, 16)  # main.py's defaults
    assert source.evaluation == "final" and source.hparams == {"init": "default"}  # fixed epochs, test read at the end
    zoo = resolve_model_recipe(meta, "zoo", "ev_containers")
    assert zoo.evaluation in (None, "validation") and zoo.hparams == {}
    assert zoo.recipe.patience == 20 and zoo.recipe.replace(patience=None) == r


def test_initialisations() -> None:
    torch.manual_seed(0)
    lecun = DeepTactile(ev_spec())  # ours: normal, std 1 / sqrt(fan_in)
    torch.manual_seed(0)
    source = DeepTactile(ev_spec(), init="default")  # PyTorch's: uniform within 1 / sqrt(fan_in)
    for a, b in zip(lecun.fcs, source.fcs):
        bound = a.in_features ** -0.5
        assert float(b.weight.detach().abs().max()) <= bound < float(a.weight.detach().abs().max())
        assert abs(float(a.weight.detach().std()) * a.in_features ** 0.5 - 1) < 0.05
    lecun.reset_classifier(4)  # a fresh head is initialised as the constructor does
    assert abs(float(lecun.fcs[-1].weight.detach().std()) * 16 - 1) < 0.1
    for bad, culprit in (({"init": "xavier"}, "init must be one of lecun, he, default"),
                         ({"bin_size": 0}, "bin_size must be >= 1"),
                         ({"block_config": ()}, "widths and block sizes must be positive"),
                         ({"compression": 0.0}, "compression must lie in")):
        with pytest.raises(ConfigError, match=culprit):
            DeepTactile(ev_spec(), **bad)


def test_bins_sum_frames_before_the_stem() -> None:
    spec = ev_spec(5, steps=7)
    torch.manual_seed(2)
    binned = DeepTactile(spec, bin_size=2).eval()
    plain = DeepTactile(spec).eval()
    plain.load_state_dict(binned.state_dict())
    x, _, _ = make_batch(spec, 2, seed=3)
    with torch.no_grad():
        assert torch.equal(binned(x), plain(bin_frames(x, 2)))  # 7 frames: 3 bins of 2 and a partial one
