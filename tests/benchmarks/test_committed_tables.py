"""The committed bench folders' tables rebuild byte for byte from their cell files.

The test metrics of ``leaderboard.csv`` and ``summary.csv`` are computed from the predictions each cell file stores
(:func:`tactile_zoo.engine.metrics.register_metric`), no longer copied from its stored numbers: every committed
table must come out exactly as it was written, which holds only if each recomputed accuracy, balanced accuracy and
macro-F1 equals, to the last bit, the number the cell stored.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tactile_zoo.bench.records import cell_files, read_cell_bytes
from tactile_zoo.bench.report import load_run
from tactile_zoo.bench.tables import leaderboard_rows, record_metrics, rows_to_csv, summary_rows
from tactile_zoo.engine.metrics import metric_value, registered_metrics
from tactile_zoo.study.publish import study_folder

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
FULL = study_folder(RESULTS.parent / "studies", "table1-full-r3")  # Table I's `full` cells, round 3
FOLDERS = sorted(p.parent for p in RESULTS.rglob("cells") if (p.parent / "leaderboard.csv").is_file())


def test_the_committed_folders_are_found() -> None:
    assert len(FOLDERS) >= 20 and FULL in FOLDERS


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: str(p.relative_to(RESULTS)))
def test_a_committed_folder_rebuilds_its_tables_unchanged(folder: Path) -> None:
    # a folder built by several bench commands says so in its report (``--all-cells``)
    all_cells = "Built with `--all-cells`" in (folder / "report.md").read_text()
    records, skipped, _, _ = load_run(folder, all_cells=all_cells)
    board, columns = leaderboard_rows(records, skipped)
    summary, summary_columns = summary_rows(board, columns)
    assert rows_to_csv(board, columns) == (folder / "leaderboard.csv").read_text()
    assert rows_to_csv(summary, summary_columns) == (folder / "summary.csv").read_text()


def test_recomputed_metrics_equal_the_stored_ones_in_the_table1_cells() -> None:
    """Each registered metric computed from the stored predictions (never the stored fallback) is the stored number,
    and the table's row holds that number."""
    fixed = [m for m in registered_metrics() if m.name in ("accuracy", "balanced_accuracy", "macro_f1")]
    assert [m.name for m in fixed] == ["accuracy", "balanced_accuracy", "macro_f1"]
    checked = 0
    for path in cell_files(FULL):
        record = json.loads(read_cell_bytes(path))
        test = (record.get("metrics") or {}).get("test")
        if record["status"] != "ok" or not test:
            continue
        assert record["predictions"]["test"]["predictions"], path.name
        row = record_metrics(record)
        for metric in fixed:
            assert metric_value(metric, record["predictions"]["test"]) == test[metric.name] == row[metric.name]
        checked += 1
    assert checked >= 60
