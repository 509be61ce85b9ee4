"""Tuning mode: reading a test split raises, and ``--evaluation tuning`` cells train and select without one."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.data.guard import TUNING_ENV, in_tuning_mode, tuning
from tactile_zoo.engine.cell import train_cell
from tactile_zoo.engine.config import resolve_cell
from tactile_zoo.errors import TestSplitForbidden


@pytest.mark.parametrize("split", ["test", None])
def test_the_guard_refuses_every_split_that_holds_test_samples(split: str | None) -> None:
    assert not in_tuning_mode()
    with tuning():
        assert in_tuning_mode()
        assert len(tz.load_dataset("tiny_blobs", split="train")) and len(tz.load_dataset("tiny_blobs", split="val"))
        with pytest.raises(TestSplitForbidden, match="tiny_blobs: .* cannot be read in tuning mode"):
            tz.load_dataset("tiny_blobs", split=split)
    assert not in_tuning_mode() and len(tz.load_dataset("tiny_blobs", split=split))  # the guard ends with the block


def test_the_environment_puts_a_whole_process_in_tuning_mode(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TUNING_ENV, "1")
    with pytest.raises(TestSplitForbidden):
        tz.load_dataset("tiny_blobs", split="test")


def test_a_tuning_cell_selects_like_a_validation_cell_and_reads_no_test() -> None:
    honest = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 5})
    tune = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 5}, evaluation="tuning")
    a, b = train_cell(honest, seed=0, measure=False), train_cell(tune, seed=0, measure=False)
    assert b.tests == {} and b.fit.test is None and b.n_test == 0 and b.test_reads == 0 and a.test_reads == 1
    # the same training and the same selection: tuning only leaves the test split out
    assert b.fit.best_epoch == a.fit.best_epoch and b.fit.val.metrics == a.fit.val.metrics
    assert train_cell(resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 3}, evaluation="reference"),
                      seed=0, measure=False).test_reads == 3  # one evaluation per epoch


def test_bench_tuning_records_validation_only_and_reports_the_trials(tmp_path: Path) -> None:
    out = tmp_path / "tune"
    assert main(["bench", "--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0,1", "--evaluation",
                 "tuning", "--epochs", "3", "--hparam", "hidden=8", "--out", str(out), "--no-plots", "-q"]) == 0
    cells = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    assert len(cells) == 2 and all(c["status"] == "ok" for c in cells)
    for cell in cells:
        assert cell["test_reads"] == 0 and cell["predictions"] == {} and set(cell["metrics"]) == {"val"}
    board = list(csv.DictReader((out / "leaderboard.csv").open()))
    assert [row["accuracy"] for row in board] == ["", ""]  # no test figure exists
    assert [float(row["val_accuracy"]) for row in board] == [c["metrics"]["val"]["accuracy"] for c in cells]
    report = (out / "report.md").read_text()
    assert "## Tuning trials (--evaluation tuning)" in report and "default: hidden=8" in report
    assert f"`{cells[0]['config_hash']}`" in report
