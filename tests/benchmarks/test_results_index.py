"""``benchmarks/results/``: every folder says what it holds, and the index lists every folder and CSV."""

from __future__ import annotations

from pathlib import Path

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results"
#: folders a run writes inside itself: records, not places that need their own README
RUN_PARTS = {"cells", "plots", "weights", "progress", "claims", "damaged", "__pycache__", "study"}  # study: its state


def folders_without_readme(root: Path) -> list[str]:
    return sorted(str(d.relative_to(root)) for d in root.rglob("*")
                  if d.is_dir() and not RUN_PARTS & set(d.relative_to(root).parts) and not (d / "README.md").exists())


def unindexed(root: Path) -> list[str]:
    index = (root / "README.md").read_text()
    names = [f"`{p.name}/`" if p.is_dir() else f"`{p.name}`" for p in root.iterdir()
             if p.name != "README.md" and not p.name.startswith(".")]
    return sorted(n for n in names if n not in index)


def test_every_results_folder_has_a_readme() -> None:
    assert folders_without_readme(RESULTS) == []


def test_the_index_lists_every_folder_and_csv() -> None:
    assert unindexed(RESULTS) == []


def test_the_checks_catch_a_new_folder(tmp_path: Path) -> None:
    (tmp_path / "README.md").write_text("| `old/` | a run |\n")
    (tmp_path / "old" / "cells").mkdir(parents=True)
    (tmp_path / "old" / "README.md").write_text("old")
    (tmp_path / "new").mkdir()
    (tmp_path / "timing.csv").write_text("a\n")
    assert folders_without_readme(tmp_path) == ["new"]
    assert unindexed(tmp_path) == ["`new/`", "`timing.csv`"]
