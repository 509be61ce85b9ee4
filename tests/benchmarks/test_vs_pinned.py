"""benchmarks.vs_pinned: the pinned copy is the commit's tree, and the rows alternate versions and divide medians.

The timing children are replaced by a stub here (they train for minutes); what is checked is the bookkeeping.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from forked_bench import finish_python, package_from

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, common, vs_pinned  # noqa: E402


def test_registered() -> None:
    assert BENCHMARKS["vs_pinned"] == "vs_pinned"
    assert BENCHMARKS["profile_models"] == "profile_models"


def test_pinned_tree_is_the_commits_tree(tmp_path: Path) -> None:
    tree = vs_pinned.pinned_tree(vs_pinned.PINNED_COMMIT, tmp_path / "tree")
    want = subprocess.run(["git", "-C", str(REPO), "show", f"{vs_pinned.PINNED_COMMIT}:tactile_zoo/__init__.py"],
                          capture_output=True, text=True, check=True).stdout
    assert (tree / "tactile_zoo" / "__init__.py").read_text() == want
    assert not (tree / "benchmarks" / "vs_pinned.py").exists()  # the benchmark came after the pinned commit


def test_rows_alternate_versions_and_divide_medians(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, str]] = []
    seconds = {"current": iter([1.0, 3.0, 2.0]), "pinned": iter([4.0, 6.0, 5.0])}

    def stub(root: Path, job: dict[str, Any], extra: dict[str, str] | None = None) -> dict[str, Any]:
        version = "current" if root == vs_pinned.REPO else "pinned"
        calls.append((job["model"], version))
        assert job["batch_size"] == 8  # the current recipe's, given to both versions
        assert job.get("hparams") == ({"compute": "event"} if version == "current" else None)  # opt-in: current only
        assert extra == ({"X": "1"} if version == "current" else None)  # --env-current reaches one side only
        s = next(seconds[version])
        return {"epoch_s": s, "epoch_cpu_s": 2 * s, "batch_size": 8, "samples_timed": 576, "loadavg": [0.5, 0.5, 0.5],
                "cpu_capability": "AVX2", "data": "synthetic"}

    monkeypatch.setattr(vs_pinned, "_run_child", stub)
    ctx = common.Context(threads=1, out=tmp_path, log=lambda _msg: None)
    path = vs_pinned.run(ctx, pinned=tmp_path / "pinned", models=("sgnet[compute=event]",), repeats=3,
                         env_current={"X": "1"})
    assert calls == [("sgnet", v) for v in ("current", "pinned", "pinned", "current", "current", "pinned")]
    (row,) = csv.DictReader(path.open())
    assert float(row["current_median_s"]) == 2.0 and float(row["pinned_median_s"]) == 5.0
    assert float(row["ratio"]) == 2.5 and float(row["ratio_cpu"]) == 2.5
    assert (row["case"], row["model"], row["hparams"]) == ("sgnet[compute=event]", "sgnet", '{"compute": "event"}')
    assert row["target"] == ">= 2.5x" and row["cpu_capability"] == "AVX2" and row["loadavg_before"]


def test_child_env_gives_extra_settings_to_one_version_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("THP_MEM_ALLOC_ENABLE", raising=False)
    env = vs_pinned.child_env(Path("/pinned"), 2)
    assert "THP_MEM_ALLOC_ENABLE" not in env
    assert (env["PYTHONPATH"], env["OMP_NUM_THREADS"], env["PYTHONDONTWRITEBYTECODE"]) == ("/pinned", "2", "1")
    assert vs_pinned.child_env(Path("/cur"), 2, {"THP_MEM_ALLOC_ENABLE": "1"})["THP_MEM_ALLOC_ENABLE"] == "1"


def test_parse_variant() -> None:
    assert vs_pinned.parse_variant("dcnn") == ("dcnn", {})
    assert vs_pinned.parse_variant("convlstm[backend=compiled;fc_units=8]") == (
        "convlstm", {"backend": "compiled", "fc_units": 8})
    for bad in ("sgnet[compute=event", "sgnet[compute]", "sgnet[=event]"):
        with pytest.raises(ValueError, match="--models"):
            vs_pinned.parse_variant(bad)


@pytest.mark.parametrize("version", ["current", "pinned"])
def test_child_runs_against_both_versions(version: str, tmp_path: Path) -> None:
    """The child uses only API both versions have (issue 39 renamed the registry's constructor): one real batch."""
    root = REPO if version == "current" else vs_pinned.pinned_tree(vs_pinned.PINNED_COMMIT, tmp_path / "tree")
    job = {"model": "cnn_lstm", "threads": 1, "batches": 1, "device": "cpu", "root": None, "batch_size": 4}
    (tmp_path / "no-data").mkdir()  # an empty data home: the synthetic stand-in, whatever the user's data home holds
    env = vs_pinned.child_env(root, 1, {"TACTILE_ZOO_DATA": str(tmp_path / "no-data")})
    # forked from the warm server (torch imported once per test process), with the version's own package: the
    # checkout's, which the server imported, or the pinned tree's in its place (tests/forked_bench.package_from)
    env["TACTILE_ZOO_DEFAULT_MALLOC"] = "0"  # the child's environment is the server's updated: set, not unset
    source = ("" if version == "current" else package_from(root)) + \
        f"import runpy; runpy.run_path({str(vs_pinned.CHILD)!r}, run_name='__main__')"  # the script by path, as -P
    code, stdout, stderr = finish_python(source, [json.dumps(job)], tmp_path / "child", **env)
    assert code == 0, stderr[-2000:]
    got = json.loads(stdout.strip().splitlines()[-1])
    assert (got["batch_size"], got["samples_timed"], got["data"]) == (4, 4, "synthetic")
    assert got["epoch_s"] > 0 and got["peak_rss_mb"] > 0
    assert got["malloc_tuned"] is (version == "current" and sys.platform == "linux")
