"""Cells in worker processes and on a Dask cluster give exactly the local numbers."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SMALL, read_board, run_cli

#: these tests share the session's reference run: one xdist worker computes it once
pytestmark = pytest.mark.xdist_group("tiny_bench")


def test_process_executor_matches_local(reference_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert run_cli([*SMALL, "--executor", "process", "--workers", "2", "--out", str(out)]) == 0
    assert "process (2 workers x 1 thread)" in capsys.readouterr().out
    assert read_board(out) == read_board(reference_run)


def test_dask_local_cluster_with_two_workers_matches_local(reference_run: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture) -> None:
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "run"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert run_cli([*SMALL, "--executor", "dask", "--scheduler", cluster.scheduler_address, "--out",
                        str(out)]) == 0
    assert f"dask ({cluster.scheduler_address}, 2 worker threads)" in capsys.readouterr().out
    assert read_board(out) == read_board(reference_run)


def test_unreachable_scheduler_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("distributed")
    assert run_cli([*SMALL, "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9", "--out",
                    str(tmp_path / "o")]) == 2
    assert "cannot connect to the Dask scheduler" in capsys.readouterr().err
