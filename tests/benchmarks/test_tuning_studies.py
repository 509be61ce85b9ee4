"""The tuning trials and DeepTactile's round as studies (``benchmarks/studies/tuning-*.yaml``,
``deeptactile-*.yaml``): each audits as its notes say against its committed cells, and ``study report`` computes the
outcome each plan's rule decided; the schedule trial's table and verdicts as appended to its plan (what
``tools/schedule_trial.py`` computed). The validation reads' semantics on synthetic records: the rule reads epoch N,
not the best epoch; a missing seed leaves the read waiting; a bound of exactly two recordings is met."""

from __future__ import annotations

import csv
import re
import statistics
from pathlib import Path
from typing import Any

import pytest

from tactile_zoo.errors import ConfigError
from tactile_zoo.study import audit, load_study, write_report
from tactile_zoo.study.checks import plans
from tactile_zoo.study.reads import decision_outcome, threshold_outcome
from tactile_zoo.study.tuning import validation_value

STUDIES = Path(__file__).resolve().parents[2] / "benchmarks" / "studies"
#: the migrated ones carry the freeze read from their plan's history (`freeze:`); a study planned as a file
#: (deeptactile-r5.yaml) is frozen by `study freeze` instead, and audited by test_studies.py
MIGRATED = sorted(p for p in [*STUDIES.glob("tuning-*.yaml"), *STUDIES.glob("deeptactile-*.yaml")]
                  if re.search(r"^freeze:", p.read_text(), re.MULTILINE))
#: what the audit finds in a migrated study, kept as found and explained in its notes (each one failure line)
FINDINGS = {
    "tuning-convlstm-ev": "grid trial2: cell convlstm__ev_containers__f0__s1__9ab6db06188b88bd: started "
                          "2026-12-02T04:40:23+0000, before the freeze (2026-12-02T04:42:40+0000)",
    "tuning-zoo-ev": "cells on 2 CPU types (AMD EPYC (?); Intel(R) Xeon(R) Processor (?)); a study runs on one",
}
#: the schedule trial's outcome as appended to its plan (benchmarks/results/tuning/full-schedule/PLAN.md):
#: (model, dataset) -> registered mean, scaled mean, gain, the validation accuracy at epoch N over seeds 0-2
SCHEDULE = {("sgnet", "ev_objects"): (0.8827, 0.8642, -0.0185), ("sgnet", "ev_containers"): (0.6000, 0.6000, 0.0),
            ("tacformer", "ev_objects"): (0.9074, 0.9105, 0.0031),
            ("tacformer", "ev_containers"): (0.6500, 0.6250, -0.0250),
            ("x_tacformer", "ev_objects"): (0.9259, 0.9198, -0.0062),
            ("x_tacformer", "ev_containers"): (0.6583, 0.6417, -0.0167)}
SHORT = {"ev_objects": "objects", "ev_containers": "containers"}


def test_every_tuning_trial_and_deeptactile_is_a_study() -> None:
    names = {p.stem for p in MIGRATED}
    assert names >= {"tuning-full-schedule", "tuning-full-ema", "tuning-full-ema99", "tuning-zoo-ev",
                     "tuning-zoo-biotac", "tuning-convlstm-ev", "tuning-biotac-window", "deeptactile-r4"}, names


@pytest.mark.parametrize("path", MIGRATED, ids=[p.stem for p in MIGRATED])
def test_a_migrated_study_audits_as_its_notes_say(path: Path, cells_checked_once: None) -> None:
    study = load_study(path)
    result = audit(study)
    expected = [FINDINGS[path.stem]] if path.stem in FINDINGS else []
    assert result.failures == expected
    if expected:  # an audit finding is stated in the study's notes, not left for a reader to find
        assert "What the audit finds" in study.spec.notes
    assert study.spec.freeze is not None and study.spec.freeze.commit
    if path.stem.startswith("tuning-"):
        assert study.rules().test_split == "never"
    assert all(": 0 ok cell(s)" not in line for line in result.lines), result.lines


