"""docs/fidelity.md's tables are what the committed results give (``python -m tools.fidelity`` rewrites them)."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tools import fidelity  # noqa: E402
from tools.model_pages import display, zoo_models  # noqa: E402


def test_the_ledger_is_regenerated_from_the_committed_results() -> None:
    assert fidelity.main(["--check"]) == 0, "run python -m tools.fidelity and commit docs/fidelity.md"


def test_the_ledger_has_a_row_for_every_builtin_model() -> None:
    tables = fidelity.tables()
    for model in zoo_models():  # the registry's built-ins, not a list of the tool's own
        assert f"| {display(model)} |" in tables
    assert len(zoo_models()) >= 8
    assert "released weights, evaluation only" in tables and "best test epoch" in tables
