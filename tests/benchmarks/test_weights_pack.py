"""``tools.weights_pack``'s selection rules, on made-up cell records (no weights are read): which cell gives a
model x dataset its weights, when a rerun may stand in for a Table I cell, and why a pair has none."""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tools import weights_pack  # noqa: E402

HASH = "0123456789abcdef"


def _record(model: str = "cnn_lstm", dataset: str = "biotac_dos", *, fold: int = 0, seed: int = 0,
            config_hash: str = HASH, weights: bool = True, **config: Any) -> dict[str, Any]:
    cell_id = f"{model}__{dataset}__f{fold}__s{seed}__{config_hash}"
    record = {"cell_id": cell_id, "model": model, "dataset": dataset, "fold": fold, "seed": seed,
              "config_hash": config_hash, "status": "ok", "epochs_run": 1, "best_epoch": 1, "train_seconds": 1.0,
              "config": {"recipe_name": weights_pack.default_recipe(model), "evaluation": "validation",
                         "subset": None, "model_revision": 1, "dataset_revision": 1, **config},
              "metrics": {"test": {"accuracy": 0.5}},
              "predictions": {"test": {"targets": [0, 1, 2, 3], "predictions": [0, 1, 1, 2]}}}
    if weights:
        record["weights"] = {"file": f"weights/{cell_id}.safetensors", "sha256": "ab" * 32, "bytes": 10}
    return record


def _folder(root: Path, *records: dict[str, Any]) -> Path:
    (root / "cells").mkdir(parents=True)
    for record in records:
        (root / "cells" / f"{record['cell_id']}.json").write_text(json.dumps(record))
    return root


def _slot(slots: list[weights_pack.Slot], model: str = "cnn_lstm", dataset: str = "biotac_dos") -> weights_pack.Slot:
    (slot,) = [s for s in slots if (s.model, s.dataset) == (model, dataset)]
    return slot


def test_the_seed0_fold0_default_recipe_cell_with_weights_is_chosen(tmp_path: Path) -> None:
    table = _folder(tmp_path / "table", _record(), _record(fold=1), _record(seed=1),
                    _record("convlstm", weights=False))
    slots = weights_pack.select(table=table)
    chosen = _slot(slots).source
    assert chosen is not None and chosen.cell is chosen.saved and chosen.cell["cell_id"].endswith(f"f0__s0__{HASH}")
    assert chosen.file == table / "weights" / f"cnn_lstm__biotac_dos__f0__s0__{HASH}.safetensors"
    convlstm = _slot(slots, "convlstm")
    assert convlstm.source is None and "was run without --save-weights" in convlstm.reason
    assert "no seed-0 fold-0 cell" in _slot(slots, "sgnet").reason
    assert len(slots) == len(weights_pack.MODELS) * len(weights_pack.DATASETS)


