"""A metric registered by one function appears in the tables of an already finished folder (issue 39).

The folder is a copy of a committed one (``benchmarks/results/weights-ev-sgnet``: two finished cells, each storing
its test targets, predictions and class probabilities); nothing is trained.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from tactile_zoo.bench.records import cell_files, read_cell_bytes
from tactile_zoo.cli import main
from tactile_zoo.engine.metrics import MetricError, register_metric, unregister_metric

COMMITTED = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "weights-ev-sgnet"


@pytest.fixture
def metrics() -> Iterator[Callable[..., Callable]]:
    """``metrics(name, needs, label)``: :func:`register_metric`, the metric removed again when the test ends."""
    names: list[str] = []

    def add(name: str, needs: str = "predictions", label: str | None = None) -> Callable:
        names.append(name)
        return register_metric(name, needs=needs, label=label)

    yield add
    for name in names:
        unregister_metric(name)


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    out = tmp_path / "finished"
    shutil.copytree(COMMITTED, out)
    for path in cell_files(out):  # committed compact: the tests below edit plain files
        path.with_name(path.name.removesuffix(".gz")).write_bytes(read_cell_bytes(path))
        if path.name.endswith(".gz"):
            path.unlink()
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _cells(folder: Path) -> dict[str, dict]:
    return {p: json.loads(p.read_text()) for p in sorted((folder / "cells").glob("*.json"))}


def test_a_metric_added_by_one_function_appears_for_a_finished_folder(folder: Path, metrics: Callable) -> None:
    @metrics("error_count", label="errors")
    def error_count(labels: np.ndarray, predictions: np.ndarray) -> float:
        return float((labels != predictions).sum())

    assert main(["report", str(folder), "--no-plots"]) == 0
    board = _rows(folder / "leaderboard.csv")
    committed = _rows(COMMITTED / "leaderboard.csv")
    assert len(board) == len(committed) == 2
    for row, old in zip(board, committed):
        assert {k: v for k, v in row.items() if k != "error_count"} == old  # every other number as committed
    expected = {}
    for record in _cells(folder).values():
        test = record["predictions"]["test"]
        expected[record["dataset"]] = sum(t != p for t, p in zip(test["targets"], test["predictions"]))
    assert {r["dataset"]: float(r["error_count"]) for r in board} == expected
    assert any(v > 0 for v in expected.values())  # a metric that is 0 everywhere would prove little
    header = list(board[0])
    assert header.index("error_count") == header.index("error") + 1
    summary = {r["dataset"]: r for r in _rows(folder / "summary.csv")}
    assert {d: float(r["error_count_mean"]) for d, r in summary.items()} == expected
    report = (folder / "report.md").read_text()
    assert "| macro-F1 | errors | train s |" in report
    assert "computed from what each cell file stores of it: errors (`error_count`, from the predictions)." in report
    for dataset, errors in expected.items():
        assert f"| {errors:.3f} |" in next(line for line in report.splitlines() if f"| {dataset} |" in line)


def test_a_record_without_probabilities_shows_the_marker(folder: Path, metrics: Callable) -> None:
    @metrics("top2_accuracy", needs="probabilities", label="top-2 acc.")
    def top2_accuracy(labels: np.ndarray, probabilities: np.ndarray) -> float:
        top2 = np.argsort(probabilities, axis=1)[:, -2:]
        return float((top2 == labels[:, None]).any(axis=1).mean())

    paths = list(_cells(folder))
    stripped = json.loads(paths[0].read_text())
    del stripped["predictions"]["test"]["probabilities"]  # as a record of a test split over 2500 samples
    paths[0].write_text(json.dumps(stripped))
    assert main(["report", str(folder), "--no-plots"]) == 0
    board = {r["dataset"]: r for r in _rows(folder / "leaderboard.csv")}
    kept = json.loads(paths[1].read_text())
    assert board[stripped["dataset"]]["top2_accuracy"] == "n/a"
    value = float(board[kept["dataset"]]["top2_accuracy"])
    assert float(board[kept["dataset"]]["accuracy"]) <= value <= 1.0
    assert board[stripped["dataset"]]["accuracy"] == repr(stripped["metrics"]["test"]["accuracy"])  # predictions kept
    summary = {r["dataset"]: r for r in _rows(folder / "summary.csv")}
    assert summary[stripped["dataset"]]["top2_accuracy_mean"] == "n/a"
    report = (folder / "report.md").read_text()
    header = next(line for line in report.splitlines() if line.startswith("| model |")).split(" | ")
    assert header.index("top-2 acc.") == header.index("macro-F1") + 1
    for dataset, shown in ((stripped["dataset"], "n/a"), (kept["dataset"], f"{value:.3f}")):
        row = next(line for line in report.splitlines() if f"| {dataset} |" in line).split(" | ")
        assert row[header.index("top-2 acc.")] == shown
    legend = next(line for line in report.splitlines() if line.startswith("- `n/a` (top-2 acc.)"))
    assert "1 cell file(s) store no test probabilities, which `top2_accuracy` needs" in legend
    assert f"sgnet on {stripped['dataset']}" in legend and kept["dataset"] not in legend


def test_a_record_without_predictions_keeps_its_stored_numbers(folder: Path, metrics: Callable) -> None:
    metrics("always_one")(lambda labels, predictions: 1.0)
    path = next(iter(_cells(folder)))
    record = json.loads(path.read_text())
    del record["predictions"]  # an older record format: the numbers alone
    path.write_text(json.dumps(record))
    assert main(["report", str(folder), "--no-plots"]) == 0
    row = next(r for r in _rows(folder / "leaderboard.csv") if r["dataset"] == record["dataset"])
    for name in ("accuracy", "balanced_accuracy", "macro_f1"):
        assert row[name] == repr(record["metrics"]["test"][name])
    assert row["always_one"] == "n/a"
    assert "store no test predictions, which `always_one` needs" in (folder / "report.md").read_text()


def test_a_broken_metric_is_one_error_naming_it(folder: Path, metrics: Callable,
                                                capsys: pytest.CaptureFixture) -> None:
    @metrics("broken")
    def broken(labels: np.ndarray, predictions: np.ndarray) -> float:
        raise ZeroDivisionError("no classes to divide by")

    before = (folder / "leaderboard.csv").read_text()
    assert main(["report", str(folder), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert "metric 'broken'" in err[0] and "ZeroDivisionError: no classes to divide by" in err[0]
    assert "sgnet on ev_" in err[0]  # the cell it failed on
    assert (folder / "leaderboard.csv").read_text() == before  # nothing half written
    with pytest.raises(MetricError, match="metric 'broken'"):
        from tactile_zoo.bench.report import write_outputs

        write_outputs(folder, plots=False)


def test_a_metric_named_like_another_column_is_refused(folder: Path, metrics: Callable) -> None:
    metrics("params")(lambda labels, predictions: 0.0)  # would overwrite the parameter count
    with pytest.raises(MetricError, match="metric 'params' has the name of another table column"):
        from tactile_zoo.bench.report import write_outputs

        write_outputs(folder, plots=False)
