"""The published set packaged with tactile-zoo (``tactile_zoo/published/table1-v1.json.gz``): what the committed
cells give (``python -m tools.published_set --check``), every `full` and `zoo` Table I cell in it, a few MB, and
named in the docs."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import pytest

from tactile_zoo.bench.records import cell_files
from tactile_zoo.study.published import load_set, packaged_sets
from tools import published_set

REPO = Path(__file__).resolve().parents[2]
#: with the published tables: one worker checks each committed cell file once for both (cells_checked_once)
pytestmark = pytest.mark.xdist_group("published_tables")


@pytest.mark.usefixtures("cells_checked_once")
def test_the_committed_set_is_what_the_cells_give() -> None:
    assert published_set.main(["--check"]) == 0, "run python -m tools.published_set and commit the set"


def test_the_check_fails_on_a_set_the_cells_do_not_give(tmp_path: Path) -> None:
    (tmp_path / "base" / "cells").mkdir(parents=True)
    for path in cell_files(REPO / "benchmarks" / "results" / "paper-table1-full")[:2]:
        shutil.copy(path, tmp_path / "base" / "cells")
    argv = ["--from", str(tmp_path / "base"), "--out", str(tmp_path / "t-v1.json.gz"), "--name", "t", "--tuning",
            str(tmp_path / "none")]
    (tmp_path / "none").mkdir()
    assert published_set.main(argv) == 0
    assert published_set.main([*argv, "--check"]) == 0
    data = json.loads(gzip.decompress((tmp_path / "t-v1.json.gz").read_bytes()))
    split = data["cells"][0]["splits"]["test"]
    split["predictions"][0] = (split["predictions"][0] + 1) % 7
    (tmp_path / "t-v1.json.gz").write_bytes(gzip.compress(json.dumps(data).encode()))
    assert published_set.main([*argv, "--check"]) == 1


def test_the_set_holds_every_full_and_zoo_table1_cell() -> None:
    assert packaged_sets() == ["table1-v1"]
    pset = load_set("published")
    assert pset.set_id == "table1-v1"
    results = REPO / "benchmarks" / "results"
    expected = {"full": {p.name.split(".")[0] for f in ("paper-table1-full", "paper-table1-full-r4")
                         for p in cell_files(results / f)},
                "zoo": {p.name.split(".")[0] for p in cell_files(results / "paper-table1-zoo")}}
    for recipe, ids in expected.items():
        assert {c["cell_id"] for c in pset.cells if c["recipe_name"] == recipe} == ids
    assert len(expected["full"]) == 180  # six models, three datasets, seeds 0-9
    full = [c for c in pset.cells if c["recipe_name"] == "full"]
    assert {c["seed"] for c in full} == set(range(10))
    assert all(c["splits"]["test"]["predictions"] and c["config_hash"] and c["dataset_revision"] == 1 for c in full)


def test_the_set_is_small_and_its_version_and_size_are_in_the_docs() -> None:
    size = published_set.OUT.stat().st_size
    assert size < 4_000_000
    page = (REPO / "docs" / "compare.md").read_text()
    assert "table1-v1" in page and f"{size / 1e6:.1f} MB" in page
