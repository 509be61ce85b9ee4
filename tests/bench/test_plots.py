"""The report's plots draw a legend only where it has something to name: a run whose cells have no validation
accuracy (a final evaluation) gave matplotlib's "No artists with labels found to put in legend" on every bench
(issue 49, item 15)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import pytest

from tactile_zoo.bench.plots import write_plots
from tactile_zoo.bench.rundir import RunDir


def _record(curve: list[dict[str, Any]]) -> dict[str, Any]:
    return {"status": "ok", "model": "m", "dataset": "d", "fold": 0, "seed": 0, "class_names": ["a", "b"],
            "metrics": {"test": {"accuracy": 0.75, "confusion": [[1, 1], [0, 2]]}}, "curve": curve}


SUMMARY = [{"model": "m", "dataset": "d", "accuracy_mean": 0.75, "accuracy_std": None, "n_cells": 1}]


@pytest.mark.parametrize("curve", [
    [{"epoch": 1, "train_loss": 1.0}, {"epoch": 2, "train_loss": 0.5}],  # final evaluation: no validation split
    [],  # no curve at all
    [{"epoch": 1, "train_loss": 1.0, "val_loss": 1.2, "val_accuracy": 0.5}],  # the usual case
])
def test_no_empty_legend_warning(tmp_path: Path, curve: list[dict[str, Any]]) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        figures = write_plots(RunDir(tmp_path), [_record(curve)], SUMMARY)
    assert [str(w.message) for w in caught if "No artists with labels" in str(w.message)] == []
    assert (tmp_path / figures["curves"]["d"]).is_file()