def test_the_report_computes_the_schedule_trials_outcome(tmp_path: Path, cells_checked_once: None) -> None:
    """The numbers ``tools/schedule_trial.py`` appended to the plan: each arm's mean validation accuracy at epoch N
    over seeds 0-2, the gains, and no scaled schedule adopted."""
    study = load_study(STUDIES / "tuning-full-schedule.yaml")
    paths = write_report(study, tmp_path)
    rows = {row["name"]: row for row in csv.DictReader(paths["reads"].open())}
    for (model, dataset), (registered, scaled, gain) in SCHEDULE.items():
        read = rows[f"{model}-{SHORT[dataset]}"]
        assert read["score"] == "final" and read["runs"] == "3"
        assert float(read["against_mean"]) == pytest.approx(registered, abs=5e-5)
        assert float(read["mean"]) == pytest.approx(scaled, abs=5e-5)
        assert float(read["value"]) == pytest.approx(gain, abs=5e-5)
        threshold = rows[f"{model}-{SHORT[dataset]}-gain"]
        assert threshold["met"] == "False" and threshold["bound"] == f">= {0.019 if dataset == 'ev_objects' else 0.05}"
    for model in ("sgnet", "tacformer", "x_tacformer"):
        assert rows[f"adopt-{model}"]["met"] == "False"
        assert rows[f"adopt-{model}"]["decision"] == f"{model} keeps its registered schedule"
    report = paths["report"].read_text()
    assert "1.402 CPU-hours over 36 cell(s)" in report and "test split: held" in report


# ------------------------------------------------------------------------------------------ synthetic records
def _cell(plan: Any, model: str, dataset: str, seed: int, final: float, best: float = 0.99, fold: int = 0,
          epochs: int | None = None) -> dict[str, Any]:
    """An ok tuning cell of ``plan`` whose validation accuracy is ``final`` at its last epoch and ``best`` at epoch 1
    (what it selected): a read of the wrong epoch gets other numbers."""
    n = plan.configs[model, dataset].recipe.max_epochs
    curve = [{"epoch": e, "val_accuracy": best if e == 1 else 0.5} for e in range(1, (epochs or n))]
    curve.append({"epoch": epochs or n, "val_accuracy": final})
    digest = plan.hashes[model, dataset]
    return {"cell_id": f"{model}__{dataset}__f{fold}__s{seed}__{digest}", "model": model, "dataset": dataset,
            "fold": fold, "seed": seed, "config_hash": digest, "status": "ok", "best_epoch": 1,
            "metrics": {"val": {"accuracy": best}}, "curve": curve,
            "config": {"recipe": {"max_epochs": n}, "evaluation": "tuning"}}


@pytest.fixture(scope="module")
def schedule() -> Any:
    return load_study(STUDIES / "tuning-full-schedule.yaml")


def _arms(study: Any, registered: list[float], scaled: list[float], **changes: Any) -> dict[str, dict[str, Any]]:
    out = {}
    for arm, finals in (("registered-containers", registered), ("scaled-containers", scaled)):
        plan = plans(study)[arm]
        for seed, final in enumerate(finals):
            cell = _cell(plan, "sgnet", "ev_containers", seed, final, **changes)
            out[cell["cell_id"]] = cell
    return out


def _read(study: Any, name: str) -> Any:
    return next(r for r in study.reads().validation if r.name == name)


def test_the_rule_reads_epoch_n_not_the_selected_epoch(schedule: Any) -> None:
    records = _arms(schedule, [0.6, 0.6, 0.6], [0.7, 0.6, 0.65])
    value, ids, missing = validation_value(schedule, _read(schedule, "sgnet-containers"), records)
    assert not missing and len(ids) == 6
    assert value["mean"] == pytest.approx(0.65) and value["against_mean"] == pytest.approx(0.6)
    assert value["difference"] == pytest.approx(0.05) and (value["improved"], value["pairs"]) == (2, 3)
    epochs = plans(schedule)["scaled-containers"].configs["sgnet", "ev_containers"].recipe.max_epochs
    short = _arms(schedule, [0.6, 0.6, 0.6], [0.7, 0.6, 0.65], epochs=epochs - 1)  # stopped before epoch N
    value, _, _ = validation_value(schedule, _read(schedule, "sgnet-containers"), short)
    assert f"no validation accuracy at epoch {epochs}" in value["unreadable"]


def test_a_missing_seed_leaves_the_read_waiting(schedule: Any) -> None:
    records = _arms(schedule, [0.6, 0.6, 0.6], [0.7, 0.6, 0.65])
    del records[next(i for i in records if "__s2__" in i and i.endswith(plans(schedule)["scaled-containers"]
                                                                          .hashes["sgnet", "ev_containers"]))]
    value, _, missing = validation_value(schedule, _read(schedule, "sgnet-containers"), records)
    assert value is None and missing == ["grid scaled-containers: sgnet on ev_containers, seed 2"]


