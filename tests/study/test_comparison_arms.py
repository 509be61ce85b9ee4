"""A comparison whose sides are arms across grids (a previous revision's seeds, in the two folders that ran them):
its value is the paired bootstrap over the arms' cells, its inputs name each cell's grid, the audit follows them into
their folders, and a wrong grid, model or seed is one error naming the key. The cells are committed ones (Table I's
`full` rounds 3 and 4 on Ev-Objects), copied into the test's folder: nothing is trained."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from tactile_zoo.bench import records
from tactile_zoo.bench.paired import records_paired
from tactile_zoo.errors import ConfigError
from tactile_zoo.study import audit, load_study, write_report
from tactile_zoo.study.freeze import freeze
from tactile_zoo.study.reads import recorded_reads, threshold_outcome
from tactile_zoo.study.schema import Threshold

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
#: the committed folder of each round and the seeds the test copies from it
ROUNDS = {"r3": ("paper-table1-full", (0, 1)), "r4": ("paper-table1-full-r4", (5, 6))}
HASHES = {"sgnet": "921b4365023e30a7", "dcnn": "ad5073877cee023c"}  # `full`, revision 2 / 1, on Ev-Objects

_STUDY = """\
study: cross
question: Is D-CNN better than SGnet over both rounds' seeds?
pre_registered: false
results: results
grids:
  - {name: r3, reused: round 3, settings: {models: [sgnet, dcnn], datasets: ev_objects, recipe_name: full,
                                           folds: 1, model_revisions: {sgnet: 2, dcnn: 1}, seeds: [0, 1]}}
  - {name: r4, reused: round 4, settings: {models: [sgnet, dcnn], datasets: ev_objects, recipe_name: full,
                                           folds: 1, model_revisions: {sgnet: 2, dcnn: 1}, seeds: [5, 6]}}
  - {name: rerun, folder: rerun, reused: round 4 again, settings: {models: [sgnet], datasets: ev_objects,
                                           recipe_name: full, folds: 1, model_revisions: {sgnet: 2}, seeds: [5, 6]}}
reads:
  comparisons:
    - {name: cross, dataset: ev_objects, a: ARM_A, b: ARM_B}
  thresholds:
    - {name: drop, read: cross, statistic: high, below: 0, decision: {met: back, missed: stays}}
"""
ARMS_A = "[{grid: r3, model: sgnet}, {grid: r4, model: sgnet, seeds: [5, 6]}]"
ARMS_B = "[{grid: r3, model: dcnn}, {grid: r4, model: dcnn}]"


def _id(model: str, seed: int) -> str:
    return f"{model}__ev_objects__f0__s{seed}__{HASHES[model]}"


def _committed(model: str, seed: int) -> dict[str, Any]:
    folder, _ = next(v for v in ROUNDS.values() if seed in v[1])
    record = records.read_record(records.cell_file(RESULTS / folder / "cells", _id(model, seed)))
    assert isinstance(record, dict)
    return record


def _write(tmp_path: Path, a: str = ARMS_A, b: str = ARMS_B) -> Path:
    """The study file in ``tmp_path`` and the committed cells of its grids copied beside it; the rerun grid holds
    SGnet's round-4 cells under their own ids, every test sample predicted right (another run of one configuration)."""
    for grid, (folder, seeds) in ROUNDS.items():
        (tmp_path / "results" / grid / "cells").mkdir(parents=True, exist_ok=True)
        for model in HASHES:
            for seed in seeds:
                source = records.cell_file(RESULTS / folder / "cells", _id(model, seed))
                shutil.copy(source, tmp_path / "results" / grid / "cells" / source.name)
    (tmp_path / "results" / "rerun" / "cells").mkdir(parents=True)
    for seed in (5, 6):
        record = _committed("sgnet", seed)
        record["predictions"]["test"]["predictions"] = list(record["predictions"]["test"]["targets"])
        (tmp_path / "results" / "rerun" / "cells" / f"{_id('sgnet', seed)}.json").write_text(json.dumps(record))
    path = tmp_path / "cross.yaml"
    path.write_text(_STUDY.replace("ARM_A", a).replace("ARM_B", b))
    return path


