"""A study planned for one CPU type, run on another: an amendment, before the study's own first cell, changes its
rules and re-declares the reused grids of the other type superseded (what ``benchmarks/studies/table1-r5.yaml``
did); what has inputs stays fixed. Also ``study run --grid`` and a grid whose folder is the results folder itself.
The reused cells are committed ones (Table I's `full` rounds 3 and 4, AMD EPYC with AVX-512): nothing is trained."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from study_helpers import tz

from tactile_zoo.bench import records
from tactile_zoo.bench.rundir import RunDir
from tactile_zoo.errors import ConfigError
from tactile_zoo.study import audit, load_study
from tactile_zoo.study import run as study_run
from tactile_zoo.study.checks import plans
from tactile_zoo.study.freeze import freeze

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
SGNET = "sgnet__ev_objects__f0__s{seed}__921b4365023e30a7"  # `full` at revision 2 on Ev-Objects

_STUDY = """\
study: moved
question: Does SGnet's new revision drop against the old one?
results: results
grids:
  - {name: new, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, folds: 1, seeds: [0, 5]}}
  - {name: r3, reused: round 3, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, folds: 1,
                                           model_revisions: {sgnet: 2}, seeds: [0]}}
  - {name: r4, reused: round 4, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, folds: 1,
                                           model_revisions: {sgnet: 2}, seeds: [5]}}
rules: {cpu: AMD EPYC (AVX512), budget_cpu_hours: 1.0}
reads:
  comparisons:
    - {name: drop, dataset: ev_objects, a: [{grid: r3, model: sgnet}, {grid: r4, model: sgnet}],
       b: [{grid: new, model: sgnet}]}
"""
#: the amendment table1-r5 needed: the rule of this machine's type, the old arm rerun here, the old cells superseded
_MOVE = """\
amendments:
  - reason: this machine is another CPU type
    rules: {cpu: AMD EPYC (AVX2), budget_cpu_hours: 2.0}
    grids:
      - {name: old, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, folds: 1,
                               model_revisions: {sgnet: 2}, seeds: [0, 5]}}
      - {name: r3, superseded: another CPU type, reused: round 3, settings: {models: [sgnet], datasets: ev_objects,
                                recipe_name: full, folds: 1, model_revisions: {sgnet: 2}, seeds: [0]}}
      - {name: r4, superseded: another CPU type, reused: round 4, settings: {models: [sgnet], datasets: ev_objects,
                                recipe_name: full, folds: 1, model_revisions: {sgnet: 2}, seeds: [5]}}
    reads:
      comparisons:
        - {name: drop, dataset: ev_objects, a: [{grid: old, model: sgnet}], b: [{grid: new, model: sgnet}]}
