"""Cells in worker processes and on a Dask cluster give exactly the local numbers."""

from __future__ import annotations

import json
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest
from conftest import SMALL, ProcessRun, read_board, run_cli
from forked_bench import dask_forkserver

#: these tests share the session's reference run: one xdist worker computes it once
pytestmark = pytest.mark.xdist_group("tiny_bench")


def test_process_executor_matches_local(process_run: ProcessRun, reference_run: Path) -> None:
    out = process_run.out  # SMALL on 2 spawned workers, which also logged to MLflow (tests/bench/conftest.py)
    assert process_run.code == 0, process_run.stderr
    assert "process (2 workers x 1 thread)" in process_run.stdout
    assert read_board(out) == read_board(reference_run)
    # the workers' epochs reach the runner as they happen: one log line per epoch (stderr is not a terminal here)
    for cell in ("tiny_mlp x tiny_blobs fold 0 seed 0", "tiny_rate x tiny_kfold fold 1 seed 0"):
        assert f"{cell}: epoch 1/8 val_acc " in process_run.stderr
        assert f"{cell}: epoch 2/8 val_acc " in process_run.stderr
    assert not list((out / "progress").iterdir())  # each cell's progress file goes with its record


def test_dask_local_cluster_with_two_workers_matches_local(dask_cluster: Any, reference_run: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    cluster = dask_cluster
    assert run_cli([*SMALL, "--executor", "dask", "--scheduler", cluster.scheduler_address, "--out", str(out)]) == 0
    printed = capsys.readouterr()
    assert f"dask ({cluster.scheduler_address}, 2 worker threads, retries 3)" in printed.out  # Dask's default
    assert "tiny_mlp x tiny_blobs fold 0 seed 0: epoch 1/8" in printed.err
    assert read_board(out) == read_board(reference_run)
    assert all(json.loads(p.read_text())["attempts"] == 1 for p in (out / "cells").glob("*.json"))


def test_dask_local_cluster_with_dashboard_and_plugin_shipping(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("distributed")
    out = tmp_path / "run"
    with dask_forkserver():  # the cluster's worker forked from the warm server, not a new interpreter
        assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--no-plots", "--executor", "dask",
                        "--workers", "1", "--retries", "2", "--dashboard", "127.0.0.1:0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1 worker threads, retries 2, dashboard http://127.0.0.1:" in text


def test_dask_flags_need_dask(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert run_cli([*SMALL, "--retries", "1", "--out", str(tmp_path / "o")]) == 2
    assert "--retries only applies to --executor dask" in capsys.readouterr().err
    assert run_cli([*SMALL, "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9", "--dashboard", ":8787",
                    "--out", str(tmp_path / "o")]) == 2
    assert "--dashboard only applies" in capsys.readouterr().err


def test_plugin_modules_are_shipped_as_files(tmp_path: Path) -> None:
    from tactile_zoo.bench.executors import _shipped_file

    assert _shipped_file("tiny_zoo", tmp_path).name == "tiny_zoo.py"  # a local module: its file
    assert _shipped_file("numpy", tmp_path) is None  # an installed distribution: the workers install it
    package = tmp_path / "src" / "zoo_pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("from .sub.m import X\n")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "m.py").write_text("X = 7\n")
    sys.path.insert(0, str(package.parent))
    try:
        archive = _shipped_file("zoo_pkg.sub.m", tmp_path)
    finally:
        sys.path.remove(str(package.parent))
        for name in [m for m in sys.modules if m.startswith("zoo_pkg")]:
            del sys.modules[name]
    assert archive is not None and archive.suffix == ".zip"
    assert sorted(zipfile.ZipFile(archive).namelist()) == ["zoo_pkg/__init__.py", "zoo_pkg/sub/__init__.py",
                                                           "zoo_pkg/sub/m.py"]


def test_unreachable_scheduler_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("distributed")
    assert run_cli([*SMALL, "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9", "--out",
                    str(tmp_path / "o")]) == 2
    assert "cannot connect to the Dask scheduler" in capsys.readouterr().err
