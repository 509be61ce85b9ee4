"""``--tracker tensorboard`` and ``--tracker mlflow`` on ``bench`` (local, process and Dask executors) and ``train``:
what each cell logs is read back through the libraries' own readers (TensorBoard's ``EventAccumulator``, MLflow's
``MlflowClient`` on the local file store) and compared with the cell JSON, the source of truth. A tracker that fails
costs a warning, never a cell; a missing tracker library is one line naming the extra."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import ProcessRun, run_cli

from tactile_zoo.bench.rundir import BENCH_FORMAT
from tactile_zoo.cli import main

pytestmark = pytest.mark.xdist_group("tiny_bench")

ONE = ["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0", "--threads", "1", "--no-plots", "-q"]
TWO = [*ONE, "--datasets", "tiny_blobs,tiny_kfold", "--folds", "1"]  # two cells


@pytest.fixture(autouse=True)
def _file_store_allowed(monkeypatch: pytest.MonkeyPatch) -> None:
    """MLflow 3 opens its file store only with this opt-out, which a reader needs as the writer does (logging sets
    it in the processes that log; set here for the test's own reader, and undone after)."""
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")


def _cells(out: Path) -> dict[str, dict[str, Any]]:
    records = [json.loads(p.read_text()) for p in (out / "cells").glob("*.json")]
    return {r["cell_id"]: r for r in records}


def _tensorboard(logdir: Path) -> Any:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(logdir), size_guidance={"scalars": 0, "tensors": 0})
    acc.Reload()
    return acc


def _text(acc: Any, tag: str) -> str:
    return acc.Tensors(f"{tag}/text_summary")[0].tensor_proto.string_val[0].decode()


def _check_tensorboard(out: Path, record: dict[str, Any]) -> None:
    logdir = out / "tensorboard" / record["cell_id"]
    acc = _tensorboard(logdir)
    assert _text(acc, "params/config_hash") == record["config_hash"]
    assert _text(acc, "params/config.recipe.lr") == json.dumps(record["config"]["recipe"]["lr"])
    assert _text(acc, "params/config.model") == record["model"]
    curve = acc.Scalars("curve/val_loss")
    assert [e.step for e in curve] == [row["epoch"] for row in record["curve"]]
    assert [e.value for e in curve] == pytest.approx([row["val_loss"] for row in record["curve"]], rel=1e-6)
    [final] = acc.Scalars("test/accuracy")
    assert final.value == pytest.approx(record["metrics"]["test"]["accuracy"], rel=1e-6)
    assert record["cell_id"] in _text(acc, "cell")
    assert json.loads((logdir / "cell.json").read_text())["metrics"] == record["metrics"]


def _check_mlflow(out: Path, records: dict[str, dict[str, Any]]) -> None:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=(out / "mlruns").resolve().as_uri())
    experiment = client.get_experiment_by_name("tactile-zoo")
    runs = client.search_runs([experiment.experiment_id])
    assert sorted(r.info.run_name for r in runs) == sorted(records)
    for run in runs:
        record = records[run.info.run_name]
        assert run.info.status == "FINISHED"
        assert run.data.params["config_hash"] == record["config_hash"]
        assert run.data.params["config.recipe.batch_size"] == json.dumps(record["config"]["recipe"]["batch_size"])
        assert run.data.metrics["test/accuracy"] == pytest.approx(record["metrics"]["test"]["accuracy"])
        history = client.get_metric_history(run.info.run_id, "curve/val_accuracy")
        assert [(m.step, m.value) for m in sorted(history, key=lambda m: m.step)] == [
            (row["epoch"], pytest.approx(row["val_accuracy"])) for row in record["curve"]]
        artifact = Path(client.download_artifacts(run.info.run_id, "cell.json", str(out / "downloads" /
                                                                                        run.info.run_id)))
        logged = json.loads(artifact.read_text())
        assert logged["cell_id"] == record["cell_id"] and logged["config"] == record["config"]
        assert _untimed(logged["curve"]) == _untimed(record["curve"])


