"""``examples/studies/quickstart.yaml`` through check, run, audit and report, and a rerun that resumes."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from study_helpers import QuickstartRun, tz

from tactile_zoo.bench.records import run_records

pytestmark = pytest.mark.xdist_group("quickstart_study")  # one worker runs the package's quickstart study once


def test_check_lists_the_cells_and_says_when_there_is_nothing_to_estimate_from(quickstart: QuickstartRun) -> None:
    code, out, err = quickstart.check
    assert code == 0, err
    assert "4 cells: 2 model(s) x 1 dataset(s)" in out
    assert out.count("    cell ") == 4
    assert "no earlier cell of this model, dataset and recipe: no estimate" in out
    assert "declared ensembles: cnn_lstm_ens2" in out
    assert "freeze: not frozen yet" in out


def test_run_freezes_before_the_first_cell_and_runs_the_grid(quickstart: QuickstartRun) -> None:
    code, _, err = quickstart.run
    assert code == 0, err
    frozen = quickstart.folder / "quickstart-results" / "study"
    assert (frozen / "study.yaml").read_text() == quickstart.file.read_text()
    state = json.loads((frozen / "freeze.json").read_text())
    records = run_records(quickstart.folder / "quickstart-results" / "main")
    assert len(records) == 4 and all(r["status"] == "ok" for r in records)
    assert all(r["started"] >= state["time"] for r in records)


def test_audit_finds_every_rule_held(quickstart: QuickstartRun) -> None:
    code, out, err = quickstart.audit
    assert code == 0, out + err
    assert "every rule held" in out


def test_report_records_the_declared_reads_once(quickstart: QuickstartRun, tmp_path: Path) -> None:
    code, out, err = quickstart.report
    assert code == 0, err
    folder = quickstart.folder / "quickstart-results" / "study"
    report = (folder / "report.md").read_text()
    for text in ("Pre-registered: frozen", "accuracy [95 % interval]", "acc. at 50 %", "earliness",
                 "cnn_lstm_ens2", "dcnn_vs_cnn_lstm", "ensemble_above_chance", "- budget: held", "CPU-hours"):
        assert text in report, text
    rows = {r["name"]: r for r in csv.DictReader((folder / "reads.csv").open())}
    assert rows["ensemble_above_chance"]["met"] in ("True", "False") and rows["ensemble_above_chance"]["decision"]
    summary = list(csv.DictReader((folder / "summary.csv").open()))
    assert {r["model"] for r in summary} == {"cnn_lstm", "dcnn"}
    assert all(float(r["accuracy_low"]) <= float(r["accuracy_mean"]) <= float(r["accuracy_high"]) for r in summary)
    recorded = json.loads((folder / "reads.json").read_text())["reads"]
    assert recorded["cnn_lstm_ens2"]["inputs"] == [
        r["cell_id"] for r in sorted(run_records(quickstart.folder / "quickstart-results" / "main"),
                                     key=lambda r: r["seed"]) if r["model"] == "cnn_lstm"]
    # a recorded read is read back, never computed again: a planted value survives the next report
    study = quickstart.copy(tmp_path)
    folder = study.parent / "quickstart-results" / "study"
    recorded["cnn_lstm_ens2"]["value"]["accuracy"] = 0.123456
    (folder / "reads.json").write_text(json.dumps({"study": "quickstart", "reads": recorded}))
    assert tz("study", "report", str(study))[0] == 0
    assert "accuracy 0.1235 [" in (folder / "report.md").read_text()


def test_a_second_run_resumes_and_computes_nothing(quickstart: QuickstartRun, tmp_path: Path) -> None:
    code, out, err = tz("study", "run", str(quickstart.copy(tmp_path)))
    assert code == 0, err
    assert "4 already finished, 0 to run" in out + err