def test_a_comparison_across_grids_is_the_paired_bootstrap_of_its_arms_cells(tmp_path: Path) -> None:
    study = load_study(_write(tmp_path))
    write_report(study, tmp_path / "report")
    entry = recorded_reads(study)["cross"]
    by_hand = records_paired([_committed("sgnet", s) for s in (0, 1, 5, 6)],
                             [_committed("dcnn", s) for s in (0, 1, 5, 6)], "test")
    assert entry["value"] == {"difference": by_hand.difference, "low": by_hand.low, "high": by_hand.high,
                              "p_value": by_hand.p_value, "pairs": 4}
    assert entry["inputs"] == [f"{grid}/{_id(model, seed)}" for model in ("sgnet", "dcnn")
                               for grid, (_, seeds) in ROUNDS.items() for seed in seeds]
    assert set(entry["digests"]) == set(entry["inputs"])
    outcome = recorded_reads(study)["drop"]["outcome"]
    assert outcome["statistic"] == "high" and outcome["met"] is (by_hand.high < 0)
    assert audit(study).failures == []
    cell = records.cell_file(tmp_path / "results" / "r4" / "cells", _id("dcnn", 6))  # edited after its read
    record = json.loads(records.read_cell_bytes(cell))
    cell.write_bytes(gzip.compress(json.dumps({**record, "seconds": 1.0}).encode()))
    assert audit(study).failures == [f"comparison cross: input r4/{_id('dcnn', 6)} changed after the read was "
                                     f"recorded"]


def test_a_cell_id_in_two_grids_is_read_from_the_arms_own_grid(tmp_path: Path) -> None:
    """The rerun grid holds SGnet's round-4 cell ids too (same configuration, another run): each side reads its
    own grid's file, and the recorded inputs say which."""
    path = _write(tmp_path, a="[{grid: r4, model: sgnet}]", b="[{grid: rerun, model: sgnet}]")
    study = load_study(path)
    report = write_report(study, tmp_path / "report")
    rerun = [json.loads((tmp_path / "results" / "rerun" / "cells" / f"{_id('sgnet', s)}.json").read_text())
             for s in (5, 6)]
    by_hand = records_paired([_committed("sgnet", s) for s in (5, 6)], rerun, "test")
    entry = recorded_reads(study)["cross"]
    assert by_hand.difference > 0 and entry["value"]["difference"] == by_hand.difference
    assert entry["inputs"] == [f"{grid}/{_id('sgnet', s)}" for grid in ("r4", "rerun") for s in (5, 6)]
    assert audit(study).failures == [] and "cross | comparison | difference" in report["report"].read_text()


def test_the_single_grid_form_reads_and_records_as_before(tmp_path: Path) -> None:
    path = _write(tmp_path, a="sgnet", b="dcnn")
    path.write_text(path.read_text().replace("name: cross,", "name: cross, grid: r4,"))
    study = load_study(path)
    write_report(study, tmp_path / "report")
    entry = recorded_reads(study)["cross"]
    by_hand = records_paired([_committed("sgnet", s) for s in (5, 6)], [_committed("dcnn", s) for s in (5, 6)])
    assert entry["value"]["difference"] == by_hand.difference and entry["value"]["pairs"] == 2
    assert entry["inputs"] == [_id(model, s) for model in ("sgnet", "dcnn") for s in (5, 6)]  # plain ids


def test_an_amendment_may_change_a_comparison_until_the_studys_own_cells_exist(tmp_path: Path) -> None:
    """The reused grids' cells exist before the study runs any: only the study's own (here the rerun grid, made the
    study's) decide whether a comparison across grids has been read."""
    path = _write(tmp_path, a=ARMS_A, b="[{grid: rerun, model: sgnet}]")
    text = path.read_text().replace("reused: round 4 again, ", "")
    shutil.move(tmp_path / "results" / "rerun", tmp_path / "later")
    path.write_text(text)
    freeze(load_study(path))
    amendment = ("  - reason: seed {seed} only\n    reads: {{comparisons: [{{name: cross, dataset: ev_objects, b: "
                 "[{{grid: rerun, model: sgnet}}], a: [{{grid: r4, model: sgnet, seeds: [{seed}]}}]}}]}}\n")
    path.write_text(text + "amendments:\n" + amendment.format(seed=6))
    freeze(load_study(path))  # no cell of the study's own yet: the read may change
    shutil.move(tmp_path / "later", tmp_path / "results" / "rerun")
    path.write_text(text + "amendments:\n" + amendment.format(seed=6) + amendment.format(seed=5))
    with pytest.raises(ConfigError, match=r"reads.comparisons.cross: its grids already hold cells \(rerun\)"):
        freeze(load_study(path))


