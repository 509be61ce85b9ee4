"""Progress of running cells (tactile_zoo.bench.progress), the cost-weighted ETA, and the CLI's logging."""

from __future__ import annotations

import json
import logging
import os
import time
import tomllib
import warnings
from pathlib import Path
from typing import Any

import pytest
from conftest import run_cli

from tactile_zoo import registry
from tactile_zoo.bench import progress
from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.executors import LocalExecutor
from tactile_zoo.bench.grid import build_grid
from tactile_zoo.bench.progress import CostModel, ProgressDisplay, ProgressWriter
from tactile_zoo.bench.runner import _task
from tactile_zoo.bench.worker import run_cell
from tactile_zoo.cli import main

TIMING = {"seconds", "train_seconds", "infer_ms_per_sample", "started", "finished", "peak_memory_mb",
          "peak_memory_source", "peak_gpu_memory_mb"}


def _tiny_task(progress_dir: Path | None, model: str = "tiny_mlp") -> Any:
    (cell,) = build_grid(BenchConfig(models=[model], datasets=["tiny_blobs"])).cells
    return _task(cell, BenchConfig(), LocalExecutor(threads=1), progress_dir)


def _numbers(record: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in record.items() if k not in TIMING}
    out["curve"] = [{k: v for k, v in row.items() if k != "seconds"} for row in record["curve"]]
    return out


def test_progress_leaves_every_number_unchanged_and_reports_every_epoch(tmp_path: Path) -> None:
    states: list[dict[str, Any]] = []
    with progress.listening(lambda state: states.append(dict(state))):
        with_progress = run_cell(_tiny_task(tmp_path))
    without = run_cell(_tiny_task(None))
    assert with_progress["status"] == "ok" and _numbers(with_progress) == _numbers(without)  # bit for bit
    epochs = with_progress["epochs_run"]
    assert [s["epoch"] for s in states] == list(range(1, epochs + 1))
    assert [s["val_accuracy"] for s in states] == [row["val_accuracy"] for row in with_progress["curve"]]
    last = json.loads((tmp_path / f"{with_progress['cell_id']}.json").read_text())
    assert last["epoch"] == epochs and last["max_epochs"] == 8 and last["pid"] == os.getpid()
    assert [e[0] for e in last["epochs"]] == list(range(1, epochs + 1))
    assert {"model", "dataset", "fold", "seed", "host", "elapsed", "updated", "seconds", "train_seconds"} <= set(last)
    assert last["train_seconds"] == pytest.approx(sum(row["seconds"] for row in with_progress["curve"]), abs=0.01)
    assert not [p for p in tmp_path.iterdir() if p.suffix == ".tmp"]  # replaced atomically


def test_a_progress_folder_that_is_not_there_never_fails_the_cell(tmp_path: Path) -> None:
    record = run_cell(_tiny_task(tmp_path / "absent"))  # a remote worker without the shared --out
    assert record["status"] == "ok" and not (tmp_path / "absent").exists()

    def broken(state: dict[str, Any]) -> None:
        raise OSError("the terminal went away")

    with progress.listening(broken):
        assert run_cell(_tiny_task(tmp_path))["status"] == "ok"  # a display that cannot draw fails nothing
    writer = ProgressWriter(tmp_path, {"cell_id": "c", "model": "m", "dataset": "d", "fold": 0, "seed": 0}, 3)
    (tmp_path / "c.json").mkdir()  # os.replace onto a folder fails: progress turns off, no exception
    writer({"epoch": 1, "val_accuracy": 0.5, "seconds": 0.1})
    assert not writer.enabled


def test_local_run_logs_every_epoch_and_the_eta_then_cleans_up(tmp_path: Path, capsys: pytest.CaptureFixture
                                                                ) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_blobs", "--no-plots", "--out",
                    str(out)]) == 0
    err = capsys.readouterr().err
    for model in ("tiny_mlp", "tiny_rate"):
        lines = [line for line in err.splitlines() if line.startswith(f"{model} x tiny_blobs fold 0 seed 0: epoch")]
        assert [line.split("epoch ")[1].split(" ")[0] for line in lines] == [f"{e}/8" for e in range(1, 9)]
    assert "1/2 cells done, eta " in err
    assert not list((out / "progress").iterdir())
    assert all(json.loads(p.read_text())["attempts"] == 1 for p in (out / "cells").glob("*.json"))


