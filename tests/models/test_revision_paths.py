"""Selectable model revisions (issue 53): ``create_model(name, spec, revision=N)`` builds revision ``N``'s compute
path, a cell builds the revision it records, and each new default computes what the revision before it did.

The numerics are the issue's: a spiking model's new revision gives the previous revision's spikes exactly, for the
same weights and inputs, and its gradients within 1e-5 of the previous revision's (relative to the largest entry of
each); a non-spiking model's revision gives scores within 1e-4 and gradients within 1e-3 (relative to the largest)
of a float64 copy, on the CPU in training mode.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any

import pytest
import tiny_zoo
import torch

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.engine.config import config_hash, resolve_cell
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.lif import MultiStepLIF


def _zoo_models() -> list[str]:
    """The zoo's own models (tests/tiny_zoo.py registers others in xdist workers)."""
    return [name for name in tz.list_models() if (entry := registry.get_model_entry(name)).dist is None
            and entry.obj.__module__.startswith("tactile_zoo.models.")]


def _spec(sensor: str = "neutouch", channels: int = 2, globals_: int = 0, classes: int = 4,
          steps: int = 20) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec(f"toy_{sensor}", classes, tuple(f"c{i}" for i in range(classes)), steps, s.num_nodes,
                       channels, globals_, s)


def _events(spec: DatasetSpec, batch: int = 3, seed: int = 5) -> tuple[torch.Tensor, torch.Tensor | None]:
    gen = torch.Generator().manual_seed(seed)
    x = (torch.rand(batch, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen) < 0.2).float()
    g = torch.randn(batch, spec.num_steps, spec.num_globals, generator=gen) if spec.num_globals else None
    return x, g


# ----------------------------------------------------------------------------------------------- the registry
@pytest.mark.parametrize("name", _zoo_models())
def test_every_revision_names_constructor_keywords_and_the_default_is_the_constructors(name: str) -> None:
    """A path only sets keywords the constructor takes, and the default revision's path is the constructor's own
    defaults: the class and the registry build the same thing."""
    entry = registry.get_model_entry(name)
    params = inspect.signature(entry.obj).parameters
    revisions = registry.model_revisions(entry)
    assert registry.revision_of(entry) in revisions
    for revision, path in revisions.items():
        assert set(path) <= set(params), (revision, sorted(set(path) - set(params)))
    default = revisions[registry.revision_of(entry)]
    assert {k: params[k].default for k in default} == default


@pytest.mark.parametrize("name,keyword,old,new", [("sgnet", "compute", "dense", "event"),
                                                  ("tacformer", "attention", "fused", "explicit"),
                                                  ("x_tacformer", "attention", "fused", "explicit")])
def test_the_fast_path_is_the_new_default_and_the_old_one_stays_selectable(name: str, keyword: str, old: str,
                                                                           new: str) -> None:
    entry = registry.get_model_entry(name)
    assert registry.revision_of(entry) == 3 and sorted(registry.model_revisions(entry)) == [2, 3]
    assert registry.model_revisions(entry)[2][keyword] == old and registry.model_revisions(entry)[3][keyword] == new
    spec = _spec(classes=3)

    def built(model: torch.nn.Module) -> str:
        if name == "sgnet":
            return model.compute
        return {blk.attention for blk in model.spatial.attn}.pop()

    assert built(tz.create_model(name, spec)) == new
    assert built(tz.create_model(name, spec, revision=3)) == new
    assert built(tz.create_model(name, spec, revision=2)) == old
    assert built(tz.create_model(name, spec, revision=3, **{keyword: old})) == old  # hparams win over the path


def test_convlstms_compiled_recurrence_is_selectable_and_not_the_default() -> None:
    """No committed run shows the compiled step beating the fused one (benchmarks/results/vs_pinned.csv), so the
    default stays revision 1."""
    entry = registry.get_model_entry("convlstm")
    assert registry.revision_of(entry) == 1 and registry.model_revisions(entry) == {1: {"backend": "fused"},
                                                                                    2: {"backend": "compiled"}}
    spec = _spec()
    assert {layer.backend for layer in tz.create_model("convlstm", spec).convlstm.layers} == {"fused"}
    assert {layer.backend for layer in tz.create_model("convlstm", spec, revision=2).convlstm.layers} == {"compiled"}


