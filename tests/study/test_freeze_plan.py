"""``study freeze``: a plan frozen before its first cell audits as "not run yet", not as a broken rule; a grid of a
migrated study (its freeze written in the file) that finds no cell stays a failure (a misspelt folder)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from study_helpers import QUICKSTART, tz


def _plan(tmp_path: Path) -> Path:
    shutil.copy(QUICKSTART, tmp_path / "quickstart.yaml")
    return tmp_path / "quickstart.yaml"


def test_a_frozen_plan_audits_clean_and_names_its_waiting_grids(tmp_path: Path) -> None:
    path = _plan(tmp_path)
    code, out, _ = tz("study", "audit", str(path))
    assert code == 1 and "never frozen" in out  # before the freeze: a plan nobody fixed
    code, out, _ = tz("study", "freeze", str(path))
    assert code == 0 and "study quickstart frozen " in out
    state = json.loads((tmp_path / "quickstart-results" / "study" / "freeze.json").read_text())
    assert (tmp_path / "quickstart-results" / "study" / "study.yaml").read_text() == path.read_text()
    assert not list((tmp_path / "quickstart-results").glob("*/cells"))  # the freeze runs no cell
    code, out, _ = tz("study", "audit", str(path))
    assert code == 0, out
    assert f"grid main: not run yet (frozen {state['time']})" in out and "every rule held" in out
    assert "ensemble cnn_lstm_ens2: waits for its members (grid main not run yet)" in out


def test_a_frozen_plan_then_edited_is_still_refused(tmp_path: Path) -> None:
    path = _plan(tmp_path)
    assert tz("study", "freeze", str(path))[0] == 0
    path.write_text(path.read_text().replace("budget_cpu_hours: 0.1", "budget_cpu_hours: 0.3"))
    code, out, _ = tz("study", "audit", str(path))
    assert code == 1 and "not the file that was frozen" in out, out


def test_a_migrated_studys_empty_grid_is_still_a_failure(tmp_path: Path) -> None:
    path = _plan(tmp_path)
    text = path.read_text().replace("pre_registered: true\n", "pre_registered: true\nfreeze: {time: "
                                                                "\"2026-12-01T10:00:00+0000\", source: PLAN.md}\n")
    path.write_text(text)
    code, out, _ = tz("study", "audit", str(path))
    assert code == 1 and "does not exist" in out and "not run yet" not in out, out
