"""Planted violations: each fails ``study run`` or ``study audit``, naming it. Each test edits a copy of the shared
quickstart run (cell records rewritten through the records writer, which validates them)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from study_helpers import QuickstartRun, tz

from tactile_zoo.bench.records import run_records
from tactile_zoo.bench.rundir import RunDir

pytestmark = pytest.mark.xdist_group("quickstart_study")  # with test_quickstart.py: the quickstart study runs once


def _edit_cell(study: Path, change: Callable[[dict[str, Any]], None], model: str = "cnn_lstm", seed: int = 1
               ) -> dict[str, Any]:
    folder = study.parent / "quickstart-results" / "main"
    record = next(r for r in run_records(folder) if r["model"] == model and r["seed"] == seed)
    change(record)
    RunDir(folder).write_cell(record)
    return record


def _audit(study: Path) -> str:
    code, out, err = tz("study", "audit", str(study))
    assert code == 1, out + err
    return out


def test_the_grid_edited_after_cells_exist_is_refused_by_run(quickstart: QuickstartRun, tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    study.write_text(study.read_text().replace("epochs: 1", "epochs: 2"))
    code, out, _ = tz("study", "check", str(study), "--history", str(tmp_path / "none"))
    assert code == 0 and "changed since: grids.main.settings.epochs: 1 -> 2 (`study run` will refuse it)" in out
    code, _, err = tz("study", "run", str(study), "-q")
    assert code == 2
    assert "changed after cells exist" in err and "grids.main.settings.epochs: 1 -> 2" in err


def test_an_amendment_may_add_a_read_but_not_change_one_already_read(quickstart: QuickstartRun,
                                                                    tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    added = ("amendments:\n  - reason: a mean of D-CNN too\n    reads:\n      means:\n"
             "        - {name: dcnn_mean, dataset: sim_evtouch, model: dcnn}\n")
    study.write_text(study.read_text() + added)
    code, _, err = tz("study", "run", str(study), "-q")
    assert code == 0, err
    changed = ("  - reason: one member only\n    reads:\n      ensembles:\n        - {name: cnn_lstm_ens2, "
               "dataset: sim_evtouch, members: [{model: cnn_lstm, seeds: [0]}]}\n")
    study.write_text(study.read_text() + changed)
    code, _, err = tz("study", "run", str(study), "-q")
    assert code == 2
    assert "amendments[1] changes what already has inputs: reads.ensembles.cnn_lstm_ens2: already read" in err


@pytest.mark.parametrize(("plant", "named"), [
    (lambda r: r.update(test_reads=2), "a final cell that read its test split 2 time(s), not once"),
    (lambda r: (r["config"].update(evaluation="tuning"), r.update(test_reads=1)),
     "a tuning cell that read its test split 1 time(s), not never"),
    (lambda r: r.update(cpu="Intel Xeon"), "cells on 2 CPU types"),
    (lambda r: r.update(started="2020-01-01T00:00:00+0000"), "started 2020-01-01T00:00:00+0000, before the freeze"),
    (lambda r: r.update(config_hash="0123456789abcdef"), "config hash 0123456789abcdef is not the grid's"),
    (lambda r: r.update(seconds=3600.0), "budget exceeded: 1."),
], ids=["test-read-twice", "tuning-cell-read-test", "two-cpu-types", "before-freeze", "config-hash", "budget"])
def test_a_planted_cell_violation_fails_the_audit(quickstart: QuickstartRun, tmp_path: Path,
                                                  plant: Callable[[dict[str, Any]], Any], named: str) -> None:
    study = quickstart.copy(tmp_path)
    record = _edit_cell(study, plant)
    out = _audit(study)
    assert named in out, out
    if "budget" in named:  # and no further cell runs
        code, _, err = tz("study", "run", str(study), "-q")
        assert code == 2 and "budget exceeded" in err
    else:
        assert record["cell_id"] in out


def test_an_ensemble_member_that_was_not_declared_fails_the_audit(quickstart: QuickstartRun, tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    reads = study.parent / "quickstart-results" / "study" / "reads.json"
    data = json.loads(reads.read_text())
    dcnn = next(r["cell_id"] for r in run_records(study.parent / "quickstart-results" / "main")
                if r["model"] == "dcnn")
    data["reads"]["cnn_lstm_ens2"]["inputs"].append(dcnn)
    reads.write_text(json.dumps(data))
    assert f"ensemble cnn_lstm_ens2: member {dcnn} was not declared" in _audit(study)


def test_a_declared_member_missing_fails_the_audit(quickstart: QuickstartRun, tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    folder = study.parent / "quickstart-results" / "main"
    member = next(r["cell_id"] for r in run_records(folder) if r["model"] == "cnn_lstm")
    RunDir(folder).cell_path(member).unlink()
    assert f"ensemble cnn_lstm_ens2: declared member(s) not present: {member}" in _audit(study)


def test_a_rule_edited_after_the_run_fails_the_audit(quickstart: QuickstartRun, tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    study.write_text(study.read_text().replace("budget_cpu_hours: 0.1", "budget_cpu_hours: 5"))
    assert "not the file that was frozen" in (out := _audit(study)) and "rules.budget_cpu_hours: 0.1 -> 5" in out


def test_a_migrated_study_is_audited_against_the_freeze_in_its_file(quickstart: QuickstartRun,
                                                                   tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    study.write_text(study.read_text() + "freeze: {time: 2030-01-01T00:00:00+0000, source: PLAN.md's first commit}\n")
    assert _audit(study).count("before the freeze (2030-01-01T00:00:00+0000)") == 4


def test_a_study_not_pre_registered_says_so_and_skips_the_freeze(quickstart: QuickstartRun, tmp_path: Path) -> None:
    study = quickstart.copy(tmp_path)
    _edit_cell(study, lambda r: r.update(started="2020-01-01T00:00:00+0000"), model="dcnn")  # not an ensemble's
    extra = ("pre_registered: false\npublishes: [{where: docs/mine.md, block: quickstart, reads: [cnn_lstm_ens2]}]\n"
             "compares_with:\n  - name: a_paper\n    source: Someone et al. 2030, Table 2\n"
             "    figures: [{model: dcnn, dataset: sim_evtouch, value: 0.99}]\n")
    study.write_text(study.read_text() + extra)
    code, out, err = tz("study", "audit", str(study))
    assert code == 0 and "not pre-registered" in out, out + err
    assert tz("study", "report", str(study))[0] == 0
    report = (study.parent / "quickstart-results" / "study" / "report.md").read_text()
    assert "**Not pre-registered**" in report and "- docs/mine.md, block `quickstart`: cnn_lstm_ens2" in report
    assert "**a_paper** (Someone et al. 2030, Table 2)" in report and "| dcnn | sim_evtouch | 0.9900 |" in report
    assert "| above |" in report
