"""Weight entries and manifests: the tag scheme, the entry made from a bench cell record, round trips, and one clear
error for each malformed manifest."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from weights_helpers import CELL_ID, CONFIG_HASH, DATA_ARGS, DATASET, HPARAMS, MODEL, Trained

from tactile_zoo.data.base import file_sha256
from tactile_zoo.engine.config import resolve_cell
from tactile_zoo.errors import ConfigError
from tactile_zoo.weights import (
    DEFAULT_LICENCE,
    ENTRY_KEYS,
    MANIFEST_FORMAT,
    WeightEntry,
    entry_from_record,
    make_tag,
    parse_manifest,
    preprocessing_of,
    read_manifest,
    tag_key,
)
from tactile_zoo.weights.manifest import recipe_changes


def test_weights_that_did_not_follow_their_recipe_are_tagged_custom(trained: Trained) -> None:
    """Issue 49 item 8: the tag names a recipe; a cell that changed it (here 2 epochs and --hparam values, as
    ``--epochs 1`` would) is tagged ``custom`` and its note says what changed; a cell that followed it keeps it."""
    honest = entry_from_record(trained.record, trained.run, note="trained by the test suite")
    assert honest.tag == "cnn_lstm.custom_sim_uskin_textures" and honest.recipe == "custom"
    declared = resolve_cell(MODEL, DATASET)
    assert honest.note.startswith(f"Trained with recipe 'full' changed (max_epochs 2 (the recipe: "
                                  f"{declared.recipe.max_epochs}); hparam ")
    assert honest.note.endswith("so tagged 'custom'. trained by the test suite")
    assert recipe_changes(MODEL, DATASET, trained.record["config"]) in honest.note
    followed = {**trained.record["config"], "recipe": declared.recipe.to_dict(), "hparams": dict(declared.hparams)}
    assert recipe_changes(MODEL, DATASET, followed) == ""
    entry = entry_from_record({**trained.record, "config": followed}, trained.run, note="n")
    assert entry.tag == "cnn_lstm.full_sim_uskin_textures" and entry.recipe == "full" and entry.note == "n"


def test_tags_follow_model_dot_recipe_dataset() -> None:
    assert make_tag("x_tacformer", "ev_objects") == "x_tacformer.source_ev_objects"
    assert make_tag("tactile-zoo-tcn:tcn", "sim_evtouch", "default", fold=2, seed=1) == "tcn.default_sim_evtouch_f2_s1"
    assert tag_key("X-Tacformer.Source_Ev-Objects") == tag_key("x_tacformer.source_ev_objects")
    assert tag_key("x_tacformer.source_ev_objects") != tag_key("x_tacformer.source_ev_containers")


def test_the_entry_of_a_cell_record_holds_everything_the_issue_lists(trained: Trained) -> None:
    entry, record = trained.entry, trained.record
    assert entry.tag == "cnn_lstm.full_sim_uskin_textures"
    assert (entry.model, entry.dataset, entry.recipe, entry.loss) == (MODEL, DATASET, "full", "ce")
    assert entry.spec == record["spec"] and entry.spec["num_nodes"] == 60 and entry.spec["sensor"] == "uskin_allegro"
    assert entry.hparams == HPARAMS and entry.dataset_kwargs == DATA_ARGS
    assert (entry.config_hash, entry.cell_id, entry.seed, entry.fold) == (CONFIG_HASH, CELL_ID, 0, 0)
    assert entry.accuracy == record["metrics"]["test"]["accuracy"] and entry.commit == "0123abc"
    assert entry.sha256 == file_sha256(trained.file) == record["weights"]["sha256"]
    assert entry.bytes == trained.file.stat().st_size and entry.model_revision == 1
    assert entry.licence == DEFAULT_LICENCE and entry.dataset_licence == "generated (MIT, part of tactile-zoo)"
    assert entry.note == "trained by the test suite"
    # the preprocessing, resolved: the dataset's options with their defaults, and the model's frame bins (12 steps
    # read as at most max_frames=4 bins: 3 frames each)
    assert entry.preprocessing == {"dataset_options": {"seed": 0, **DATA_ARGS}, "frame_period_s": None,
                                   "frame_bin_size": 3}
    assert set(entry.to_dict()) == ENTRY_KEYS


def test_preprocessing_fills_the_datasets_defaults_and_leaves_the_unknown_empty() -> None:
    spec = {"name": "biotac_dos", "num_classes": 7, "class_names": list("nsewcat"), "num_steps": 10, "num_nodes": 24,
            "num_channels": 1, "num_globals": 0, "sensor": "biotac_sp"}
    described = preprocessing_of("cnn_lstm", "biotac_dos", spec, {"max_frames": 5}, {"window": 10})
    assert described == {"dataset_options": {"protocol": "objects", "validation": "recordings", "num_folds": 5,
                                             "window": 10, "stride": None, "normalize": "baseline", "baseline": 10,
                                             "scale": 1000.0},
                         "frame_period_s": 0.01, "frame_bin_size": 2}
    unknown = preprocessing_of("no_such_model", "no_such_dataset", spec, {}, {"window": 3})
    assert unknown == {"dataset_options": {"window": 3}, "frame_period_s": None, "frame_bin_size": None}


def test_a_written_manifest_reads_back_with_the_file_relative_to_it(trained: Trained) -> None:
    document = json.loads(trained.manifest.read_text())
    assert document["format"] == MANIFEST_FORMAT
    assert document["weights"][0]["file"] == f"weights/{CELL_ID}.safetensors"  # relative: the folder can move
    (entry,) = read_manifest(trained.manifest)
    assert entry.local_path() == trained.file
    assert dataclasses.replace(entry, file=None) == dataclasses.replace(trained.entry, file=None)
    assert entry.origin == str(trained.manifest) and entry.dist is None


def test_records_without_publishable_weights_are_refused(trained: Trained) -> None:
    record = trained.record
    with pytest.raises(ConfigError, match="status 'failed'"):
        entry_from_record({**record, "status": "failed"})
    with pytest.raises(ConfigError, match="has no weights"):
        entry_from_record({k: v for k, v in record.items() if k != "weights"})
    quick = {**record, "config": {**record["config"], "subset": {"train": 64}}}
    with pytest.raises(ConfigError, match="trained on a subset.*not publishable"):
        entry_from_record(quick)


def _entry(**changes: Any) -> dict[str, Any]:
    base = {"tag": "sgnet.source_sim_evtouch", "model": "sgnet", "dataset": "sim_evtouch", "sha256": "ab" * 32,
            "file": "w.safetensors", "spec": {"name": "sim_evtouch", "num_classes": 2, "class_names": ["a", "b"],
                                              "num_steps": 5, "num_nodes": 39, "num_channels": 2, "num_globals": 0,
                                              "sensor": "neutouch"}}
    return {k: v for k, v in {**base, **changes}.items() if v is not ...}


@pytest.mark.parametrize(("document", "message"), [
    ({"format": "other/1", "weights": []}, "format must be 'tactile-zoo-weights/1'"),
    ({"format": MANIFEST_FORMAT, "weights": {}}, "'weights' must be a list"),
    ({"format": MANIFEST_FORMAT, "weights": [], "extra": 1}, r"unknown top-level key\(s\) \['extra'\]"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(acuracy=0.5)]},
     r"entry 0 \('sgnet.source_sim_evtouch'\): unknown key\(s\) \['acuracy'\]"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(sha256=...)]}, "entry 0 .*missing sha256"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(sha256="xyz")]}, "sha256 must be 64 hexadecimal digits"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(file=...)]}, "give file .*, url .*, or both"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(file=None, url="ftp://host/w")]}, "url must be an http"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(tag="dcnn.source_sim_evtouch")]},
     "tag must read <model>.<name> with the entry's model 'sgnet'"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(spec={"name": "x"})]}, "spec lacks num_classes"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(accuracy="high")]}, "accuracy must be a number"),
    ({"format": MANIFEST_FORMAT, "weights": [_entry(), _entry(tag="SGnet.source_sim_evtouch")]},
     "tag 'SGnet.source_sim_evtouch' appears twice"),
])
def test_a_malformed_manifest_is_one_clear_error(document: dict[str, Any], message: str, tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    path.write_text(json.dumps(document))
    with pytest.raises(ConfigError, match=rf"weights manifest {path}: .*{message}|weights manifest {path}: {message}"):
        read_manifest(path)


def test_manifest_files_that_are_not_json_name_themselves(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        read_manifest(tmp_path / "absent.json")
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(ConfigError, match=r"broken.json is not valid JSON"):
        read_manifest(tmp_path / "broken.json")


def test_a_bare_list_is_a_manifest_and_entries_compare_on_content(tmp_path: Path) -> None:
    (one,) = parse_manifest([_entry()], "inline", base_dir=tmp_path)
    assert one.local_path() == tmp_path / "w.safetensors" and one.sha256 == "ab" * 32
    assert one.preprocessing == {}  # a manifest written before entries described their preprocessing
    assert one == dataclasses.replace(one, origin="elsewhere")  # where it was read is not part of the weights
    assert WeightEntry.from_dict(one.to_dict()) == one