def test_dcnns_accurate_batch_statistics_are_the_default_and_revision_1_stays_buildable() -> None:
    """Revision 2 computes batch norm's training statistics in two float32 passes (tests/models/test_dcnn_precision.py
    holds it to a float64 copy) and has its running statistics recomputed after training (precise_bn:
    tests/engine/test_precise_bn.py); it is the default since round 5, and revision 1 builds the older committed cells.
    Revision 3, selectable, fuses each conv block's ReLU -> batch norm -> pool (statistics in float64:
    tests/nn/test_relu_bn_pool.py)."""
    from tactile_zoo.nn.backend import BatchNormStats

    entry = registry.get_model_entry("dcnn")
    assert registry.revision_of(entry) == 2 and registry.model_revisions(entry) == {
        1: {"bn_stats": "native", "precise_bn": False, "fused_blocks": False},
        2: {"bn_stats": "two_pass", "precise_bn": True, "fused_blocks": False},
        3: {"bn_stats": "two_pass", "precise_bn": True, "fused_blocks": True}}
    spec = _spec()

    def stats(model: torch.nn.Module) -> set[BatchNormStats]:
        return {m.stats for m in model.modules() if hasattr(m, "stats") and isinstance(m, torch.nn.Module)}

    default, third, first = (tz.create_model("dcnn", spec, revision=r) for r in (None, 3, 1))
    assert stats(default) == stats(third) == {BatchNormStats.TWO_PASS} and stats(first) == {BatchNormStats.NATIVE}
    assert [b.fused for b in third.features] == [True] * 3
    assert not any(b.fused for m in (first, default) for b in m.features)
    assert default.precise_bn and third.precise_bn and not first.precise_bn