def _untimed(curve: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A curve without its seconds, which differ between two runs of one cell (train logs twice below)."""
    return [{k: v for k, v in row.items() if k != "seconds"} for row in curve]


def test_bench_logs_each_cell_to_tensorboard(tmp_path: Path) -> None:
    pytest.importorskip("tensorboard")
    out = tmp_path / "run"
    assert run_cli([*ONE, "--tracker", "tensorboard", "--out", str(out)]) == 0
    [record] = _cells(out).values()
    assert record["status"] == "ok"
    _check_tensorboard(out, record)


def test_process_workers_log_to_the_mlflow_file_store(process_run: ProcessRun) -> None:
    """The SMALL grid's 6 cells on 2 spawned workers, each worker logging the cells it ran (the run of
    tests/bench/conftest.py that test_executors.py checks against a local run)."""
    pytest.importorskip("mlflow")
    assert process_run.tracker == "mlflow" and process_run.code == 0, process_run.stderr
    records = _cells(process_run.out)
    assert len(records) == 6 and all(r["status"] == "ok" for r in records.values())
    _check_mlflow(process_run.out, records)


def test_dask_workers_log_tensorboard_event_files(dask_cluster: Any, tmp_path: Path) -> None:
    pytest.importorskip("tensorboard")
    out = tmp_path / "run"
    assert run_cli([*TWO, "--executor", "dask", "--scheduler", dask_cluster.scheduler_address, "--tracker",
                    "tensorboard", "--out", str(out)]) == 0
    records = _cells(out)
    assert len(records) == 2
    for record in records.values():
        _check_tensorboard(out, record)
        # written by a Dask worker process: event files are named events.out.tfevents.<time>.<host>.<pid>.<n>
        [events] = (out / "tensorboard" / record["cell_id"]).glob("events.out.tfevents.*")
        assert int(events.name.split(".")[-2]) != os.getpid()


def test_a_failing_tracker_costs_a_warning_never_the_cell(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("mlflow")
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"format": BENCH_FORMAT}))  # a bench folder: --out accepts it
    (out / "mlruns").write_text("not a folder: the file store cannot be created here")
    assert run_cli([*ONE, "--tracker", "mlflow", "--out", str(out)]) == 0
    # the command line prints warnings as one line each (a TrackerWarning from the library)
    assert "warning: tracker mlflow could not log cell tiny_mlp__tiny_blobs" in capsys.readouterr().err
    [record] = _cells(out).values()
    assert record["status"] == "ok" and record["metrics"]["test"]["accuracy"] >= 0


def test_a_missing_tracker_library_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setitem(sys.modules, "mlflow", None)  # what an environment without MLflow imports
    assert run_cli([*ONE, "--tracker", "mlflow", "--out", str(tmp_path / "run")]) != 0
    err = capsys.readouterr().err
    assert 'pip install "tactile-zoo[mlflow]"' in err
    assert not (tmp_path / "run" / "cells").exists() or not list((tmp_path / "run" / "cells").iterdir())


def test_train_logs_its_cell_to_both_trackers(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("tensorboard")
    pytest.importorskip("mlflow")
    for tracker in ("tensorboard", "mlflow"):
        assert main(["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--tracker", tracker,
                     "--tracker-dir", str(tmp_path), "--json", "-q"]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["tracker"]["name"] == tracker
    cell_id = summary["tracker"]["cell_id"]
    acc = _tensorboard(tmp_path / "tensorboard" / cell_id)
    assert [e.step for e in acc.Scalars("curve/train_loss")] == list(range(1, summary["epochs_run"] + 1))
    assert acc.Scalars("test/accuracy")[0].value == pytest.approx(summary["test"]["accuracy"])
    record = json.loads((tmp_path / "tensorboard" / cell_id / "cell.json").read_text())
    assert record["config_hash"] == cell_id.rsplit("__", 1)[1]
    assert {k: v for k, v in record["metrics"]["test"].items() if k != "confusion"} == summary["test"]
    _check_mlflow(tmp_path, {cell_id: record})


_RACE = """
import sys, time
from pathlib import Path
import mlflow.tracking  # imported before the start, so the workers' look-ups meet
from tactile_zoo.bench.trackers import log_record
folder, name = Path(sys.argv[1]), sys.argv[2]
(folder / f"{name}.ready").touch()
while not (folder / "go").exists():
    time.sleep(0.001)
assert log_record("mlflow", {"cell_id": name, "status": "ok", "metrics": {"test": {"accuracy": 0.5}}}, folder)
"""


def test_workers_logging_at_once_share_one_experiment(tmp_path: Path) -> None:
    """Four processes log their first cell at the same moment into a new store: one experiment ``tactile-zoo`` holds
    the four runs (the file store does not check names under a lock: without the tracker's own lock the workers
    made experiments named alike, and one's runs were missing from the other's)."""
    pytest.importorskip("mlflow")
    from forked_bench import fork_python
    from mlflow.tracking import MlflowClient

    names = [f"cell{i}" for i in range(4)]
    children = [fork_python(_RACE, [str(tmp_path), n], tmp_path / n, MLFLOW_ALLOW_FILE_STORE="true") for n in names]
    try:
        deadline = time.monotonic() + 120
        while not all((tmp_path / f"{n}.ready").exists() for n in names):
            assert time.monotonic() < deadline and all(c.poll() is None for c in children), \
                [c.communicate(1) for c in children if c.poll() is not None]
            time.sleep(0.01)
        (tmp_path / "go").touch()
        for child in children:
            assert child.wait(120) == 0, child.communicate(1)
    finally:
        for child in children:
            child.kill()
    client = MlflowClient(tracking_uri=(tmp_path / "mlruns").resolve().as_uri())
    named = [e for e in client.search_experiments() if e.name == "tactile-zoo"]
    assert len(named) == 1, [e.experiment_id for e in named]
    assert sorted(r.info.run_name for r in client.search_runs([named[0].experiment_id])) == names
