"""The README's Table I generator: paper figures next to mean +- std over the current, finished seeds."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.paper_table1 import main, table
from tactile_zoo import registry


def _cell(folder: Path, model: str, dataset: str, seed: int, status: str = "ok", accuracy: float | None = None,
          seconds: float | None = None, revision: int | None = None) -> None:
    current = registry.revision_of(registry.get_model_entry(model))
    record = {"model": model, "dataset": dataset, "seed": seed, "status": status, "train_seconds": seconds,
              "metrics": {"test": {"accuracy": accuracy}},
              "config": {"model_revision": current if revision is None else revision, "dataset_revision": 1,
                         "recipe_name": "source"}}
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    (folder / "cells" / f"{model}__{dataset}__s{seed}__{status}__{revision}.json").write_text(json.dumps(record))


def test_table_averages_current_ok_seeds_and_marks_missing_models(tmp_path: Path) -> None:
    _cell(tmp_path, "x_tacformer", "ev_objects", 0, accuracy=0.90, seconds=360)
    _cell(tmp_path, "x_tacformer", "ev_objects", 1, accuracy=0.92, seconds=480)
    _cell(tmp_path, "x_tacformer", "ev_objects", 2, status="failed")
    _cell(tmp_path, "sgnet", "ev_containers", 0, accuracy=0.65, seconds=600)
    _cell(tmp_path, "sgnet", "ev_objects", 0, accuracy=0.99, seconds=600, revision=1)  # older code: left out
    text = table(tmp_path)
    rows = {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines() if line.startswith("| ")}
    # mean 0.91, sample std 0.0141 over the two ok seeds; the failed and the stale cells are left out and counted
    assert "| 0.9167 | 0.9100 +- 0.0141 (2 seeds, 7 min) | 0.7833 | not run yet |" in rows["X-Tacformer"]
    assert "| 0.8944 | not run yet | 0.6417 | 0.6500 (1 seed, 10 min) |" in rows["SGnet"]
    assert rows["D-CNN"].startswith("| D-CNN | - | not run yet | - |")
    assert "2 cell file(s) are left out" in text


def test_a_missing_cells_folder_is_one_clear_error(tmp_path: Path, capsys) -> None:
    assert main([str(tmp_path)]) == 2
    assert "cells not found" in capsys.readouterr().err