def test_each_model_reads_the_table_of_its_default_recipe(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    zoo_cell = _record(recipe_name="zoo", config_hash="fedcba9876543210")
    zoo = _folder(tmp_path / "zoo", zoo_cell, _record("dcnn", "ev_objects", recipe_name="zoo"))
    source = _folder(tmp_path / "source", *(_record(*pair, recipe_name="source") for pair in (
        ("cnn_lstm", "biotac_dos"), ("convlstm", "biotac_dos"), ("dcnn", "ev_objects"))))
    monkeypatch.setattr(weights_pack, "TABLES", {"source": source, "zoo": zoo})
    defaults = {"cnn_lstm": "zoo", "dcnn": "zoo"}
    monkeypatch.setattr(weights_pack, "default_recipe", lambda model: defaults.get(model, "source"))
    slots = weights_pack.select()
    chosen = _slot(slots).source
    assert chosen is not None and chosen.cell == zoo_cell and chosen.table == zoo and chosen.run_dir == zoo
    other = _slot(slots, "convlstm").source
    assert other is not None and other.table == source
    # D-CNN's zoo cell has weights, but its file was not kept and the cell cannot be rerun on this CPU type
    declined = _slot(slots, "dcnn", "ev_objects")
    assert declined.source is None and "a rerun here trains other weights" in declined.reason
    defaults["convlstm"] = "fast"
    assert "default recipe 'fast' has no Table I folder" in _slot(weights_pack.select(), "convlstm").reason


@pytest.mark.parametrize(("change", "reason"), [
    ({"status": "failed"}, "status failed"),
    ({"config": {"recipe_name": "fast"}}, "recipe 'fast', not the default 'full'"),
    ({"config": {"evaluation": "reference"}}, "evaluation 'reference'"),
    ({"config": {"subset": {"train": 64}}}, "ran on a subset"),
    ({"config": {"model_revision": 0}}, "stale: model revision 0, now 1"),
])
def test_a_cell_that_cannot_be_the_cell_of_record_says_why(tmp_path: Path, change: dict[str, Any],
                                                           reason: str) -> None:
    record = _record()
    for key, value in change.items():
        record[key] = {**record[key], **value} if isinstance(value, dict) else value
    slot = _slot(weights_pack.select(table=_folder(tmp_path / "table", record)))
    assert slot.source is None and f"{record['cell_id']}: {reason}" in slot.reason


def test_two_configurations_of_one_pair_are_an_error(tmp_path: Path) -> None:
    table = _folder(tmp_path / "table", _record(), _record(config_hash="fedcba9876543210"))
    slot = _slot(weights_pack.select(table=table))
    assert slot.source is None and slot.reason.startswith("several configurations (0123456789abcdef, "
                                                          "fedcba9876543210)")


def test_a_rerun_gives_its_weights_only_when_it_reproduces_the_cell(tmp_path: Path) -> None:
    cell = _record(weights=False)
    table = _folder(tmp_path / "table", cell)
    same = _folder(tmp_path / "weights-same", _record())
    chosen = _slot(weights_pack.select([same], table)).source
    assert chosen is not None and chosen.run_dir == same and chosen.cell == cell and "weights" in chosen.saved

    other = _record()
    other["predictions"]["test"]["predictions"][3] = 3  # one sample differs, the accuracy too
    other["metrics"]["test"]["accuracy"] = 0.75
    slot = _slot(weights_pack.select([_folder(tmp_path / "weights-other", other)], table))
    assert slot.source is None and "is refused: test accuracy 0.75, the Table I cell's is 0.5" in slot.reason


@pytest.mark.parametrize(("change", "reason"), [
    (lambda r: r.update(config_hash="fedcba9876543210"), "config hash fedcba9876543210, the Table I cell's is"),
    (lambda r: r["metrics"]["test"].update(accuracy=0.25), "test accuracy 0.25, the Table I cell's is 0.5"),
    (lambda r: r["predictions"]["test"]["predictions"].reverse(), "test predictions differ from the Table I cell's "
                                                                  "(2 of 4 samples)"),
    (lambda r: r["predictions"]["test"].update(targets=[3, 2, 1, 0]), "test targets differ"),
    (lambda r: r.update(status="failed"), "status failed"),
])
def test_reproduction_is_exact(change: Any, reason: str) -> None:
    cell, rerun = _record(weights=False), _record()
    assert weights_pack.reproduces(rerun, cell) is None
    changed = copy.deepcopy(rerun)
    change(changed)
    assert reason in weights_pack.reproduces(changed, cell)


def test_notes_say_what_users_must_know() -> None:
    ev = weights_pack.planned_entry(weights_pack.Source(_record("x_tacformer", "ev_objects"), _record(
        "x_tacformer", "ev_objects") | {"spec": _spec("ev_objects", 250, 39, 2, 36)}, Path("."), Path(".")))
    assert ev.note.startswith("Ev-Objects class names are unverified") and ev.file == f"{ev.tag}.safetensors"
    # as the full recipe declares it on BioTac-DoS (another evaluation would be tagged custom)
    record = _record(dataset_kwargs={"window": 10}, evaluation="final") | {"spec": _spec("biotac_dos", 10, 24, 1, 7)}
    biotac = weights_pack.planned_entry(weights_pack.Source(record, record, Path("."), Path(".")))
    assert "windows of 10 BioTac SP readings at 100 Hz, each electrode as (baseline - reading) / 1000" in biotac.note
    assert biotac.tag == "cnn_lstm.full_biotac_dos" and biotac.preprocessing["frame_period_s"] == 0.01


def _spec(name: str, steps: int, nodes: int, channels: int, classes: int) -> dict[str, Any]:
    return {"name": name, "num_classes": classes, "class_names": [f"c{i}" for i in range(classes)],
            "num_steps": steps, "num_nodes": nodes, "num_channels": channels, "num_globals": 0,
            "sensor": "neutouch" if name.startswith("ev") else "biotac_sp"}