def test_quiet_flags_silence_progress_but_not_results(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    args = ["bench", "--plugin-module", "tiny_zoo", "--models", "tiny_mlp", "--datasets", "tiny_blobs",
            "--no-plots"]
    assert main(["-q", *args, "--out", str(tmp_path / "a")]) == 0  # logging: warnings and errors only
    printed = capsys.readouterr()
    assert "epoch 1/8" not in printed.err and "[1/1] ok" in printed.out
    assert main([*args, "-q", "--out", str(tmp_path / "b")]) == 0  # bench -q: no progress, no per-cell lines
    printed = capsys.readouterr()
    assert "epoch 1/8" not in printed.err and "[1/1] ok" not in printed.out and "done: 1 ok" in printed.out


def test_verbosity_and_warnings(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    import tactile_zoo.cli.bench as bench_cli

    def talk(args: Any) -> int:
        log = logging.getLogger("tactile_zoo.bench.x")
        log.debug("a debug line")
        log.info("an info line")
        warnings.warn("a plugin was skipped", registry.PluginWarning, stacklevel=1)
        return 0

    monkeypatch.setattr(bench_cli, "_cmd_report", talk)
    for flags, shown, hidden in (([], ["an info line"], ["a debug line"]),
                                 (["-v"], ["an info line", "tactile-zoo: debug: a debug line"], []),
                                 (["-q"], [], ["an info line", "a debug line"])):
        assert main([*flags, "report", "somewhere"]) == 0
        err = capsys.readouterr().err
        assert "tactile-zoo: warning: a plugin was skipped" in err  # at every verbosity
        assert all(s in err for s in shown) and not any(s in err for s in hidden)
    assert not logging.getLogger("tactile_zoo").handlers  # the CLI's handler lives only as long as the command


def test_report_lists_running_cells(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "progress").mkdir()
    writer = ProgressWriter(tmp_path / "progress", {"cell_id": "convlstm__sim__f0__s0__h", "model": "convlstm",
                                                    "dataset": "sim_evtouch", "fold": 0, "seed": 0}, 15)
    writer({"epoch": 3, "val_accuracy": 0.4125, "seconds": 41.2})
    assert main(["report", str(tmp_path), "--running"]) == 0
    text = capsys.readouterr().out
    assert "running convlstm x sim_evtouch fold 0 seed 0: epoch 3/15 val_acc 0.412 41.2s, updated" in text
    assert f"(pid {os.getpid()} on " in text
    torn = tmp_path / "progress" / ".convlstm__sim__f0__s0__h.json.0a1b2c3d4e5f.tmp"  # a write its worker never ended
    other = tmp_path / "progress" / ".dcnn__sim__f0__s0__h.json.0a1b2c3d4e5f.tmp"  # another cell's: left alone
    torn.write_text("{")
    other.write_text("{")
    progress.remove_progress(tmp_path, "convlstm__sim__f0__s0__h")
    assert main(["report", str(tmp_path), "--running"]) == 0
    assert "no cell is running" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "progress").iterdir()) == [other.name]


