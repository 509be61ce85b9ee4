"""A Dask worker that dies inside a cell is survived: the cell is rescheduled, recorded once, with ``attempts == 2``.

A real cluster on 127.0.0.1: a scheduler and two worker processes (one thread each) under two nannies, which restart
a killed worker (a ``LocalCluster`` of processes, started by this module). The nannies fork their worker processes
from the warm server of tests/forked_bench.py, which has imported torch and the package once, so the worker a death
restarts is running in a second, not after a new interpreter's imports. A plugin module, shipped to the workers by
``--plugin-module``, registers an epoch listener (:func:`tactile_zoo.bench.progress.add_listener`) that SIGKILLs its
own worker process right after epoch 2 of one chosen cell, the first time only: the marker file it creates with
``O_EXCL`` says it already happened. So the death falls on an epoch boundary, not on a timer.

The run must end with every cell ok, the killed cell recorded once with 2 attempts, and the leaderboard equal to an
uninterrupted local run's. With ``--retries 0`` the same run fails the cell, and the same checks fail
(``test_the_check_fails_with_retries_off``); a cell recorded twice fails them too.
"""

from __future__ import annotations

import collections
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import SMALL, read_board, run_cli
from forked_bench import dask_forkserver

from tactile_zoo.bench import rundir

distributed = pytest.importorskip("distributed")

#: shares the session's reference run (tests/bench/conftest.py) with the other harness tests
pytestmark = pytest.mark.xdist_group("tiny_bench")

#: the cell whose worker dies: (model, dataset, fold)
DOOMED = ("tiny_rate", "tiny_kfold", 1)
PLUGIN = "tz_death_plugin"
PLUGIN_SOURCE = """
\"\"\"Test plugin: kill this worker process at the end of epoch 2 of one cell, once per marker file.\"\"\"
import os
import signal

import tiny_zoo  # noqa: F401 - the tiny models and datasets, registered on import

from tactile_zoo.bench import progress

DOOMED = {doomed!r}
MARKER = {marker!r}
RUNNER = {runner!r}  # the test process, which imports the plugin too: never killed


def _die_once(state):
    if os.getpid() == RUNNER or (state["model"], state["dataset"], state["fold"]) != DOOMED or state["epoch"] != 2:
        return
    try:
        fd = os.open(MARKER, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return  # the second attempt
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    os.kill(os.getpid(), signal.SIGKILL)


progress.add_listener(_die_once)
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """A scheduler and two single-threaded worker processes under nannies on 127.0.0.1, random ports; always torn
    down. Every worker process (the restarted one too) is forked from the warm server: the multiprocessing method
    stays set while the cluster lives."""
    root = tmp_path_factory.mktemp("cluster")
    plugin_dir = root / "plugin"
    plugin_dir.mkdir()
    marker = root / "killed.marker"
    (plugin_dir / f"{PLUGIN}.py").write_text(PLUGIN_SOURCE.format(doomed=DOOMED, marker=str(marker),
                                                                   runner=os.getpid()))
    with dask_forkserver(), distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"},  # no dashboard; its HTTP routes on a free port, not 8787
            local_directory=str(root / "workers")) as local:
        yield {"address": local.scheduler_address, "marker": marker, "plugin_dir": plugin_dir, "root": root}


def _bench(cluster: dict[str, Any], out: Path, retries: int, monkeypatch: pytest.MonkeyPatch
           ) -> tuple[int, list[str]]:
    """The SMALL grid on the cluster with the dying plugin; returns the exit code and every cell write, in order."""
    monkeypatch.syspath_prepend(str(cluster["plugin_dir"]))
    with distributed.Client(cluster["address"], timeout="30s") as client:  # a worker killed before is back
        client.wait_for_workers(2, timeout=120)
    cluster["marker"].unlink(missing_ok=True)
    writes: list[str] = []
    real = rundir.RunDir.write_cell

    def counting(self: rundir.RunDir, record: dict) -> Path:
        writes.append(record["cell_id"])
        return real(self, record)

    monkeypatch.setattr(rundir.RunDir, "write_cell", counting)
    code = run_cli([*SMALL, "--plugin-module", PLUGIN, "--executor", "dask", "--scheduler", cluster["address"],
                    "--retries", str(retries), "--out", str(out), "-q"])
    monkeypatch.setattr(rundir.RunDir, "write_cell", real)
    assert cluster["marker"].exists(), "the doomed cell's worker was never killed: the test proves nothing"
    return code, writes


def check_survived(code: int, out: Path, writes: list[str], reference: Path) -> None:
    """What surviving a worker's death means (raises AssertionError otherwise)."""
    records = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    assert code == 0, [r.get("error") for r in records]
    assert [r["status"] for r in records] == ["ok"] * 6
    doomed = [r for r in records if (r["model"], r["dataset"], r["fold"]) == DOOMED]
    assert len(doomed) == 1 and doomed[0]["attempts"] == 2
    assert all(r["attempts"] == 1 for r in records if r is not doomed[0])
    duplicates = {cell: n for cell, n in collections.Counter(writes).items() if n > 1}
    assert not duplicates, f"recorded more than once: {duplicates}"
    assert len(writes) == 6
    assert read_board(out) == read_board(reference)  # bit for bit, timing columns aside


def test_a_killed_worker_is_survived(cluster: dict[str, Any], reference_run: Path, tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    code, writes = _bench(cluster, out, 1, monkeypatch)
    check_survived(code, out, writes, reference_run)
    assert not list((out / "progress").glob("*.json"))  # every running cell's progress file is gone
    with distributed.Client(cluster["address"], timeout="30s") as client:  # the restarted worker got the plugin too
        client.wait_for_workers(2, timeout=120)
        shipped = client.run(lambda dask_worker: os.path.exists(os.path.join(dask_worker.local_directory,
                                                                              f"{PLUGIN}.py")))
    assert len(shipped) == 2 and all(shipped.values())
    # the same run's write log with the killed cell written twice must fail the check
    doomed = next(json.loads(p.read_text())["cell_id"] for p in (out / "cells").glob(f"{DOOMED[0]}__{DOOMED[1]}__f1*"))
    with pytest.raises(AssertionError, match="recorded more than once"):
        check_survived(code, out, [*writes, doomed], reference_run)


def test_the_check_fails_with_retries_off(cluster: dict[str, Any], reference_run: Path, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    code, writes = _bench(cluster, out, 0, monkeypatch)
    with pytest.raises(AssertionError):
        check_survived(code, out, writes, reference_run)
    assert code == 1
    (doomed,) = [json.loads(p.read_text()) for p in (out / "cells").glob(f"{DOOMED[0]}__{DOOMED[1]}__f1*")]
    assert doomed["status"] == "failed" and "worker process running this cell died" in doomed["error"]
    assert doomed["attempts"] == 1