def test_a_gain_of_exactly_the_bound_is_met_and_a_decision_needs_every_threshold(schedule: Any) -> None:
    """0.05 is two of 40 recordings; the means' difference lands a rounding error below it."""
    registered, scaled = [0.575, 0.575, 0.6], [0.575, 0.6, 0.725]
    assert statistics.fmean(scaled) - statistics.fmean(registered) < 0.05
    value, _, _ = validation_value(schedule, _read(schedule, "sgnet-containers"), _arms(schedule, registered,
                                                                                           scaled))
    thresholds = {t.name: t for t in schedule.reads().thresholds}
    containers = threshold_outcome(thresholds["sgnet-containers-gain"], value)
    assert containers is not None and containers["met"] is True
    decision = next(d for d in schedule.reads().decisions if d.name == "adopt-sgnet")
    objects = threshold_outcome(thresholds["sgnet-objects-gain"], {"difference": 0.0185})
    assert decision_outcome(decision, {"sgnet-objects-gain": objects, "sgnet-containers-gain": None}) is None
    outcome = decision_outcome(decision, {"sgnet-objects-gain": objects, "sgnet-containers-gain": containers})
    assert outcome is not None and outcome["met"] is False  # Ev-Objects missed by 0.0005
    assert outcome["thresholds"] == {"sgnet-objects-gain": False, "sgnet-containers-gain": True}


# --------------------------------------------------------------------------------------------- the file's checks
_MISSING = """\
study: missing-folder
question: Does the audit notice a grid whose folder is not there?
freeze: {time: "2026-12-01T00:00:00+00:00"}
results: results
grids:
  - name: main
    folder: not-there
    settings: {models: cnn_lstm, datasets: sim_evtouch, quick: true, epochs: 1}
"""


def test_a_grid_whose_folder_is_missing_or_empty_fails_the_audit(tmp_path: Path) -> None:
    """A misspelt folder finds no cell: every rule holds over nothing, so the audit must say so."""
    path = tmp_path / "study.yaml"
    path.write_text(_MISSING)
    result = audit(load_study(path))
    assert any("grid main" in f and "not-there" in f and "does not exist" in f for f in result.failures), \
        result.failures
    (tmp_path / "results" / "not-there").mkdir(parents=True)
    result = audit(load_study(path))
    assert any("grid main" in f and "holds no cell" in f for f in result.failures), result.failures


_ARMS = """\
study: arms
question: Do two arms share a folder?
results: results
rules: {test_split: never}
grids:
  - {name: a, folder: trial, settings: {models: cnn_lstm, datasets: sim_evtouch, quick: true, epochs: 1,
                                        evaluation: tuning}}
  - {name: b, folder: trial, settings: {models: cnn_lstm, datasets: sim_evtouch, quick: true, epochs: EPOCHS,
                                        evaluation: tuning}}
reads:
  validation: [{name: gain, grid: b, dataset: sim_evtouch, model: cnn_lstm, against: AGAINST}]
  thresholds: [{name: up, read: gain, statistic: STATISTIC, at_least: 0.1, decision: {met: adopt, missed: keep}}]
  decisions: [{name: adopt, all_of: [ALL_OF], decision: {met: adopt, missed: keep}}]
"""


@pytest.mark.parametrize(("changes", "message"), [
    ({"EPOCHS": "1"}, "grids a and b share the folder"),
    ({"AGAINST": "{grid: b}"}, "reads.validation.gain.against is the read's own arm"),
    ({"AGAINST": "null"}, "reads.thresholds.up.statistic 'difference': a validation read gives mean, median"),
    ({"ALL_OF": "gain"}, "reads.decisions.adopt.all_of: 'gain' names no declared threshold (up)"),
], ids=["same-configuration", "own-arm", "difference-without-against", "decision-of-a-read"])
def test_a_bad_tuning_study_is_refused_naming_the_key(tmp_path: Path, changes: dict[str, str], message: str) -> None:
    text = _ARMS
    for key, value in {"EPOCHS": "2", "AGAINST": "{grid: a}", "STATISTIC": "difference", "ALL_OF": "up",
                       **changes}.items():
        text = text.replace(key, value)
    path = tmp_path / "arms.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="arms.yaml: ") as raised:
        load_study(path)
    assert message in str(raised.value)
    good = _ARMS.replace("EPOCHS", "2").replace("AGAINST", "{grid: a}").replace("STATISTIC", "difference")
    path.write_text(good.replace("ALL_OF", "up"))
    assert [g.name for g in load_study(path).grids()] == ["a", "b"]  # the arms may share their folder
