"""``study compare`` on the real Ev-Objects against the packaged set's `full` cells (skipped without
``../shared/data``). The "user" side reuses D-CNN's committed `full` cells of seeds 0-1 (the bench finds them finished:
nothing trains), so the test costs the data's loading alone; the report's paired differences against the five other
baselines are recomputed from the committed cells' raw predictions."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
from study_helpers import tz

from tactile_zoo.bench.paired import paired_bootstrap
from tactile_zoo.bench.records import cell_files, read_record

pytestmark = pytest.mark.real_data

FULL = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "paper-table1-full"


def test_ev_objects_against_the_published_full_cells(shared_data: Path, tmp_path: Path) -> None:
    cells = tmp_path / "mine-results" / "mine" / "cells"
    cells.mkdir(parents=True)
    raw: dict[str, dict[int, dict]] = {}
    for path in cell_files(FULL):
        rec = read_record(path)
        if rec["dataset"] == "ev_objects" and rec["seed"] in (0, 1):
            raw.setdefault(rec["model"], {})[rec["seed"]] = rec
            if rec["model"] == "dcnn":
                shutil.copy(path, cells)
    study = tmp_path / "mine.yaml"
    # revision 1: the committed cells' (the default is 2 since performance round 5)
    study.write_text("study: dcnn-vs-zoo\nquestion: D-CNN against the other published baselines\ngrids:\n"
                     "  - name: mine\n    settings: {models: [dcnn], datasets: ev_objects, recipe_name: full, "
                     f"seeds: [0, 1], model_revisions: {{dcnn: 1}}, root: {shared_data}}}\n"
                     "against: {set: published, recipe: full}\n")
    code, _, err = tz("study", "compare", str(study), "-q")
    assert code == 0, err
    assert sorted(p.name for p in cells.iterdir()) == sorted(f"{raw['dcnn'][s]['cell_id']}.json.gz" for s in (0, 1))
    with (tmp_path / "mine-results" / "compare" / "paired.csv").open() as stream:
        rows = {row["baseline"]: row for row in csv.DictReader(stream)}
    assert sorted(rows) == ["cnn_lstm", "convlstm", "sgnet", "tacformer", "x_tacformer"]
    for baseline, row in rows.items():
        pairs = [(raw[baseline][s]["predictions"]["test"]["targets"], raw[baseline][s]["predictions"]["test"][
            "predictions"], raw["dcnn"][s]["predictions"]["test"]["predictions"]) for s in (0, 1)]
        by_hand = np.mean([(np.asarray(b) == t).mean() - (np.asarray(a) == t).mean()
                           for t, a, b in ((np.asarray(t), a, b) for t, a, b in pairs)])
        expected = paired_bootstrap(pairs)
        assert float(row["difference"]) == pytest.approx(by_hand, abs=1e-12), baseline
        assert (float(row["low"]), float(row["high"])) == pytest.approx((expected.low, expected.high), abs=1e-12)
    report = (tmp_path / "mine-results" / "compare" / "report.md").read_text()
    assert "**table1-v1**" in report and "144 samples of 144 recordings" in report
