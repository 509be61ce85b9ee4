"""``create_model(..., pretrained=...)``: the saved model exactly, one clear error for weights that do not fit, and
``new_head=True``."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from weights_helpers import DATA_ARGS, DATASET, HPARAMS, MODEL, Trained, sample_table, slip_spec

import tactile_zoo as tz
from tactile_zoo.engine.evaluate import predict_scores
from tactile_zoo.errors import ConfigError, DatasetError
from tactile_zoo.weights import head_name, write_manifest


def _logits(model: torch.nn.Module, trained: Trained) -> torch.Tensor:
    return predict_scores(model, trained.test.x, trained.test.g)


def test_the_manifest_reproduces_the_saved_models_logits_exactly(trained: Trained) -> None:
    model = tz.create_model(MODEL, pretrained=trained.manifest)
    assert torch.equal(_logits(model, trained), trained.logits)
    assert model.spec.to_dict() == trained.test.spec.to_dict()  # no spec given: the weights' own
    assert model.zoo_pretrained.tag == "cnn_lstm.full_sim_uskin_textures"
    assert model.zoo_loss == "ce"
    assert not torch.equal(_logits(tz.create_model(MODEL, trained.test.spec, **HPARAMS), trained), trained.logits)


def test_a_safetensors_file_is_described_by_the_manifest_next_to_it(trained: Trained, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no manifest describes"):
        tz.create_model(MODEL, pretrained=trained.file)  # the run's weights/ folder holds no manifest
    folder = tmp_path / "mine"
    folder.mkdir()
    copy = Path(shutil.copy(trained.file, folder / "renamed.safetensors"))
    shutil.copy(trained.manifest, folder / "manifest.json")  # its entry names the original file: matched by sha256
    model = tz.create_model("CNN-LSTM", trained.test.spec, pretrained=copy)
    assert torch.equal(_logits(model, trained), trained.logits)
    assert model.zoo_pretrained.local_path() == copy.resolve()
    (folder / "manifest.json").rename(folder / "renamed.json")
    assert tz.create_model(MODEL, pretrained=str(copy)).zoo_pretrained.local_path() == copy.resolve()
    other = folder / "other.safetensors"
    other.write_bytes(b"not these weights")
    shutil.copy(folder / "renamed.json", folder / "other.json")
    with pytest.raises(ConfigError, match=r"has no entry for .*other.safetensors .*; it lists: cnn_lstm.full_"):
        tz.create_model(MODEL, pretrained=other)


def test_a_weight_entry_and_a_dataset_spec_round_trip(trained: Trained) -> None:
    spec = trained.entry.dataset_spec()
    assert spec == trained.test.spec
    assert tz.DatasetSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ConfigError, match="lacks num_globals"):
        tz.DatasetSpec.from_dict({k: v for k, v in spec.to_dict().items() if k != "num_globals"})
    model = tz.create_model(MODEL, pretrained=trained.entry)
    assert torch.equal(_logits(model, trained), trained.logits)


def test_weights_that_do_not_fit_the_data_say_everything_that_differs(trained: Trained) -> None:
    spec = trained.test.spec
    fewer = dataclasses.replace(spec, num_classes=4, class_names=spec.class_names[:4])
    with pytest.raises(ConfigError, match=r"classes: the weights know 10, your data has 4.*new_head=True"):
        tz.create_model(MODEL, fewer, pretrained=trained.manifest)
    renamed = dataclasses.replace(spec, class_names=("x", *spec.class_names[1:]))
    with pytest.raises(ConfigError, match=r"class names: class 0 is '.+' in the weights, 'x' in your data"):
        tz.create_model(MODEL, renamed, pretrained=trained.manifest)
    slip = slip_spec()
    with pytest.raises(ConfigError) as info:
        tz.create_model(MODEL, slip, pretrained=trained.manifest)
    message = str(info.value)
    for part in ("classes: the weights know 10, your data has 7", "sensor: the weights were trained on "
                 "'uskin_allegro', your data is 'biotac_sp'", "taxels: the weights expect 60, your data has 24",
                 "channels per taxel: the weights expect 3, your data has 1",
                 "global features: the weights expect 8, your data has 0"):
        assert part in message
    longer = dataclasses.replace(spec, num_steps=20)  # 20 steps: bins of 5 frames instead of 3
    with pytest.raises(ConfigError, match="steps: the weights were trained on 12 steps, your data has 20"):
        tz.create_model(MODEL, longer, pretrained=trained.manifest)
    same_bins = dataclasses.replace(spec, num_steps=11)  # ceil(11 / 4) = 3 frames per bin, as for 12
    assert torch.equal(_logits(tz.create_model(MODEL, same_bins, pretrained=trained.manifest), trained),
                       trained.logits)


def test_weights_of_another_model_another_revision_or_a_damaged_file_are_refused(trained: Trained,
                                                                                  tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="are for model 'cnn_lstm', not 'convlstm'"):
        tz.create_model("convlstm", pretrained=trained.entry)
    with pytest.raises(ConfigError, match="no entry for model 'convlstm'"):
        tz.create_model("convlstm", pretrained=trained.manifest)
    old = dataclasses.replace(trained.entry, model_revision=trained.entry.model_revision + 1)
    with pytest.raises(ConfigError, match="the installed model is revision 1"):
        tz.create_model(MODEL, pretrained=old)
    damaged = tmp_path / "w.safetensors"
    blob = bytearray(trained.file.read_bytes())
    blob[-1] ^= 0xFF
    damaged.write_bytes(bytes(blob))
    with pytest.raises(DatasetError, match="has sha256 .* the manifest says"):
        tz.create_model(MODEL, pretrained=dataclasses.replace(trained.entry, file=str(damaged)))
    assert damaged.exists()  # a user's file is refused, never deleted
    with pytest.raises(ConfigError, match="do not fit model 'cnn_lstm' built with .*'hidden': 13.*size mismatch"):
        tz.create_model(MODEL, pretrained=trained.entry, hidden=13)  # an override reaches the constructor
    with pytest.raises(ConfigError, match="pass the dataset spec, or pretrained="):
        tz.create_model(MODEL)
    with pytest.raises(ConfigError, match="new_head=True replaces the classifier"):
        tz.create_model(MODEL, trained.test.spec, new_head=True)


def test_new_head_keeps_the_trunk_and_starts_a_fresh_classifier(trained: Trained) -> None:
    saved = load_file(trained.file)
    spec = trained.test.spec
    for classes in (4, 10):
        names = tuple(f"mine_{i}" for i in range(classes))
        mine = dataclasses.replace(spec, num_classes=classes, class_names=names)
        torch.manual_seed(classes)
        model = tz.create_model(MODEL, mine, pretrained=trained.manifest, new_head=True)
        state = model.state_dict()
        assert head_name(model) == "head"
        trunk = [k for k in saved if not k.startswith("head.")]
        assert trunk and all(torch.equal(state[k], saved[k]) for k in trunk)
        assert state["head.weight"].shape == (classes, HPARAMS["hidden"]) and state["head.bias"].shape == (classes,)
        if classes == 10:  # the same shape as the saved head, initialised afresh all the same
            assert not torch.equal(state["head.weight"], saved["head.weight"])
        assert _logits(model, trained).shape == (len(trained.test), classes)
    with pytest.raises(ConfigError, match="pass the spec of your data"):
        tz.create_model(MODEL, pretrained=trained.manifest, new_head=True)
    slip = slip_spec()
    with pytest.raises(ConfigError, match="taxels: the weights expect 60") as info:
        tz.create_model(MODEL, slip, pretrained=trained.manifest, new_head=True)
    assert "classes" not in str(info.value)  # a new head takes any classes; the trunk still needs the sensor


@pytest.mark.parametrize(("model", "head"), [("cnn_lstm", "head"), ("convlstm", "head"), ("tacformer", "head"),
                                             ("x_tacformer", "head"), ("dcnn", "classifier.7"), ("sgnet", "fcs.2")])
def test_every_built_in_model_names_its_classifier_head(model: str, head: str) -> None:
    spec = slip_spec()
    built = tz.create_model(model, spec)
    assert head_name(built, spec.num_classes) == head
    layer = built.get_submodule(head)
    assert isinstance(layer, torch.nn.Linear) and layer.out_features == spec.num_classes


def test_a_model_without_a_head_is_an_error_naming_the_convention() -> None:
    with pytest.raises(ConfigError, match="set zoo_head"):
        head_name(torch.nn.Sequential(torch.nn.Conv1d(2, 3, 1)), 3)
    with pytest.raises(ConfigError, match="not one of its submodules"):
        head_name(type("M", (torch.nn.Module,), {"zoo_head": "nope"})(), 3)


def test_a_manifest_written_elsewhere_keeps_pointing_at_the_file(trained: Trained, tmp_path: Path) -> None:
    moved = write_manifest([trained.entry], tmp_path / "elsewhere" / "m.json")
    model = tz.create_model(MODEL, pretrained=moved)
    assert torch.equal(_logits(model, trained), trained.logits)
    assert DATASET in model.zoo_pretrained.tag and model.zoo_pretrained.dataset_kwargs == DATA_ARGS


def test_sgnet_without_a_zoo_head_gets_a_new_head_and_its_rates_read_as_evaluate_reads_them(tmp_path: Path) -> None:
    from tactile_zoo.bench.worker import save_weights
    from tactile_zoo.weights import WeightEntry

    test = tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=2, num_steps=6)
    torch.manual_seed(0)
    hparams = {"graph_channels": 4, "hidden": [8]}
    saved_model = tz.create_model("sgnet", test.spec, **hparams)
    info = save_weights(saved_model, tmp_path / "weights" / "sgnet.safetensors", {"model": "sgnet"})
    entry = WeightEntry(tag="sgnet.source_sim_biotac_slip", model="sgnet", dataset="sim_biotac_slip",
                        spec=test.spec.to_dict(), sha256=info["sha256"], file=str(tmp_path / info["file"]),
                        hparams=hparams, loss="mse_rate")
    model = tz.create_model("sgnet", pretrained=entry)
    assert model.zoo_loss == "mse_rate" and not hasattr(type(model), "zoo_head")
    files = []
    for i in range(len(test)):
        np.save(tmp_path / f"{i}.npy", sample_table(test, i))
        files.append(tmp_path / f"{i}.npy")
    result = tz.evaluate(model, test)
    preds = tz.predict(model, files)
    assert [p.index for p in preds] == result.predictions
    assert np.allclose([p.probabilities for p in preds], result.probabilities, atol=1e-6)  # rates normalised to 1
    three = dataclasses.replace(test.spec, num_classes=3, class_names=("a", "b", "c"))
    fresh = tz.create_model("sgnet", three, pretrained=entry, new_head=True)
    saved, state = saved_model.state_dict(), fresh.state_dict()
    assert head_name(fresh, 3) == "fcs.1" and state["fcs.1.weight"].shape == (3, 8)
    assert all(torch.equal(state[k], v) for k, v in saved.items() if not k.startswith("fcs.1."))
