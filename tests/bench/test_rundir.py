from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tactile_zoo.bench import rundir
from tactile_zoo.bench.rundir import RunDir, atomic_write_json
from tactile_zoo.bench.tables import LEADERBOARD_COLUMNS, SUMMARY_COLUMNS, leaderboard_rows, rows_to_csv, summary_rows
from tactile_zoo.errors import ConfigError


def test_atomic_write_keeps_the_old_file_when_the_write_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                             ) -> None:
    path = tmp_path / "cell.json"
    atomic_write_json(path, {"v": 1})

    def full(*args: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rundir.os, "replace", full)
    with pytest.raises(OSError, match="No space"):
        atomic_write_json(path, {"v": 2})
    assert json.loads(path.read_text()) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["cell.json"]  # no temporary file left behind


def test_unwritable_out_is_a_config_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="--out .*cannot write there"):
        RunDir(blocker / "run").prepare()


def test_claims_are_exclusive_and_released(tmp_path: Path) -> None:
    run = RunDir(tmp_path).prepare()
    first = run.claim("cell-a")
    assert first is not None
    assert run.claim("cell-a") is None  # another open file description: flock says no
    assert f"pid {os.getpid()}" in run.claim_holder("cell-a")
    assert run.claim("cell-b") is not None
    first.release()
    again = run.claim("cell-a")
    assert again is not None
    again.release()


