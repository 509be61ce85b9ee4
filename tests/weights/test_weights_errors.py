"""Malformed weight entries and manifests, ambiguous local manifests, and the arguments ``create_model`` and
``predict`` refuse before any work: each with its message. No weights are loaded and nothing is downloaded."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from torch import nn

from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import get_sensor
from tactile_zoo.weights import MANIFEST_FORMAT, WeightEntry, parse_manifest, read_manifest
from tactile_zoo.weights.load import _with_classes, create_model, local_weights, resolve_weights
from tactile_zoo.weights.manifest import _json_value
from tactile_zoo.weights.predict import iter_predict, predict

SPEC = {"name": "sim_evtouch", "num_classes": 2, "class_names": ["a", "b"], "num_steps": 5, "num_nodes": 39,
        "num_channels": 2, "num_globals": 0, "sensor": "neutouch"}


def _entry(**changes: Any) -> dict[str, Any]:
    base = {"tag": "sgnet.source_sim_evtouch", "model": "sgnet", "dataset": "sim_evtouch", "sha256": "ab" * 32,
            "file": "w.safetensors", "spec": SPEC}
    return {**base, **changes}


@pytest.mark.parametrize(("values", "message"), [
    (["sgnet"], "^entry 3: an entry must be a JSON object, got list$"),
    (_entry(licence=3), r"^entry 3 \('sgnet.source_sim_evtouch'\): licence must be a string, got 3$"),
    (_entry(file=7), r"file must be a string or null, got 7$"),
    (_entry(seed=-1), r"seed must be a non-negative integer, got -1$"),
    (_entry(fold=True), r"fold must be a non-negative integer, got True$"),
    (_entry(hparams=[1]), r"hparams must be a JSON object, got \[1\]$"),
])
def test_a_malformed_entry_is_refused_naming_it_and_the_key(values: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        WeightEntry.from_dict(values, "entry 3")


def test_an_entry_gives_its_class_names_as_a_tuple_of_strings() -> None:
    entry = WeightEntry.from_dict(_entry(spec={**SPEC, "class_names": ["a", 2]}))
    assert entry.class_names == ("a", "2") and entry.num_classes == 2


def test_a_manifest_that_is_not_an_object_is_refused() -> None:
    with pytest.raises(ConfigError, match="^m.json: a weights manifest must be a JSON object with 'format' and "
                                          "'weights', got str$"):
        parse_manifest("sgnet", "m.json")


def test_a_manifest_that_is_not_utf8_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_bytes(b'{"format": "\xff\xfe"}')
    with pytest.raises(ConfigError, match=f"^weights manifest {path} cannot be read: 'utf-8' codec can't decode"):
        read_manifest(path)


def test_values_json_cannot_hold_are_kept_as_their_repr() -> None:
    assert _json_value({"a": (1, None), 2: [True, 0.5], "p": Path("w")}) == {"a": [1, None], "2": [True, 0.5],
                                                                           "p": "PosixPath('w')"}


def _manifest(tmp_path: Path, *entries: dict[str, Any]) -> Path:
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"format": MANIFEST_FORMAT, "weights": list(entries)}))
    return path


def test_a_local_manifest_with_several_entries_needs_a_tag(tmp_path: Path) -> None:
    path = _manifest(tmp_path, _entry(), _entry(tag="sgnet.source_sim_evtouch_s1", seed=1))
    with pytest.raises(ConfigError, match=f"^weights manifest {path} has several entries for model 'sgnet' "
                                          r"\(sgnet.source_sim_evtouch, sgnet.source_sim_evtouch_s1\); name one by its "
                                          "tag$"):
        local_weights(path, model="sgnet")
    assert local_weights(path, model="sgnet", tag="SGnet.source_sim_evtouch_s1").seed == 1
    with pytest.raises(ConfigError, match=f"^weights file {tmp_path / 'absent.safetensors'} does not exist$"):
        local_weights(path, tmp_path / "absent.safetensors")


@pytest.mark.parametrize(("pretrained", "message"), [
    ("https://example.org/weights/sgnet", r"^pretrained='https://example.org/weights/sgnet': a URL alone does not "
                                          r"say what the weights are; put it in a manifest entry"),
    (3, r"^pretrained must be a dataset name, a tag, a .json manifest, a .safetensors file or a WeightEntry, got 3$"),
    ("  ", r"got '  '$"),
])
def test_pretrained_that_names_no_weights_is_refused(pretrained: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        resolve_weights("sgnet", pretrained)


@pytest.mark.parametrize("name", ["sgnet.", ".source_sim_evtouch", "sgnet.  "])
def test_a_model_name_with_an_empty_tag_is_refused(name: str) -> None:
    with pytest.raises(ConfigError, match=f"^model name {name!r}: a tag reads <model>.<tag>, e.g. "
                                          f"'x_tacformer.full_ev_objects'$"):
        create_model(name)


def test_num_classes_must_be_a_positive_integer() -> None:
    spec = DatasetSpec("sim_evtouch", 2, ("a", "b"), 5, 39, 2, 0, get_sensor("neutouch"))
    for bad in (0, True, 2.0):
        with pytest.raises(ConfigError, match=f"^num_classes must be a positive integer, got {bad!r}$"):
            _with_classes(spec, bad)
    assert _with_classes(spec, 2) is spec
    assert _with_classes(spec, 3).class_names == ("class_0", "class_1", "class_2")


def test_predict_refuses_inputs_and_batches_it_cannot_take() -> None:
    spec = DatasetSpec("sim_evtouch", 2, ("a", "b"), 5, 39, 2, 0, get_sensor("neutouch"))
    model = nn.Linear(2, 2)
    with pytest.raises(ConfigError, match="^inputs must be a file, an array, or a list of them, got int$"):
        predict(model, 3, spec=spec)
    with pytest.raises(ConfigError, match="^batch_size must be a positive integer, got 0$"):
        iter_predict(model, [np.zeros((5, 78))], spec=spec, batch_size=0)
    with pytest.raises(ConfigError, match=r"^predict: pass spec= \(the Linear model does not say which data it was "
                                          r"built for\)$"):
        predict(model, [np.zeros((5, 78))])