"""


def _committed(seed: int) -> dict[str, Any]:
    folder = "paper-table1-full" if seed < 5 else "paper-table1-full-r4"
    record = records.read_record(records.cell_file(RESULTS / folder / "cells", SGNET.format(seed=seed)))
    assert isinstance(record, dict)
    return record


def _study(tmp_path: Path, amendment: str = "") -> Path:
    for grid, seed in (("r3", 0), ("r4", 5)):
        (tmp_path / "results" / grid / "cells").mkdir(parents=True, exist_ok=True)
        cell = tmp_path / "results" / grid / "cells" / f"{SGNET.format(seed=seed)}.json"
        cell.write_text(json.dumps(_committed(seed)))
    path = tmp_path / "moved.yaml"
    path.write_text(_STUDY + amendment)
    return path


def _plant_own_cell(tmp_path: Path) -> None:
    """A cell of the study's own grid `new`: one of this machine's type (its record relabelled AVX2)."""
    study = load_study(tmp_path / "moved.yaml")
    cell_id = plans(study)["new"].cell_ids()[0]
    record = {**_committed(0), "cell_id": cell_id, "cpu_isa": {"capability": "AVX2", "flags": ["avx", "avx2"]}}
    (tmp_path / "results" / "new" / "cells").mkdir(parents=True)
    (tmp_path / "results" / "new" / "cells" / f"{cell_id}.json").write_text(json.dumps(record))


@pytest.fixture(autouse=True)
def _needs_committed_cells() -> None:
    if not (RESULTS / "paper-table1-full" / "cells").is_dir():
        pytest.skip("the committed Table I cells are not in this checkout")


def test_the_move_is_accepted_before_the_studys_own_first_cell(tmp_path: Path) -> None:
    path = _study(tmp_path)
    freeze(load_study(path))
    record = tmp_path / "results" / "study" / "freeze.json"  # planned a day before the amendment
    record.write_text(json.dumps({**json.loads(record.read_text()), "time": "2026-01-01T00:00:00+0000"}))
    path.write_text(path.read_text() + _MOVE)
    state = freeze(load_study(path))  # the reused grids hold cells, the study's own none: not "cells exist"
    assert [a["reason"] for a in state["amendments"]] == ["this machine is another CPU type"]
    study = load_study(path)
    assert study.rules().cpu == "AMD EPYC (AVX2)" and study.rules().budget_cpu_hours == 2.0
    assert [g.name for g in study.grids() if g.superseded] == ["r3", "r4"]
    result = audit(study)
    assert result.failures == [], result.failures
    lines = "\n".join(result.lines)  # each grid waits since its own freeze: `old` since the amendment's
    assert f"grid old: not run yet (frozen {state['amendments'][0]['time']})" in lines, lines
    assert f"grid new: not run yet (frozen {state['time']})" in lines, lines


def test_a_reused_grid_of_another_type_left_in_fails_the_audit(tmp_path: Path) -> None:
    """Why the move supersedes r3 and r4: the rule holds every cell the study reads to its type."""
    path = _study(tmp_path)
    freeze(load_study(path))
    without = _MOVE.split("      - {name: r3")[0] + "    reads:" + _MOVE.split("    reads:")[1]
    path.write_text(path.read_text() + without)
    study = load_study(path)
    freeze(study)
    failures = audit(study).failures
    assert failures == ["cells on AMD EPYC (AVX512); rules.cpu declares AMD EPYC (AVX2)"], failures


def test_once_the_study_has_a_cell_of_its_own_the_rules_are_fixed(tmp_path: Path) -> None:
    path = _study(tmp_path)
    freeze(load_study(path))
    _plant_own_cell(tmp_path)
    path.write_text(path.read_text() + "amendments:\n  - reason: another type\n    rules: {cpu: AMD EPYC (AVX2)}\n")
    with pytest.raises(ConfigError, match=r"rules.cpu: 'AMD EPYC \(AVX512\)' -> 'AMD EPYC \(AVX2\)', but cells "
                                          r"already exist"):
        freeze(load_study(path))


@pytest.mark.parametrize("grid, change, why", [
    ("new", "superseded: gone, ", "grids.new: its folder already holds cells"),  # the study's own: never
    ("r3", "superseded: gone, ", "grids.r3: its folder already holds cells"),  # and its seeds changed
])
def test_only_a_reused_grid_unchanged_but_superseded_may_be_redeclared(tmp_path: Path, grid: str, change: str,
                                                                       why: str) -> None:
    path = _study(tmp_path)
    freeze(load_study(path))
    _plant_own_cell(tmp_path)
    spec = {"new": "{name: new, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, folds: 1, "
                   "seeds: [0, 5]}}",
            "r3": "{name: r3, reused: round 3, settings: {models: [sgnet], datasets: ev_objects, recipe_name: full, "
                  "folds: 1, model_revisions: {sgnet: 2}, seeds: [0, 1]}}"}[grid]
    path.write_text(path.read_text() + "amendments:\n  - reason: r\n    grids:\n      - "
                    + spec.replace("{name: " + grid + ", ", "{name: " + grid + ", " + change) + "\n")
    with pytest.raises(ConfigError, match=why):
        freeze(load_study(path))


def test_a_reused_grid_a_recorded_read_took_stays(tmp_path: Path) -> None:
    path = _study(tmp_path)
    freeze(load_study(path))
    (tmp_path / "results" / "study" / "reads.json").write_text(json.dumps({"study": "moved", "reads": {"drop": {
        "kind": "comparison", "inputs": [f"r3/{SGNET.format(seed=0)}", f"new/{SGNET.format(seed=0)}"]}}}))
    path.write_text(path.read_text() + _MOVE)
    with pytest.raises(ConfigError, match="grids.r3: a recorded read took its cells, so it cannot be superseded"):
        freeze(load_study(path))


def test_study_run_grid_runs_the_named_grids_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _study(tmp_path, _MOVE)
    ran: list[str] = []

    def fake_bench(config: Any, **_: Any) -> Any:
        ran.append(Path(config.out).name)
        return type("Result", (), {"counts": {}, "exit_code": 0})()

    monkeypatch.setattr(study_run, "run_bench", fake_bench)
    assert study_run.run_study(load_study(path), grids=["old"]).exit_code == 0
    assert ran == ["old"]
    ran.clear()
    study_run.run_study(load_study(path))
    assert ran == ["new", "old"]  # every grid not superseded, in the file's order


def test_study_run_grid_refuses_a_name_before_any_work(tmp_path: Path) -> None:
    path = _study(tmp_path, _MOVE)
    code, _, err = tz("study", "run", str(path), "--grid", "old", "--grid", "olds")
    assert code == 2 and "--grid olds: not a grid of" in err and "(its grids: new, r3, r4, old)" in err, err
    assert not (tmp_path / "results" / "study").exists()  # not even the freeze
    code, _, err = tz("study", "audit", str(path), "--grid", "old")
    assert code == 2 and "--grid: only `study run` takes it, not `study audit`" in err, err


def test_a_grid_in_the_results_folder_itself_starts_beside_the_freeze(tmp_path: Path) -> None:
    """``folder: .`` puts a grid's cells beside the study's records (study/), which the freeze writes first."""
    (tmp_path / "study").mkdir()
    (tmp_path / "study" / "freeze.json").write_text("{}")
    (tmp_path / "README.md").write_text("the plan\n")
    RunDir(tmp_path).prepare()
    assert (tmp_path / "run.json").is_file() and (tmp_path / "cells").is_dir()
    (tmp_path / "notes.txt").write_text("someone else's\n")
    other = tmp_path / "other"
    shutil.copytree(tmp_path, other, ignore=shutil.ignore_patterns("run.json", "cells", "claims", "progress"))
    with pytest.raises(ConfigError, match="holds other files"):
        RunDir(other).prepare()


def test_check_leaves_reused_grids_out_of_the_estimate(tmp_path: Path) -> None:
    """A reused grid's cells were run by another study: ``study check`` does not count them in this one's cost."""
    path = tmp_path / "sim.yaml"
    path.write_text("study: sim\nquestion: q\nresults: results\ngrids:\n"
                    "  - {name: own, settings: {models: [cnn_lstm], datasets: sim_evtouch, quick: true, seeds: [0]}}\n"
                    "  - {name: earlier, reused: r, settings: {models: [dcnn], datasets: sim_evtouch, quick: true, "
                    "seeds: [0, 1]}}\n")
    code, out, err = tz("study", "check", str(path), "--history", str(tmp_path))
    assert code == 0, err
    assert "reused grid(s) earlier: their cells are read, not run (not in the estimate)" in out
    rows = [line for line in out.splitlines() if " cell(s): " in line]
    assert [row.split(":")[0].strip() for row in rows] == ["own"], rows