_WRITE_AND_EXIT = """
import sys
from tactile_zoo.bench.progress import ProgressWriter
writer = ProgressWriter(sys.argv[1], {"cell_id": "c", "model": "tiny_mlp", "dataset": "tiny_blobs", "fold": 0,
                                      "seed": 0}, 8)
writer({"epoch": 2, "val_accuracy": 0.5, "seconds": 1.0})
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="tells processes apart by their /proc start time")
def test_report_running_checks_the_process_behind_each_progress_file(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture) -> None:
    """Issue 38: a progress file outlives a killed run; ``report --running`` listed its dead pid as running. Now a
    cell is running only while the process that writes its file exists and is the same process (not a later one
    given the same pid); anything else is listed as stopped, and a process on another host as not checked."""
    import socket

    from forked_bench import run_python

    folder = tmp_path / "progress"
    folder.mkdir()
    # a process of its own that writes the file and exits: forked from the warm server (tests/forked_bench.py), not
    # a new interpreter importing torch and the package, since how it started is not what is checked here
    run_python(_WRITE_AND_EXIT, [str(folder)], tmp_path / "writer", timeout=120)
    (state,) = progress.running_cells(tmp_path)  # written by a process that has exited since
    assert state["pid"] != os.getpid() and state["pid_start"] and progress.process_alive(
        state["pid"], state["host"], state["pid_start"]) is False
    assert main(["report", str(tmp_path), "--running"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == [f"stopped tiny_mlp x tiny_blobs fold 0 seed 0: epoch 2/8 val_acc 0.500 1.0s, updated "
                     f"{lines[0].split('updated ')[1].split(' ago')[0]} ago (pid {state['pid']} on "
                     f"{socket.gethostname()} is no longer running: the run was interrupted or killed; rerunning "
                     f"its bench command resumes the cell)", f"no cell is running in {tmp_path}"]
    me = {**state, "cell_id": "d", "pid": os.getpid(), "pid_start": progress.process_start(os.getpid())}
    assert progress.process_alive(me["pid"], me["host"], me["pid_start"]) is True
    for name, change in (("alive", {}), ("reused", {"pid_start": "another boot:1"}), ("remote", {"host": "elsewhere"})):
        (folder / f"{name}.json").write_text(json.dumps({**me, "cell_id": name, **change}))
    (folder / "c.json").unlink()
    assert main(["report", str(tmp_path), "--running"]) == 0
    text = capsys.readouterr().out
    assert "running tiny_mlp x tiny_blobs fold 0 seed 0: epoch 2/8" in text and "no cell is running" not in text
    alive, remote, reused = text.splitlines()  # by file name
    assert alive.startswith("running ") and alive.endswith(f"(pid {os.getpid()} on {socket.gethostname()})")
    assert remote.startswith("running ") and remote.endswith(f"(pid {os.getpid()} on elsewhere, another host: "
                                                             f"not checked)")
    assert reused.startswith("stopped ") and "is no longer running" in reused  # the pid is now another process


def test_display_logs_each_epoch_once_and_notices_a_restart(tmp_path: Path, caplog: pytest.LogCaptureFixture
                                                            ) -> None:
    display = ProgressDisplay(tmp_path, None, enabled=True, live=False)  # type: ignore[arg-type]
    base = {"cell_id": "c", "model": "m", "dataset": "d", "fold": 0, "seed": 1, "max_epochs": 4, "host": "h",
            "elapsed": 2.0, "updated": time.time()}
    with caplog.at_level(logging.INFO, logger="tactile_zoo"):
        display.show({**base, "pid": 1, "epoch": 2, "epochs": [[1, 0.5, 1.0], [2, 0.6, 1.0]]})
        display.show({**base, "pid": 1, "epoch": 2, "epochs": [[1, 0.5, 1.0], [2, 0.6, 1.0]]})  # polled again
        display.show({**base, "pid": 2, "epoch": 1, "epochs": [[1, 0.5, 1.0]]})  # another worker took it over
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["m x d fold 0 seed 1: epoch 1/4 val_acc 0.500 1.0s",
                     "m x d fold 0 seed 1: epoch 2/4 val_acc 0.600 1.0s",
                     "m x d fold 0 seed 1: restarted (pid 2 on h) after its worker was lost",
                     "m x d fold 0 seed 1: epoch 1/4 val_acc 0.500 1.0s"]


def _record(model: str, dataset: str, seconds: float, epochs: int, max_epochs: int = 10) -> dict[str, Any]:
    return {"status": "ok", "model": model, "dataset": dataset, "seconds": seconds, "epochs_run": epochs,
            "config": {"recipe": {"max_epochs": max_epochs}}}


def test_cost_model_weights_cells_by_what_they_cost() -> None:
    costs = CostModel([_record("convlstm", "a", 600.0, 10), _record("sgnet", "a", 10.0, 5),
                       _record("failed", "a", 1.0, 1) | {"status": "failed"}])
    config = {"recipe": {"max_epochs": 10}}
    assert costs.epoch_seconds("convlstm", "a") == 60.0
    assert costs.epoch_seconds("convlstm", "b") == 60.0  # the same model on another dataset
    assert costs.epoch_seconds("new", "a") == pytest.approx(31.0)  # any finished cell
    assert CostModel().epoch_seconds("new", "a") == progress.DEFAULT_EPOCH_SECONDS  # nothing known: the recipe
    assert costs.expected_epochs("sgnet", "a", config) == 5.0  # early stopping learned
    assert costs.remaining("convlstm", "a", config) == 600.0
    assert costs.remaining("sgnet", "a", config) == 10.0
    # a running cell goes at its own pace: 4 of 10 epochs in 100 s -> 6 more at 25 s
    assert costs.remaining("convlstm", "a", config, {"epoch": 4, "train_seconds": 100.0, "elapsed": 130.0}) == 150.0
    assert costs.eta([600.0, 10.0, 10.0, 10.0], slots=2) == 600.0  # the long cell dominates, not a flat average
    assert costs.eta([100.0, 100.0, 100.0, 100.0], slots=2) == 200.0
    assert costs.eta([], slots=2) == 0.0


def test_format_seconds() -> None:
    assert [progress.format_seconds(s) for s in (None, 4.4, 75, 3725)] == ["?", "4s", "1m15s", "1h02m"]


def test_py_typed_is_shipped() -> None:
    import tactile_zoo

    assert (Path(tactile_zoo.__file__).parent / "py.typed").is_file()
    project = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["tactile_zoo"]