def test_a_claim_dies_with_its_process(tmp_path: Path) -> None:
    run = RunDir(tmp_path).prepare()
    # the child takes the claim the way RunDir.claim does (flock + "pid host time"), without importing torch
    code = ("import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
            "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, f'{os.getpid()} host 00:00:00'.encode()); "
            "print('held', flush=True); time.sleep(60)")
    lock = tmp_path / "claims" / "cell-x.lock"
    child = subprocess.Popen([sys.executable, "-c", code, str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "held"
        assert run.claim("cell-x") is None
        assert f"pid {child.pid}" in run.claim_holder("cell-x")
        child.kill()
        child.wait()
        deadline = time.time() + 10
        claim = None
        while claim is None and time.time() < deadline:
            claim = run.claim("cell-x")
        assert claim is not None  # the kernel dropped the dead holder's lock: never a stale claim
    finally:
        child.kill()


def _record(model: str, dataset: str, seed: int, acc: float, status: str = "ok", extra: dict | None = None) -> dict:
    metrics = {"test": {"accuracy": acc, "balanced_accuracy": acc, "macro_f1": acc}}
    metrics.update(extra or {})
    return {"cell_id": f"{model}-{dataset}-{seed}", "model": model, "dataset": dataset, "fold": 0, "seed": seed,
            "status": status, "metrics": metrics if status == "ok" else {}, "train_seconds": 1.0,
            "prefix": {"fractions": [0.5, 1.0], "accuracy": [acc / 2, acc], "earliness": 1.0}
            if status == "ok" else None, "versions": {"tactile_zoo": "0.1.0", "torch": "2"},
            "error": None if status == "ok" else "boom"}


def test_leaderboard_columns_are_the_issue_list_then_extras() -> None:
    recs = [_record("a", "d1", 0, 0.5, extra={"test_solids": {"accuracy": 0.25}}), _record("b", "d1", 0, 0.0,
                                                                                            "failed")]
    rows, cols = leaderboard_rows(recs, [{"model": "a", "dataset": "d2", "status": "skipped", "reason": "absent",
                                          "obtain": "tactile-zoo download d2"}])
    assert tuple(cols[:len(LEADERBOARD_COLUMNS)]) == LEADERBOARD_COLUMNS
    assert cols[len(LEADERBOARD_COLUMNS):] == ["accuracy_test_solids", "accuracy_at_50", "accuracy_at_100",
                                               "earliness"]
    assert [(r["model"], r["dataset"], r["status"]) for r in rows] == [("a", "d1", "ok"), ("a", "d2", "skipped"),
                                                                       ("b", "d1", "failed")]
    assert rows[1]["error"] == "absent. To obtain it: tactile-zoo download d2"
    assert rows[0]["accuracy_test_solids"] == 0.25 and rows[0]["accuracy_at_50"] == 0.25
    text = rows_to_csv(rows, cols)
    assert text.splitlines()[0] == ",".join(cols) and "0.5" in text.splitlines()[1]


def test_summary_means_std_ranks_and_mean_rank() -> None:
    recs = [_record("a", "d1", 0, 0.8), _record("a", "d1", 1, 0.6), _record("b", "d1", 0, 0.9),
            _record("a", "d2", 0, 0.5), _record("b", "d2", 0, 0.5), _record("c", "d2", 0, 0.2),
            _record("c", "d1", 0, 0.0, "failed")]
    board, cols = leaderboard_rows(recs)
    summary, scols = summary_rows(board, cols)
    assert tuple(scols[:len(SUMMARY_COLUMNS)]) == SUMMARY_COLUMNS
    assert {"accuracy_at_50_mean", "earliness_mean"} <= set(scols)
    by = {(s["model"], s["dataset"]): s for s in summary}
    assert by[("a", "d1")]["n_cells"] == 2 and by[("a", "d1")]["accuracy_mean"] == pytest.approx(0.7)
    assert by[("a", "d1")]["accuracy_std"] == pytest.approx(0.1414213, rel=1e-5)  # sample std (n - 1)
    assert by[("b", "d1")]["accuracy_std"] is None  # a single cell has no spread
    assert (by[("b", "d1")]["rank"], by[("a", "d1")]["rank"]) == (1, 2)
    assert (by[("a", "d2")]["rank"], by[("b", "d2")]["rank"], by[("c", "d2")]["rank"]) == (1, 1, 3)  # ties share
    assert by[("a", "d1")]["mean_rank"] == 1.5 and by[("b", "d2")]["mean_rank"] == 1.0
    assert by[("c", "d2")]["mean_rank"] == 3.0 and ("c", "d1") not in by  # failed cells are not averaged


def test_two_recipes_of_one_model_are_two_summary_rows_never_one_average() -> None:
    def named(record: dict, recipe: str) -> dict:
        return {**record, "config": {"recipe_name": recipe}}

    recs = [named(_record("a", "d1", 0, 0.6), "source"), named(_record("a", "d1", 1, 0.8), "source"),
            named(_record("a", "d1", 0, 0.9), "zoo"), named(_record("b", "d1", 0, 0.7), "source")]
    summary, _ = summary_rows(*leaderboard_rows(recs))
    by = {(s["model"], s["recipe"]): s for s in summary}
    assert set(by) == {("a", "source"), ("a", "zoo"), ("b", "source")}
    assert by[("a", "source")]["accuracy_mean"] == pytest.approx(0.7) and by[("a", "source")]["n_cells"] == 2
    assert by[("a", "zoo")]["accuracy_mean"] == 0.9 and by[("a", "zoo")]["n_cells"] == 1
    # ranked as separate entries: a's zoo first, b and a's source tie at 0.7
    assert (by[("a", "zoo")]["rank"], by[("b", "source")]["rank"], by[("a", "source")]["rank"]) == (1, 2, 2)


def test_means_are_summed_left_to_right_as_the_committed_tables_were() -> None:
    """pandas' own mean (pairwise / Kahan summation) would give 0.1 here; the tables keep the plain left-to-right sum
    their committed numbers were computed with, and write it exactly."""
    board, cols = leaderboard_rows([_record("a", "d1", seed, 0.1) for seed in range(10)])
    summary, scols = summary_rows(board, cols)
    assert summary[0]["accuracy_mean"] == sum([0.1] * 10) / 10 == 0.09999999999999999
    assert type(summary[0]["accuracy_mean"]) is float and type(summary[0]["rank"]) is int  # no numpy scalars
    assert ",0.09999999999999999," in rows_to_csv(summary, scols)
    assert [r["seed"] for r in board] == list(range(10))


def test_the_table_names_have_one_home_in_tables() -> None:
    from tactile_zoo.bench import tables

    for name in ("LEADERBOARD_COLUMNS", "SUMMARY_COLUMNS", "TIMING_COLUMNS", "leaderboard_rows", "summary_rows",
                 "rows_to_csv", "prefix_label"):
        assert name in tables.__all__ and not hasattr(rundir, name), name  # no re-export for an older layout


def test_cell_json_is_one_line_per_key_and_round_trips(tmp_path: Path) -> None:
    from tactile_zoo.bench.rundir import atomic_write_json

    record = {"cell_id": "m__d__f0__s0__abc", "metrics": {"test": {"accuracy": 0.5, "loss": None}},
              "predictions": {"test": {"targets": list(range(1000)), "probabilities": [[0.25, 0.75]] * 1000}}}
    path = tmp_path / "cell.json"
    atomic_write_json(path, record)
    text = path.read_text()
    assert len(text.splitlines()) == len(record) + 2  # braces + one line per key, however long the lists
    back = json.loads(text)
    assert back["predictions"] == record["predictions"] and back["metrics"]["test"]["loss"] is None
    # JSON has no NaN: the writer refuses one (issue 38; a record writes a number that is not one as null)
    with pytest.raises(ValueError, match="not JSON compliant"):
        atomic_write_json(path, {**record, "metrics": {"test": {"accuracy": float("nan")}}})
    assert json.loads(path.read_text()) == back  # the file is as it was
    assert '"cell_id": "m__d__f0__s0__abc"' in text
