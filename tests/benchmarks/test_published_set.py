"""The published set packaged with tactile-zoo (``tactile_zoo/published/table1-v1.json.gz``): built from the committed
cells and not committed itself, what the cells give (``python -m tools.published_set --check``), every `full` and
`zoo` Table I cell in it, a few MB, named in the docs, and no wheel built without it (``setup.py``)."""

from __future__ import annotations

import gzip
import importlib.util
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from tactile_zoo.bench.records import cell_files
from tactile_zoo.study.published import load_set, packaged_sets
from tools import published_set

REPO = Path(__file__).resolve().parents[2]
#: with the published tables: one worker checks each committed cell file once for both (cells_checked_once)
pytestmark = pytest.mark.xdist_group("published_tables")


@pytest.mark.usefixtures("cells_checked_once")
def test_the_built_set_is_what_the_cells_give() -> None:
    assert published_set.main(["--check"]) == 0, "run python -m tools.published_set (make install)"


def test_the_set_is_built_not_committed() -> None:
    # results are committed once, as cells: a committed copy of the set could drift from them unnoticed by a clone
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = subprocess.run(["git", "ls-files", "tactile_zoo/published"], cwd=REPO, capture_output=True, text=True)
    assert tracked.returncode == 0 and tracked.stdout == ""
    ignored = subprocess.run(["git", "check-ignore", "-q", str(published_set.OUT)], cwd=REPO)
    assert ignored.returncode == 0, "the built set is not ignored by git"


def _setup_module(monkeypatch: pytest.MonkeyPatch, here: Path):  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("tactile_zoo_setup", REPO / "setup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # not __main__: setup() does not run
    monkeypatch.setattr(module, "HERE", here)
    return module


def test_no_wheel_is_built_without_the_set(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    setup = _setup_module(monkeypatch, tmp_path)
    with pytest.raises(SystemExit, match="table1-v1.json.gz is missing from this source tree, and it has no tools/"):
        setup.ensure_published_sets()
    # a checkout whose builder fails (an isolated build, without torch): the error names the file and the command
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "__init__.py").write_text("")
    (tmp_path / "tools" / "published_set.py").write_text("raise ImportError('No module named torch')\n")
    with pytest.raises(SystemExit, match=r"could not be built here \(ImportError: No module named torch\): run `make "):
        setup.ensure_published_sets()
    assert not (tmp_path / "tactile_zoo").exists()
    # a checkout whose builder works: the set is written, and the build goes on
    (tmp_path / "tools" / "published_set.py").write_text(
        "from pathlib import Path\n"
        "Path('tactile_zoo/published').mkdir(parents=True)\n"
        "Path('tactile_zoo/published/table1-v1.json.gz').write_bytes(b'set')\n")
    setup.ensure_published_sets()
    assert (tmp_path / "tactile_zoo" / "published" / "table1-v1.json.gz").read_bytes() == b"set"


def test_the_build_hook_names_every_packaged_set(monkeypatch: pytest.MonkeyPatch) -> None:
    setup = _setup_module(monkeypatch, REPO)
    assert [name.removesuffix(".json.gz") for name in setup.SETS] == packaged_sets()
    assert setup.SETS[-1] == published_set.OUT.name


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
