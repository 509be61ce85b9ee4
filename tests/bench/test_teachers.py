"""Distillation in the harness (``tactile_zoo.bench.teachers``): a students' grid finds its teachers' cells and
weights in the folder its ``teachers`` setting names, checks them before anything runs, and records what it used."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest
import tiny_zoo

from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.records import read_record
from tactile_zoo.bench.runner import run_bench
from tactile_zoo.engine.config import CellConfig, config_hash
from tactile_zoo.engine.distill import teacher_config
from tactile_zoo.errors import ConfigError
from tactile_zoo.study.plan import bench_config
from tactile_zoo.study.schema import parse_study

GRID = {"models": ["tiny_mlp"], "datasets": ["tiny_kfold"], "folds": 2, "threads": 1, "evaluation": "final",
        "recipe": {"max_epochs": 2}}
STUDENT = {**GRID, "seeds": [0], "recipe": {"max_epochs": 2, "distill_weight": 0.5, "distill_temperature": 2.0}}


def _records(folder: Path) -> dict[str, dict]:
    return {r["cell_id"]: r for r in (read_record(p) for p in sorted((folder / "cells").glob("*.json*")))}


@pytest.fixture(scope="module")
def teachers(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("distil") / "teachers"
    tiny_zoo.register()  # a module fixture is set up before the per-test registration (conftest.tiny)
    outcome = run_bench(BenchConfig(**GRID, seeds=[0, 1], save_weights=True, out=str(out)), quiet=True, plots=False)
    assert outcome.exit_code == 0 and len(outcome.ran) == 4  # 2 folds x 2 seeds
    return out


def test_students_learn_from_their_own_folds_teachers_and_record_them(teachers: Path, tmp_path: Path) -> None:
    out = tmp_path / "students"
    config = BenchConfig(**STUDENT, teachers={"folder": str(teachers), "seeds": [1, 0]}, out=str(out))
    assert run_bench(config, quiet=True, plots=False).exit_code == 0
    taught = _records(teachers)
    students = _records(out)
    assert len(students) == 2
    for record in students.values():
        assert record["status"] == "ok" and record["config"]["teachers"] == [0, 1]
        used = record["teachers"]
        assert [t["cell"].split("__")[2:4] for t in used] == [[f"f{record['fold']}", "s0"],
                                                              [f"f{record['fold']}", "s1"]]
        plain = config_hash(teacher_config(CellConfig.from_dict(record["config"])))
        for teacher in used:  # the weights it learnt from are the ones each teacher's record states
            assert taught[teacher["cell"]]["weights"]["sha256"] == teacher["sha256"]
            assert taught[teacher["cell"]]["config_hash"] == plain  # its own configuration, distillation off
    # a second run finds the finished students and runs nothing
    again = run_bench(BenchConfig(**STUDENT, teachers={"folder": str(teachers), "seeds": [0, 1]}, out=str(out)),
                      quiet=True, plots=False)
    assert again.ran == [] and len(again.reused) == 2


def test_a_missing_teacher_stops_the_run_before_anything_is_written(teachers: Path, tmp_path: Path) -> None:
    out = tmp_path / "students"
    config = BenchConfig(**STUDENT, teachers={"folder": str(teachers), "seeds": [0, 7]}, out=str(out))
    with pytest.raises(ConfigError, match=r"2 teacher cell\(s\).*f0__s7__.*no cell in .*run the teachers first"):
        run_bench(config, quiet=True, plots=False)
    assert not out.exists()


def test_changed_or_unsaved_teacher_weights_are_refused(teachers: Path, tmp_path: Path) -> None:
    import shutil

    copy = tmp_path / "teachers"
    shutil.copytree(teachers, copy)
    (weights,) = [p for p in (copy / "weights").glob("*f1__s1__*.safetensors")]
    data = bytearray(weights.read_bytes())
    data[-1] ^= 1  # one bit of one tensor
    weights.write_bytes(bytes(data))
    config = BenchConfig(**STUDENT, teachers={"folder": str(copy), "seeds": [0, 1]}, out=str(tmp_path / "s"))
    with pytest.raises(ConfigError, match=r"f1__s1__.*not the ones its record states \(sha256 differs\)"):
        run_bench(config, quiet=True, plots=False)
    (cell,) = [p for p in (copy / "cells").glob("*f0__s0__*")]
    record = json.loads(gzip.decompress(cell.read_bytes()) if cell.suffix == ".gz" else cell.read_text())
    del record["weights"]
    cell.write_text(json.dumps(record))
    with pytest.raises(ConfigError, match=r"f0__s0__.*holds no weights \(run the teachers with save_weights"):
        run_bench(config, quiet=True, plots=False)


def test_a_study_reads_a_relative_teachers_folder_under_its_results(tmp_path: Path) -> None:
    path = tmp_path / "distil.yaml"
    path.write_text(json.dumps({
        "study": "distil", "question": "q?", "results": "out",
        "grids": [{"name": "teachers", "settings": {**GRID, "seeds": [0, 1], "save_weights": True}},
                  {"name": "students", "settings": {**STUDENT, "teachers": {"folder": "teachers", "seeds": [0, 1]}}}],
        "rules": {"test_split": "once"}}))
    study = parse_study(path)
    students = next(g for g in study.grids() if g.name == "students")
    assert Path(bench_config(study, students).teachers["folder"]) == study.results / "teachers"
