"""Harness test helpers: the tiny zoo (tests/tiny_zoo.py) registered per test, CLI runners, leaderboard reading."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
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


def subprocess_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["OMP_NUM_THREADS"] = "1"
    env["PYTHONFAULTHANDLER"] = "1"  # SIGABRT then prints every thread's stack: see hung_stacks()
    return env


def _default_interrupts() -> None:
    """In the child before it execs: SIGINT and SIGQUIT as a terminal gives them. A suite started in the background
    of a shell without job control (``make test &`` in a script) inherits both ignored, and an ignored SIGINT stays
    ignored through exec: the child would then train on through the SIGINT a test sends it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)


def bench_subprocess(args: list[str], **kw: object) -> subprocess.Popen:
    """``python -m tactile_zoo.cli bench --plugin-module tiny_zoo ARGS`` as a real child process."""
    cmd = [sys.executable, "-m", "tactile_zoo.cli", "bench", "--plugin-module", "tiny_zoo", *args]
    return subprocess.Popen(cmd, env=subprocess_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_interrupts, **kw)


def hung_stacks(proc: subprocess.Popen) -> str:
    """The stacks of every thread of a child that stopped answering (it runs with ``PYTHONFAULTHANDLER``, so SIGABRT
    makes it print them), for the failure message: an intermittent hang is then diagnosable from one CI log."""
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
