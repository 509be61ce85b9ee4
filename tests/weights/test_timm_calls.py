"""timm's pretrained calls against the shipped weight pack (``plugins/tactile-zoo-weights``, installed by pip as
tests/weights/test_plugin_weights.py does): ``pretrained=True`` picks the weights that match the spec or the dataset
and names the choices when it cannot, a tag in the model name, ``list_models(pretrained=True)``, and
``num_classes=`` (the trunk loaded, a fresh classifier)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file
from weights_helpers import installed_weight_pack

import tactile_zoo as tz
from tactile_zoo.errors import ConfigError, UnknownNameError
from tactile_zoo.weights import find_weights, head_name

pytestmark = pytest.mark.xdist_group("plugin_weights")

PLUGIN = Path(__file__).resolve().parents[2] / "plugins" / "tactile-zoo-weights"


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    with installed_weight_pack(PLUGIN, tmp_path_factory) as target:
        yield target


def _shipped(model: torch.nn.Module, tag: str) -> None:
    """``model`` holds exactly the shipped tensors of ``tag``."""
    state = load_file(str(find_weights(tag).local_path()))
    assert model.zoo_pretrained.tag == tag
    assert all(torch.equal(model.state_dict()[k], v) for k, v in state.items())


def test_pretrained_true_picks_the_weights_of_the_spec_or_the_dataset(installed: Path) -> None:
    ev = find_weights("x_tacformer.full_ev_objects").dataset_spec()
    _shipped(tz.create_model("x_tacformer", ev, pretrained=True), "x_tacformer.full_ev_objects")
    _shipped(tz.create_model("X-Tacformer", pretrained=True, dataset="biotac_dos"), "x_tacformer.full_biotac_dos")
    # your own data under another name: the only weights whose sensor, taxels, channels and classes it fits
    mine = dataclasses.replace(find_weights("x_tacformer.full_ev_containers").dataset_spec(), name="my_containers")
    _shipped(tz.create_model("x_tacformer", mine, pretrained=True), "x_tacformer.full_ev_containers")
    _shipped(tz.create_model("dcnn", pretrained=True, dataset="ev_containers"), "dcnn.full_ev_containers")


def test_pretrained_true_names_the_choices_when_it_cannot_pick(installed: Path) -> None:
    choices = ("x_tacformer.full_biotac_dos (biotac_dos)", "x_tacformer.full_ev_containers (ev_containers)",
               "x_tacformer.full_ev_objects (ev_objects)")
    with pytest.raises(ConfigError, match="has weights for several datasets") as info:
        tz.create_model("x_tacformer", pretrained=True)
    assert all(c in str(info.value) for c in choices)
    # a NeuTouch spec with 5 classes and a new head: both Ev datasets' weights fit it
    ev = find_weights("x_tacformer.full_ev_objects").dataset_spec()
    five = dataclasses.replace(ev, name="mine", num_classes=5, class_names=tuple("abcde"))
    with pytest.raises(ConfigError, match="several fit") as info:
        tz.create_model("x_tacformer", five, pretrained=True, new_head=True)
    assert all(c in str(info.value) for c in choices)
    with pytest.raises(UnknownNameError, match="no installed weights of model 'x_tacformer' for dataset 'nope'"):
        tz.create_model("x_tacformer", pretrained=True, dataset="nope")
    with pytest.raises(ConfigError, match="pass pretrained=True"):
        tz.create_model("x_tacformer", ev, dataset="ev_objects")


def test_a_tag_in_the_model_name(installed: Path) -> None:
    _shipped(tz.create_model("x_tacformer.full_ev_objects", pretrained=True), "x_tacformer.full_ev_objects")
    _shipped(tz.create_model("ConvLSTM.full_biotac_dos", pretrained=True), "convlstm.full_biotac_dos")
    # without pretrained: the tag's spec and hyper-parameters, fresh weights (timm's pretrained=False)
    fresh = tz.create_model("convlstm.full_biotac_dos")
    assert fresh.spec == find_weights("convlstm.full_biotac_dos").dataset_spec() and fresh.frame_norm == "minmax"
    assert not hasattr(fresh, "zoo_pretrained")
    with pytest.raises(UnknownNameError, match="no installed weights tagged 'x_tacformer.full_nope'"):
        tz.create_model("x_tacformer.full_nope", pretrained=True)
    with pytest.raises(ConfigError, match="the name's tag already names the weights"):
        tz.create_model("x_tacformer.full_ev_objects", pretrained="biotac_dos")


def test_list_models_pretrained_lists_tags_with_the_filters(installed: Path) -> None:
    tags = tz.list_models(pretrained=True)
    assert len(tags) == 18 and "x_tacformer.full_ev_objects" in tags and tags == sorted(tags)
    assert tz.list_models("x_tac*", pretrained=True) == [
        "x_tacformer.full_biotac_dos", "x_tacformer.full_ev_containers", "x_tacformer.full_ev_objects"]
    assert tz.list_models("*biotac_dos", pretrained=True) == [
        "cnn_lstm.full_biotac_dos", "convlstm.full_biotac_dos", "dcnn.full_biotac_dos", "sgnet.full_biotac_dos",
        "tacformer.full_biotac_dos", "x_tacformer.full_biotac_dos"]
    assert tz.list_models(tags=["attention"], pretrained=True) == [
        t for t in tags if t.split(".")[0] in ("tacformer", "x_tacformer")]
    assert "x_tacformer" in tz.list_models() and "x_tacformer" not in tags  # without pretrained: model names


def test_num_classes_loads_the_trunk_and_starts_a_fresh_classifier(installed: Path) -> None:
    tag = "x_tacformer.full_biotac_dos"
    state = load_file(str(find_weights(tag).local_path()))
    model = tz.create_model("x_tacformer", pretrained=True, dataset="biotac_dos", num_classes=4)
    head = head_name(model)
    assert model.get_classifier().out_features == 4 and model.spec.num_classes == 4
    for key, value in model.state_dict().items():
        if key.startswith(f"{head}."):
            assert value.shape[0] == 4
        else:
            assert torch.equal(value, state[key]), key
    x = torch.randn(2, model.spec.num_steps, model.spec.num_nodes, model.spec.num_channels)
    assert model(x).shape == (2, 4)
    # the weights' own count: their classifier too, as timm keeps it
    _shipped(tz.create_model(tag, pretrained=True, num_classes=7), tag)
