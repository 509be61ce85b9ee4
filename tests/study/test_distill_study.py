"""Distillation as a study (what benchmarks/studies/distill-tuning-r5.yaml does, on the tiny zoo): a teachers' grid
that saves its weights, a students' grid taught by it through a folder relative to the results, validation reads
in tuning mode, then the audit and the report."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import tiny_zoo
from study_helpers import tz

from tactile_zoo.bench.records import cell_files, read_record

_GRID = """\
      models: [tiny_mlp]
      datasets: tiny_blobs
      evaluation: tuning
      recipe: {max_epochs: 3, patience: null%s}
      seeds: %s
      threads: 1
"""
_STUDY = f"""\
study: distil
question: Does a tiny student taught by two seeds score higher on validation than its teachers?
results: results
rules: {{test_split: never, budget_cpu_hours: 0.1}}
grids:
  - name: teachers
    settings:
{_GRID % ("", "[5, 6]")}      save_weights: true
  - name: students
    settings:
{_GRID % (", distill_weight: 0.5, distill_temperature: 2.0", "[0, 1]")}\
      teachers: {{folder: teachers, seeds: [5, 6]}}
reads:
  validation:
    - {{name: taught, grid: students, dataset: tiny_blobs, model: tiny_mlp, score: final, against: {{grid: teachers}}}}
  thresholds:
    - {{name: gain, read: taught, statistic: difference, at_least: 0.0,
       decision: {{met: "students at least as good", missed: "students worse"}}}}
"""


@pytest.fixture(autouse=True)
def _tiny() -> Iterator[None]:
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()


def test_a_distillation_study_runs_teachers_first_then_students_and_audits_clean(tmp_path: Path) -> None:
    study = tmp_path / "distil.yaml"
    study.write_text(_STUDY)
    assert tz("study", "check", str(study), "--history", str(tmp_path / "none"))[0] == 0
    code, _, err = tz("study", "run", str(study), "-q")
    assert code == 0, err
    teachers = {r["cell_id"]: r for r in map(read_record, cell_files(tmp_path / "results" / "teachers"))}
    students = list(map(read_record, cell_files(tmp_path / "results" / "students")))
    assert len(teachers) == 2 and len(students) == 2
    for record in students:
        assert record["test_reads"] == 0 and record["config"]["evaluation"] == "tuning"
        assert {t["cell"] for t in record["teachers"]} == set(teachers)
        assert all(teachers[t["cell"]]["weights"]["sha256"] == t["sha256"] for t in record["teachers"])
    code, out, err = tz("study", "audit", str(study))
    assert code == 0 and "every rule held" in out, out + err
    code, _, err = tz("study", "report", str(study))
    assert code == 0, err
    reads = json.loads((tmp_path / "results" / "study" / "reads.json").read_text())
    taught = reads["reads"]["taught"]
    assert taught["value"]["pairs"] == 0 and taught["value"]["runs"] == 2  # seeds 0-1 against 5-6: nothing pairs
    assert len(taught["inputs"]) == 4  # the students' and the teachers' cells, each read