def test_an_unknown_revision_is_one_error_naming_the_model_and_its_revisions(capsys: pytest.CaptureFixture) -> None:
    message = r"model 'sgnet' has no revision 1; its revisions: 2, 3 \(default\)"
    with pytest.raises(ConfigError, match=message):
        tz.create_model("sgnet", _spec(), revision=1)
    with pytest.raises(ConfigError, match=message):
        resolve_cell("sgnet", "sim_evtouch", model_revision=1)
    with pytest.raises(ConfigError, match="model 'dcnn' has no revision 'two'"):
        tz.create_model("dcnn", _spec(), revision="two")
    assert main(["bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--model-revision", "sgnet=1",
                 "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "--model-revision or a config file's model_revisions: model 'sgnet' has no revision 1; its revisions: " \
           "2, 3 (default)" in err and err.count("\n") == 1, err
    assert main(["bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--model-revision", "sgnet=two",
                 "--dry-run"]) == 2
    assert "--model-revision expects [MODEL=]N" in capsys.readouterr().err


def test_registration_checks_the_revisions() -> None:
    class _Net(torch.nn.Module):
        def __init__(self, spec: Any, width: int = 3) -> None:
            super().__init__()

    for meta, why in [({"revision": 2, "revisions": {1: {"width": 4}}}, "must list the default revision 2"),
                      ({"revisions": {0: {}}}, "0 is not a positive integer revision"),
                      ({"revisions": {1: {"not a name": 1}}}, "revision 1 must map keyword names"),
                      ({"revisions": []}, "must map revision numbers")]:
        with pytest.raises(ConfigError, match=why):
            registry.register_model("zt_revision_check", **meta)(_Net)
    assert "zt_revision_check" not in tz.list_models()


# ----------------------------------------------------------------------------------------------- cells and hashes
def test_the_revision_is_part_of_the_cell_hash() -> None:
    """New runs of the same recipe plan the new revision: their cells never pool with the old revision's."""
    default, old = resolve_cell("sgnet", "sim_evtouch"), resolve_cell("sgnet", "sim_evtouch", model_revision=2)
    assert (default.model_revision, old.model_revision) == (3, 2) and default.hparams == old.hparams == {}
    assert config_hash(default) != config_hash(old)
    assert config_hash(resolve_cell("sgnet", "sim_evtouch", model_revision=3)) == config_hash(default)


@pytest.fixture
def revised_zoo() -> Iterator[str]:
    """tiny_zoo's datasets and a tiny model with two revisions (a hidden width of 3 at 1, of 5 at 2)."""
    tiny_zoo.register()
    name = "zt_revised_mlp"
    registry.register_model(name, revision=2, revisions={1: {"hidden": 3}, 2: {"hidden": 5}},
                            recipe=tiny_zoo.TINY_RECIPE)(tiny_zoo.TinyMLP)
    yield name
    registry._unregister("model", name)
    tiny_zoo.unregister()


def test_a_cell_builds_the_revision_it_records(revised_zoo: str) -> None:
    from tactile_zoo.engine.cell import train_cell

    for revision, width in ((None, 5), (1, 3)):
        config = resolve_cell(revised_zoo, "tiny_blobs", epochs=1, model_revision=revision)
        fit = train_cell(config, measure=False).fit
        assert fit.model.net[0].out_features == width, revision


def test_a_checkpoint_rebuilds_its_revision(revised_zoo: str) -> None:
    from tactile_zoo.engine.checkpoint import build_from_checkpoint

    spec = registry.load_dataset("tiny_blobs", split="train").spec
    config = resolve_cell(revised_zoo, "tiny_blobs", model_revision=1).to_dict()
    state = tz.create_model(revised_zoo, spec, revision=1).state_dict()
    model = build_from_checkpoint({"config": config, "state_dict": state}, spec)
    assert model.net[0].out_features == 3
    with pytest.raises(ConfigError, match=r"revision 7 of model 'zt_revised_mlp', which the installed code no "
                                          r"longer builds \(its revisions: 1, 2\)"):
        build_from_checkpoint({"config": {**config, "model_revision": 7}, "state_dict": state}, spec)


# ----------------------------------------------------------------------------------------------- the numerics
def _spikes_and_grads(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None
                      ) -> tuple[list[torch.Tensor], torch.Tensor, dict[str, torch.Tensor]]:
    """Every LIF layer's spikes, the output and every parameter's gradient of a fixed projection of it, in training
    mode (the dropout masks drawn from one seed)."""
    spikes: list[torch.Tensor] = []
    hooks = [m.register_forward_hook(lambda _m, _i, out: spikes.append((out[0] if isinstance(out, tuple) else out)
                                                                       .detach().clone()))
             for m in model.modules() if isinstance(m, MultiStepLIF)]
    model.train().zero_grad(set_to_none=True)
    torch.manual_seed(11)
    out = model(x, g)
    weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(12))
    (out * weights).sum().backward()
    for hook in hooks:
        hook.remove()
    return spikes, out.detach(), {n: p.grad for n, p in model.named_parameters() if p.grad is not None}


@pytest.mark.parametrize("name,sensor,channels,globals_", [("sgnet", "neutouch", 2, 0),
                                                           ("sgnet", "uskin_allegro", 3, 4),
                                                           ("tacformer", "neutouch", 2, 0),
                                                           ("x_tacformer", "neutouch", 2, 3)])
def test_the_new_revision_gives_the_previous_ones_spikes_and_its_gradients_within_1e_5(
        name: str, sensor: str, channels: int, globals_: int) -> None:
    spec = _spec(sensor, channels, globals_)
    torch.manual_seed(0)
    old = tz.create_model(name, spec, revision=2)
    if name == "sgnet":  # livelier weights: every layer spikes
        with torch.no_grad():
            for fc in old.fcs:
                fc.weight.mul_(3.0)
    new = tz.create_model(name, spec, revision=3)
    new.load_state_dict(old.state_dict())
    x, g = _events(spec)
    spikes_old, out_old, grads_old = _spikes_and_grads(old, x, g)
    spikes_new, out_new, grads_new = _spikes_and_grads(new, x, g)
    assert len(spikes_old) == len(spikes_new) >= 2 and sum(float(s.sum()) for s in spikes_old) > 0
    for i, (a, b) in enumerate(zip(spikes_old, spikes_new)):
        assert torch.equal(a, b), f"LIF layer {i}: {int((a != b).sum())} spikes differ"
    assert torch.equal(out_old, out_new)
    assert grads_old.keys() == grads_new.keys()
    for key, ref in grads_old.items():
        if ref.abs().max() > 0:
            assert float((grads_new[key] - ref).abs().max() / ref.abs().max()) <= 1e-5, key


def test_the_multibarrel_snns_revision_2_gives_revision_1s_spikes_and_its_gradients_within_1e_5() -> None:
    """Revision 2 runs each ALIF step as one compiled kernel forward and one backward (tactile_zoo.nn._kernels.alif):
    the columns' spikes and the logits are revision 1's exactly, in training mode (noise on) and at test time. It is
    selectable, not the default: under the bench's malloc settings its training step was the slower one."""
    pytest.importorskip("numba")
    entry = registry.get_model_entry("multibarrel")
    assert registry.revision_of(entry) == 1 and registry.model_revisions(entry) == {
        1: {"alif_backend": "torch"}, 2: {"alif_backend": "compiled"}}
    spec = _spec(classes=3, steps=60)
    small = dict(entry.meta["test_hparams"])
    torch.manual_seed(0)
    old = tz.create_model("multibarrel", spec, **small)
    new = tz.create_model("multibarrel", spec, revision=2, **small)
    assert {n.backend for n in old.neurons} == {"torch"} and {n.backend for n in new.neurons} == {"compiled"}
    new.load_state_dict(old.state_dict())
    x, _ = _events(spec, batch=4)
    for mode in ("train", "eval"):
        got = []
        for model in (old, new):
            getattr(model, mode)()
            model.zero_grad(set_to_none=True)
            torch.manual_seed(11)  # the same membrane noise and random start
            spikes = model.columns(model.compress(x))
            out = model.forward_head(model._features(spikes))
            (out * torch.randn(out.shape, generator=torch.Generator().manual_seed(12))).sum().backward()
            got.append((spikes.detach(), out.detach(), {n: p.grad for n, p in model.named_parameters()
                                                        if p.grad is not None}))
        (spikes_old, out_old, grads_old), (spikes_new, out_new, grads_new) = got
        assert 0 < float(spikes_old.sum()) < spikes_old.numel()
        assert torch.equal(spikes_old, spikes_new), f"{mode}: {int((spikes_old != spikes_new).sum())} spikes differ"
        assert torch.equal(out_old, out_new)
        assert grads_old.keys() == grads_new.keys() and any(k.startswith("neurons.") for k in grads_old)
        for key, ref in grads_old.items():
            if ref.abs().max() > 0:
                assert float((grads_new[key] - ref).abs().max() / ref.abs().max()) <= 1e-5, (mode, key)


@pytest.mark.parametrize("revision", [1, 2])
def test_convlstms_revisions_are_within_the_tolerances_of_a_float64_copy(revision: int) -> None:
    if revision == 2:
        pytest.importorskip("numba")
    spec = _spec()
    torch.manual_seed(0)
    model = tz.create_model("convlstm", spec, revision=revision)
    copy = tz.create_model("convlstm", spec, revision=revision)
    copy.load_state_dict(model.state_dict())
    copy = copy.double()
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(4, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen)
    _, out, grads = _spikes_and_grads(model, x, None)
    _, out64, grads64 = _spikes_and_grads(copy, x.double(), None)
    assert float((out.double() - out64).abs().max() / out64.abs().max()) <= 1e-4
    for key, ref in grads64.items():
        assert float((grads[key].double() - ref).abs().max() / ref.abs().max()) <= 1e-3, key


def test_pretrained_weights_build_the_revision_their_manifest_records(tmp_path) -> None:
    """Weights trained at SGnet's revision 2 load into revision 2's dense path, the default being 3; hparams still
    win, and asking for another revision with them is refused."""
    import hashlib
    import json

    from safetensors.torch import save_file

    spec = _spec(classes=3)
    torch.manual_seed(0)
    trained = tz.create_model("sgnet", spec, revision=2)
    file = tmp_path / "w.safetensors"
    save_file({k: v.contiguous() for k, v in trained.state_dict().items()}, str(file))
    entry = {"tag": "sgnet.toy", "model": "sgnet", "dataset": spec.name, "spec": spec.to_dict(), "hparams": {},
             "file": file.name, "sha256": hashlib.sha256(file.read_bytes()).hexdigest(), "model_revision": 2}
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps({"format": "tactile-zoo-weights/1", "weights": [entry]}))
    loaded = tz.create_model("sgnet", pretrained=str(manifest))
    assert loaded.compute == "dense" and tz.create_model("sgnet", spec).compute == "event"
    x, _ = _events(spec)
    with torch.no_grad():
        assert torch.equal(loaded.eval()(x), trained.eval()(x))
    assert tz.create_model("sgnet", pretrained=str(manifest), compute="event").compute == "event"
    with pytest.raises(ConfigError, match="were trained with revision 2 of model 'sgnet' and load into that "
                                          "revision only"):
        tz.create_model("sgnet", pretrained=str(manifest), revision=3)
    manifest.write_text(json.dumps({"format": "tactile-zoo-weights/1", "weights": [{**entry, "model_revision": 1}]}))
    with pytest.raises(ConfigError, match=r"revision 1 of model 'sgnet'; the installed model is revision 3 \(it "
                                          r"builds revision\(s\) 2, 3\)"):
        tz.create_model("sgnet", pretrained=str(manifest))
