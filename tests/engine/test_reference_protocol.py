"""``--evaluation reference``: the sources' protocol, kept apart from the honest one, and the shared bootstrap."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from tactile_zoo.bench.intervals import bootstrap_accuracy, records_interval
from tactile_zoo.cli import main
from tactile_zoo.engine.cell import train_cell
from tactile_zoo.engine.config import config_hash, resolve_cell
from tactile_zoo.errors import ConfigError


def test_reference_trains_on_everything_for_the_fixed_epochs_and_keeps_two_numbers() -> None:
    honest = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 6, "patience": 1})
    reference = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 6, "patience": 1},
                             evaluation="reference")
    a, b = train_cell(honest, seed=0, measure=False), train_cell(reference, seed=0, measure=False)
    assert b.n_train == a.n_train + a.n_val and b.n_val == 0 and b.fit.val is None
    assert b.fit.epochs_run == 6  # patience is off: every epoch of the budget runs, nothing is selected
    ref = b.reference
    assert ref["final_epoch_accuracy"] == b.tests["test"].metrics["accuracy"]
    assert ref["best_test_epoch_accuracy"] >= ref["final_epoch_accuracy"] and 1 <= ref["best_test_epoch"] <= 6
    # no per-epoch test figure is kept anywhere: the curve holds training rows only
    assert all(row["val_accuracy"] is None and not any("test" in k for k in row) for row in b.fit.curve)
    assert a.reference is None


def test_the_default_evaluation_keeps_existing_hashes_and_reference_gets_its_own() -> None:
    honest = resolve_cell("tiny_mlp", "tiny_blobs")
    reference = resolve_cell("tiny_mlp", "tiny_blobs", evaluation="reference")
    assert "evaluation" not in honest.hashed() and reference.hashed()["evaluation"] == "reference"
    assert config_hash(honest) != config_hash(reference)
    with pytest.raises(ConfigError, match="--evaluation must be one of"):
        resolve_cell("tiny_mlp", "tiny_blobs", evaluation="best")
    with pytest.raises(ConfigError, match="does not combine with --refit"):
        resolve_cell("tiny_mlp", "tiny_blobs", evaluation="reference", refit=True)


def test_bench_labels_the_reference_figures(tmp_path: Path) -> None:
    out = tmp_path / "ref"
    assert main(["bench", "--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0,1", "--evaluation",
                 "reference", "--epochs", "4", "--out", str(out), "--no-plots", "-q"]) == 0
    cells = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    assert {c["config"]["evaluation"] for c in cells} == {"reference"} and all("reference" in c for c in cells)
    board = list(csv.DictReader((out / "leaderboard.csv").open()))
    assert {row["evaluation"] for row in board} == {"reference"}
    assert all(float(row["best_test_epoch_accuracy"]) >= float(row["accuracy"]) for row in board)
    report = (out / "report.md").read_text()
    assert "## Reference protocol" in report and "best test epoch (optimistic)" in report
    assert "final epoch (honest)" in report


def test_an_honest_run_has_no_reference_columns(tmp_path: Path) -> None:
    out = tmp_path / "honest"
    assert main(["bench", "--models", "tiny_mlp", "--datasets", "tiny_blobs", "--epochs", "2", "--out", str(out),
                 "--no-plots", "-q"]) == 0
    header = (out / "leaderboard.csv").read_text().splitlines()[0].split(",")
    assert "best_test_epoch_accuracy" not in header and "Reference protocol" not in (out / "report.md").read_text()


def test_bootstrap_interval_covers_the_mean_and_widens_with_dependent_units() -> None:
    rng = np.random.default_rng(1)
    cells = []
    targets = rng.integers(0, 4, 200)  # the seeds share one test set
    for _ in range(3):
        predictions = np.where(rng.random(200) < 0.7, targets, (targets + 1) % 4)
        cells.append((targets.tolist(), predictions.tolist()))
    mean = np.mean([np.mean(np.equal(t, p)) for t, p in cells])
    low, high = bootstrap_accuracy(cells)
    assert low < mean < high and 0.6 < low and high < 0.8
    assert bootstrap_accuracy(cells) == (low, high)  # seeded: a report regenerates to the same digits
    # 20 "recordings" of 10 windows that are right or wrong together (for every seed alike, so that only the test
    # part is left): 20 independent units, not 200
    right = np.repeat(rng.random(20) < 0.7, 10)
    targets = np.zeros(200, dtype=int)
    grouped = [(targets.tolist(), np.where(right, 0, 1).tolist())] * 3
    groups = [np.repeat(np.arange(20), 10).tolist()] * 3
    narrow, wide = bootstrap_accuracy(grouped), bootstrap_accuracy(grouped, groups=groups)
    assert (wide[1] - wide[0]) > 2 * (narrow[1] - narrow[0])
    assert bootstrap_accuracy([([0, 1], [0, 1])]) == (1.0, 1.0) and bootstrap_accuracy([]) is None
    # records_interval reads the same from cell records, by recording where the record lists them
    records = [{"predictions": {"test": {"targets": t, "predictions": p, "groups": g}}}
               for (t, p), g in zip(grouped, groups)]
    assert records_interval(records) == wide
    for rec in records:
        del rec["predictions"]["test"]["groups"]
    assert records_interval(records) == narrow
    with pytest.raises(ValueError, match="no stored predictions for split 'test_textures'"):
        records_interval(records, "test_textures")