@pytest.mark.parametrize(("a", "b", "message"), [
    ("[{grid: r3, model: sgnet}, {grid: r5, model: sgnet}]", ARMS_B,
     "reads.comparisons.cross.a[1].grid 'r5' names no grid of the study (r3, r4, rerun)"),
    ("[{grid: r3, model: sgnet}, {grid: r4, model: tacformer}]", ARMS_B,
     "reads.comparisons.cross.a[1]: model 'tacformer' is not a model of grid r4"),
    ("[{grid: r3, model: sgnet}, {grid: r4, model: sgnet, seeds: [0, 5]}]", ARMS_B,
     "reads.comparisons.cross.a[1].seeds [0] are not seeds of grid r4"),
    (ARMS_A, "[{grid: r3, model: dcnn}, {grid: rerun, model: dcnn}]",
     "reads.comparisons.cross.b[1]: model 'dcnn' is not a model of grid rerun"),
    ("[{model: sgnet}]", ARMS_B, "reads.comparisons.cross.a[0].grid is required: the study has 3 grids"),
    ("[{grid: r4, model: sgnet}, {grid: rerun, model: sgnet, seeds: [6]}]", ARMS_B,
     "reads.comparisons.cross.a[1]: seed 6 is also selected by reads.comparisons.cross.a[0]"),
    ("[{grid: r4, model: dcnn, seeds: [6]}]", ARMS_B,
     f"reads.comparisons.cross: a and b both select the cell {_id('dcnn', 6)} (grid r4)"),
    ("[{grid: r3}]", ARMS_B, "reads.comparisons[0].a[0].model is required"),
    ("[{grid: r3, model: sgnet, seed: [0]}]", ARMS_B, "reads.comparisons[0].a[0].seed is not a known key"),
    ("3", ARMS_B, "reads.comparisons[0].a must be a model's name or a list of arms"),
], ids=["grid", "model", "seed", "model-of-b", "no-grid", "seed-twice", "same-cell", "no-model", "key", "type"])
def test_a_wrong_arm_is_one_error_naming_its_key(tmp_path: Path, a: str, b: str, message: str) -> None:
    path = _write(tmp_path, a=a, b=b)
    with pytest.raises(ConfigError) as raised:
        load_study(path)
    assert str(raised.value).startswith(f"{path}: ") and message in str(raised.value), raised.value


@pytest.mark.parametrize(("high", "met"), [(-0.001, True), (0.0, False), (0.02, False)])
def test_an_interval_entirely_below_zero_is_a_measured_drop(high: float, met: bool) -> None:
    threshold = Threshold.model_validate({"name": "drop", "read": "cross", "statistic": "high", "below": 0.0,
                                          "decision": {"met": "back", "missed": "stays"}})
    outcome = threshold_outcome(threshold, {"difference": -0.02, "low": -0.04, "high": high, "p_value": 0.9})
    assert outcome is not None and outcome["met"] is met and outcome["bound"] == "< 0"


def test_a_report_reads_each_cell_file_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The reads, the audit and the summary of ``write_report`` share one reading of the study's cells: the committed
    results' cell files hold every test prediction, and decoding them twice was a report's time twice."""
    study = load_study(_write(tmp_path))
    seen: list[Path] = []
    real = records.read_record
    monkeypatch.setattr(records, "read_record", lambda path: seen.append(Path(path)) or real(path))
    write_report(study, tmp_path / "report")
    assert len(seen) == 10 and len(set(seen)) == 10, sorted(seen)  # r3 and r4: 4 each, the rerun grid's 2


def test_the_published_tables_read_each_cell_file_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The page blocks count, pool and read the same folders over and over: their context reads each folder once."""
    from tactile_zoo.study.publish import Context, index_block

    study = load_study(_write(tmp_path))
    seen: list[Path] = []
    real = records.read_record
    monkeypatch.setattr(records, "read_record", lambda path: seen.append(Path(path)) or real(path))
    ctx = Context(studies={study.name: study}, repo=tmp_path)
    assert len(ctx.cells(study)) == 10 and ctx.left_out(study) == 0
    assert "cross" in ctx.reads(study)
    assert "/r3/` (4, reused)" in index_block(ctx)
    assert ctx.records(tmp_path / "results" / "r3") is ctx.records(tmp_path / "results" / "r3" / ".." / "r3")
    assert len(seen) == 10 and len(set(seen)) == 10, sorted(seen)
