"""Harness test helpers: the tiny zoo (tests/tiny_zoo.py) registered per test, CLI runners, leaderboard reading."""

from __future__ import annotations

import contextlib
import csv
import importlib.util
import io
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import tiny_zoo

from tactile_zoo.bench.tables import TIMING_COLUMNS
from tactile_zoo.cli import main

TESTS = Path(__file__).resolve().parents[1]
#: a small grid: 2 models x (tiny_blobs: 1 fold + tiny_kfold: 2 of its 3 folds) x seed 0 = 6 cells
SMALL = ["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_blobs,tiny_kfold", "--folds", "2", "--seeds", "0",
         "--threads", "1", "--no-plots"]


@pytest.fixture(autouse=True)
def tiny() -> Iterator[None]:
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()


def run_cli(args: list[str]) -> int:
    return main(["bench", "--plugin-module", "tiny_zoo", *args] if args and args[0].startswith("-") else args)


def hung_stacks(proc: subprocess.Popen) -> str:
    """The stacks of every thread of a child that stopped answering, for the failure message: an intermittent hang is
    then diagnosable from one CI log (forked children run with faulthandler on where ``PYTHONFAULTHANDLER`` is set,
    tests/forked_bench.py, so SIGABRT makes them print their stacks)."""
    proc.send_signal(signal.SIGABRT)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return (err or "")[-8000:]


def read_board(path: Path, drop_timing: bool = True) -> list[dict[str, str]]:
    """leaderboard.csv rows, without the machine-dependent timing columns."""
    with open(path / "leaderboard.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if drop_timing:
        rows = [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]
    return rows


@pytest.fixture(scope="session")
def dask_cluster() -> Iterator[object]:
    """Two single-threaded Dask worker processes on 127.0.0.1, started once per test process for the tests that run
    a grid on a cluster given by ``--scheduler`` (started once, not once per test). The workers are forked from the
    warm server of tests/forked_bench.py, which has imported torch and the package, not spawned as new interpreters
    that import them on their first cell. The tests of the cluster that ``--executor dask`` starts itself, and of a
    worker's death, have their own."""
    distributed = pytest.importorskip("distributed")
    from forked_bench import dask_forkserver

    with dask_forkserver():
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    with cluster:
        yield cluster


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The SMALL grid run once, uninterrupted, locally in this process."""
    out = tmp_path_factory.mktemp("reference") / "run"
    tiny_zoo.register()
    assert run_cli([*[a for a in SMALL if a != "--no-plots"], "--out", str(out), "-q"]) == 0  # with plots
    return out


@dataclass(frozen=True)
class ProcessRun:
    """The SMALL grid run once by ``--executor process --workers 2``: its folder, exit code, what it printed, and
    the tracker its workers logged each cell to (``mlflow`` where MLflow is installed, else ``None``)."""

    out: Path
    code: int
    stdout: str
    stderr: str
    tracker: str | None


@pytest.fixture(scope="session")
def process_run(tmp_path_factory: pytest.TempPathFactory) -> ProcessRun:
    """One run of the process executor for the tests of its numbers and output (test_executors.py) and of what its
    workers log to MLflow (test_trackers.py): each spawned worker imports torch, the package, sklearn and MLflow
    (seconds of CPU), so they share one pool of two instead of starting two."""
    out = tmp_path_factory.mktemp("process") / "run"
    tracker = "mlflow" if importlib.util.find_spec("mlflow") is not None else None
    tiny_zoo.register()
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = run_cli([*SMALL, "--executor", "process", "--workers", "2", *(["--tracker", tracker] if tracker else []),
                        "--out", str(out)])
    return ProcessRun(out, code, stdout.getvalue(), stderr.getvalue(), tracker)
