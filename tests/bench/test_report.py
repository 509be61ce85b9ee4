from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import tiny_zoo
from conftest import read_board, run_cli

from tactile_zoo import registry
from tactile_zoo.cli import main

#: these tests share the session's reference run: one xdist worker computes it once
pytestmark = pytest.mark.xdist_group("tiny_bench")

PLOTS = ["heatmap.png", "bars_tiny_blobs.png", "bars_tiny_kfold.png", "curves_tiny_blobs.png", "curves_tiny_kfold.png",
         "early_tiny_blobs.png", "early_tiny_kfold.png", "confusion/tiny_blobs__tiny_mlp.png",
         "confusion/tiny_blobs__tiny_rate.png", "confusion/tiny_kfold__tiny_mlp.png",
         "confusion/tiny_kfold__tiny_rate.png"]


def test_report_regenerates_everything_from_the_cell_files(reference_run: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run / "cells", out / "cells")  # nothing but the cell files (no run.json)
    assert main(["report", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    for name in ("leaderboard.csv", "summary.csv"):
        assert (out / name).read_text() == (reference_run / name).read_text(), name
    for plot in PLOTS:
        data = (out / "plots" / plot).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000, plot
    report = (out / "report.md").read_text()
    for text in ("## Summary", "| tiny_mlp | default | tiny_blobs | 1 |", "## tiny_kfold", "plots/heatmap.png",
                 "plots/early_tiny_blobs.png", "Early classification", "| tiny_rate | yes |",
                 "| tiny_mlp | no (truncated) |", "plots/confusion/tiny_kfold__tiny_rate.png"):
        assert text in report, text


def test_the_summary_quotes_the_shared_bootstrap_interval(reference_run: Path) -> None:
    from tactile_zoo.bench.intervals import records_interval

    cells = [json.loads(p.read_text()) for p in sorted((reference_run / "cells").glob("tiny_rate__tiny_kfold*.json"))]
    assert len(cells) == 2  # two folds: the interval resamples both and their test samples
    low, high = records_interval(cells)
    row = next(line for line in (reference_run / "report.md").read_text().splitlines()
               if line.startswith("| tiny_rate | default | tiny_kfold |"))
    assert f"[{low:.3f}, {high:.3f}]" in row
    mean = sum(c["metrics"]["test"]["accuracy"] for c in cells) / 2
    assert low <= mean <= high and low < high


def test_report_uses_the_cells_of_the_run_grid(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    foreign = next((out / "cells").glob("tiny_mlp__tiny_blobs*.json"))
    shutil.copy(foreign, out / "cells" / "stale.json")  # same content, a cell id that the grid does not list:
    text = foreign.read_text().replace('"cell_id": "tiny_mlp__tiny_blobs', '"cell_id": "stale__tiny_mlp__tiny_blobs')
    (out / "cells" / "stale.json").write_text(text)
    assert main(["report", str(out), "--no-plots"]) == 0
    assert (out / "leaderboard.csv").read_text() == (reference_run / "leaderboard.csv").read_text()
    assert "1 cell file(s) in the folder belong to another configuration" in (out / "report.md").read_text()


def test_all_cells_builds_one_table_from_several_commands(reference_run: Path, tmp_path: Path) -> None:
    """Two bench commands into one folder (as the README's Table I does): the default report shows the last
    command's grid; ``--all-cells`` shows every cell, and equals the one-command run's leaderboard."""
    out = tmp_path / "run"
    base = ["--datasets", "tiny_blobs,tiny_kfold", "--folds", "2", "--seeds", "0", "--threads", "1", "--no-plots",
            "--out", str(out), "-q"]
    assert run_cli(["--models", "tiny_mlp", *base]) == 0
    assert run_cli(["--models", "tiny_rate", *base]) == 0
    assert {r["model"] for r in read_board(out)} == {"tiny_rate"}  # run.json names the last grid only
    assert main(["report", str(out), "--all-cells", "--no-plots"]) == 0
    assert read_board(out) == read_board(reference_run)
    report = (out / "report.md").read_text()
    assert "Built with `--all-cells`" in report and "Warning" not in report


def test_all_cells_warns_when_one_pair_mixes_configurations(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    cell = next((out / "cells").glob("tiny_mlp__tiny_blobs*.json"))
    text = cell.read_text().replace('"cell_id": "tiny_mlp__tiny_blobs', '"cell_id": "other__tiny_mlp__tiny_blobs')
    text = text.replace('"config_hash": "', '"config_hash": "other', 1)  # the same pair under another configuration
    (out / "cells" / "other.json").write_text(text)
    assert main(["report", str(out), "--all-cells", "--no-plots"]) == 0
    warning = "Warning: cells of more than one configuration are averaged together for tiny_mlp (default) on tiny_blobs"
    assert warning in (out / "report.md").read_text()


def _edit_cell(path: Path, **config: object) -> None:
    """Set (value) or drop (None) keys of a cell record's config."""
    record = json.loads(path.read_text())
    for key, value in config.items():
        if value is None:
            record["config"].pop(key, None)
        else:
            record["config"][key] = value
    path.write_text(json.dumps(record))


def test_report_flags_cells_of_an_older_revision(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    assert main(["report", str(out), "--all-cells", "--no-plots"]) == 0
    assert "older code" not in (out / "report.md").read_text()  # every cell is of the registered revisions
    cells = out / "cells"
    # tiny_mlp's code moves to revision 2 and tiny_kfold's to 3 after the run
    registry.register_model("tiny_mlp", recipe=tiny_zoo.TINY_RECIPE, tags=["test"], causal=False,
                            revision=2)(tiny_zoo.TinyMLP)
    registry.register_dataset("tiny_kfold", description="test dataset", revision=3)(tiny_zoo.TinyKFold)
    _edit_cell(next(cells.glob("tiny_mlp__tiny_blobs*.json")), model_revision=2)  # already rerun: up to date
    kfold0, kfold1 = sorted(cells.glob("tiny_mlp__tiny_kfold*.json"))
    _edit_cell(kfold0, model_revision=None, dataset_revision=None)  # a record from before revisions: revision 1
    _edit_cell(kfold1, model_revision=1, dataset_revision=1)
    gone = json.loads(next(cells.glob("tiny_rate__tiny_blobs*.json")).read_text())
    gone.update(model="tiny_gone", cell_id="tiny_gone__tiny_blobs")  # a model no longer registered: tolerated
    (cells / "tiny_gone.json").write_text(json.dumps(gone))
    assert main(["report", str(out), "--all-cells", "--no-plots"]) == 0
    report = (out / "report.md").read_text()
    assert "## Warning: cells computed by older code" in report and "`--force`" in report
    section = report.split("## Warning: cells computed by older code")[1].split("## Summary")[0]
    flagged = [line for line in section.splitlines() if line.startswith("- ")]
    assert flagged == [
        "- tiny_mlp on tiny_kfold, 2 cell(s) (fold 0 seed 0, fold 1 seed 0): model revision 1, now 2; dataset "
        "revision 1, now 3",
        "- tiny_rate on tiny_kfold, 2 cell(s) (fold 0 seed 0, fold 1 seed 0): dataset revision 1, now 3",
    ]  # not tiny_mlp on tiny_blobs (recorded 2), tiny_rate on tiny_blobs (1 = 1), nor the unregistered tiny_gone
