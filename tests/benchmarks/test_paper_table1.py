"""The README's Table I generator: paper figures next to mean +- std over the finished seeds."""

from __future__ import annotations

import csv
from pathlib import Path

from benchmarks.paper_table1 import main, table


def _write(path: Path, rows: list[dict[str, object]]) -> Path:
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, ["model", "dataset", "seed", "status", "accuracy", "train_seconds"])
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_table_averages_ok_seeds_and_marks_missing_models(tmp_path: Path) -> None:
    board = _write(tmp_path / "leaderboard.csv", [
        {"model": "x_tacformer", "dataset": "ev_objects", "seed": 0, "status": "ok", "accuracy": 0.90,
         "train_seconds": 360},
        {"model": "x_tacformer", "dataset": "ev_objects", "seed": 1, "status": "ok", "accuracy": 0.92,
         "train_seconds": 480},
        {"model": "x_tacformer", "dataset": "ev_objects", "seed": 2, "status": "failed", "accuracy": "",
         "train_seconds": ""},
        {"model": "sgnet", "dataset": "ev_containers", "seed": 0, "status": "ok", "accuracy": 0.65,
         "train_seconds": 600},
    ])
    text = table(board)
    rows = {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines() if line.startswith("| ")}
    # mean 0.91, sample std 0.0141 over the two ok seeds; the failed seed is left out and counted
    assert "| 0.9167 | 0.9100 +- 0.0141 (2 seeds, 7 min) | 0.7833 | not run yet |" in rows["X-Tacformer"]
    assert "| 0.8944 | not run yet | 0.6417 | 0.6500 (1 seed, 10 min) |" in rows["SGnet"]
    assert rows["D-CNN"].startswith("| D-CNN | - | not run yet | - |")
    assert "1 cell(s) of the leaderboard are not ok" in text


def test_missing_leaderboard_is_one_clear_error(tmp_path: Path, capsys) -> None:
    assert main([str(tmp_path)]) == 2
    assert "leaderboard.csv not found" in capsys.readouterr().err
