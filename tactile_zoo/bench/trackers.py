"""Experiment trackers: a finished cell's record logged to TensorBoard or MLflow (``--tracker tensorboard|mlflow``).

The cell JSON stays the source of truth: a tracker gets a copy of what the record holds, after the cell finished, in
the process that ran it (this one, a worker of the process executor, a Dask worker), and a tracker that fails (not
installed on a worker, an unwritable folder, a full disk) costs a warning, never the cell. Both write to files on disk
under the tracker folder (``--tracker-dir``; bench: the run folder ``--out``), so workers need no server:

* ``tensorboard``: event files in ``<dir>/tensorboard/<cell id>/`` (``tensorboard --logdir <dir>/tensorboard``);
* ``mlflow``: the file store ``<dir>/mlruns`` (``mlflow ui --backend-store-uri <dir>/mlruns``), experiment
  ``tactile-zoo`` (or the name given), one run per cell named by its cell id. MLflow 3 keeps that store in
  maintenance mode behind ``MLFLOW_ALLOW_FILE_STORE=true``, which logging sets (unless it is set already).

What is logged, from the record:

* parameters: the cell configuration flattened (``recipe.lr``, ``hparams.dim``, ``dataset_kwargs.window``...), its
  ``config_hash``, the cell id, model, dataset, fold and seed (TensorBoard: text summaries ``params/<key>``);
* per-epoch curves (``curve/<key>`` at step ``epoch``: train_loss, val_loss, val_accuracy, lr, seconds; a refit's as
  ``refit/<key>``);
* final metrics (``<split>/<metric>``: ``test/accuracy``, ``val/macro_f1``..., the confusion matrix left out),
  ``train_seconds`` and ``params_count``;
* the cell JSON as an artifact (MLflow: ``cell.json``; TensorBoard: ``cell.json`` next to the event files, and the
  text summary ``cell``).

TensorBoard (``torch.utils.tensorboard`` needs the ``tensorboard`` package) and MLflow are optional extras, imported
only when asked for: ``pip install "tactile-zoo[tensorboard]"`` / ``pip install "tactile-zoo[mlflow]"``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from ..errors import ConfigError

__all__ = ["TRACKERS", "check_tracker", "log_record", "flat_params", "TrackerWarning"]

#: tracker name -> (module that must import, the extra that installs it)
TRACKERS = {"tensorboard": ("tensorboard", "tensorboard"), "mlflow": ("mlflow", "mlflow")}
EXPERIMENT = "tactile-zoo"
#: MLflow refuses longer parameter values (its limit is 6000 characters); the cell JSON artifact has the whole config
MAX_PARAM_CHARS = 6000


class TrackerWarning(UserWarning):
    """A tracker could not log a cell (the cell itself is unaffected)."""


def check_tracker(name: str | None) -> str | None:
    """``name`` checked: ``None``, or a tracker whose library imports here; else one :class:`ConfigError` line
    naming the extra to install."""
    if name is None:
        return None
    if name not in TRACKERS:
        raise ConfigError(f"--tracker must be one of {', '.join(TRACKERS)}, got {name!r}")
    module, extra = TRACKERS[name]
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a module set to None in sys.modules, or one without a spec
        found = False
    if not found:
        raise ConfigError(f"--tracker {name} needs the {module} package: pip install \"tactile-zoo[{extra}]\"")
    return name


def flat_params(config: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{"recipe": {"lr": 0.001}}`` -> ``{"recipe.lr": "0.001"}``: every leaf as text (lists as JSON)."""
    out: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.update(flat_params(value, f"{name}."))
        else:
            text = value if isinstance(value, str) else json.dumps(value, sort_keys=True, default=str)
            out[name] = text[:MAX_PARAM_CHARS]
    return out


def _params(record: Mapping[str, Any]) -> dict[str, str]:
    labels = {k: record.get(k) for k in ("cell_id", "config_hash", "model", "dataset", "fold", "seed")}
    return {**flat_params(record.get("config") or {}, "config."), **flat_params(labels)}


def _curves(record: Mapping[str, Any]) -> list[tuple[str, float, int]]:
    """(key, value, epoch) of every number in the per-epoch curves."""
    out = []
    for name, rows in (("curve", record.get("curve")), ("refit", record.get("refit_curve"))):
        for row in rows or ():
            epoch = int(row.get("epoch", 0))
            out += [(f"{name}/{k}", float(v), epoch) for k, v in row.items()
                    if k != "epoch" and isinstance(v, int | float) and not isinstance(v, bool)]
    return out


def _finals(record: Mapping[str, Any]) -> dict[str, float]:
    out = {}
    for split, metrics in (record.get("metrics") or {}).items():
        for key, value in (metrics or {}).items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                out[f"{split}/{key}"] = float(value)
    for key, name in (("train_seconds", "train_seconds"), ("params", "params_count"), ("best_epoch", "best_epoch")):
        value = record.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool):
            out[name] = float(value)
    return out


def _record_json(record: Mapping[str, Any]) -> str:
    return json.dumps(record, indent=1, sort_keys=True, default=str)


def _tensorboard(record: Mapping[str, Any], folder: Path) -> Path:
    from torch.utils.tensorboard import SummaryWriter

    logdir = folder / "tensorboard" / str(record["cell_id"])
    logdir.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(log_dir=str(logdir))
    try:
        for key, value in _params(record).items():
            writer.add_text(f"params/{key}", value, 0)
        for key, value, epoch in _curves(record):
            writer.add_scalar(key, value, epoch)
        final_step = int(record.get("epochs_run") or 0)
        for key, value in _finals(record).items():
            writer.add_scalar(key, value, final_step)
        text = _record_json(record)
        writer.add_text("cell", f"```json\n{text}\n```", 0)
        (logdir / "cell.json").write_text(text, encoding="utf-8")
    finally:
        writer.close()
    return logdir


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``folder`` itself for the block (processes on one machine, or on a file system that
    maps ``flock`` to its own locks); unserialised where the platform or file system has none."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a file system without locks (some network mounts)
            pass
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


def _mlflow(record: Mapping[str, Any], folder: Path, experiment: str) -> str:
    import tempfile

    from mlflow.entities import Metric, Param
    from mlflow.tracking import MlflowClient

    # MLflow 3 keeps the file store in maintenance mode and refuses it unless this opt-out is set; it is the one
    # backend that needs no server and no database, so every worker of a run can write its own runs beside the others
    os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
    store = folder / "mlruns"
    store.mkdir(parents=True, exist_ok=True)
    # the file store gives a new experiment a random id and does not check its name under a lock: two workers that
    # both found no experiment made two named alike, and the runs of one were missing from the other (seen with 2
    # process workers). The look-up and the create hold the store's lock, so every worker finds the one experiment
    with _locked(store):
        client = MlflowClient(tracking_uri=store.resolve().as_uri())
        found = client.get_experiment_by_name(experiment)
        experiment_id = found.experiment_id if found is not None else client.create_experiment(experiment)
    run = client.create_run(experiment_id, run_name=str(record["cell_id"]),
                            tags={"status": str(record.get("status")), "tactile_zoo.cell_id": str(record["cell_id"])})
    run_id = run.info.run_id
    try:
        stamp = 0  # timestamps are not measurements here: the cell record has the real times
        params = [Param(k, v) for k, v in _params(record).items()]
        metrics = [Metric(k, v, stamp, step) for k, v, step in _curves(record)]
        final_step = int(record.get("epochs_run") or 0)
        metrics += [Metric(k, v, stamp, final_step) for k, v in _finals(record).items()]
        for i in range(0, max(len(params), len(metrics)), 100):  # MLflow takes at most 100 params per batch
            client.log_batch(run_id, metrics=metrics[i:i + 100], params=params[i:i + 100])
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "cell.json"
            path.write_text(_record_json(record), encoding="utf-8")
            client.log_artifact(run_id, str(path))
    except BaseException:
        client.set_terminated(run_id, "FAILED")
        raise
    client.set_terminated(run_id, "FINISHED")
    return run_id


def log_record(tracker: str | None, record: Mapping[str, Any], folder: str | Path, *, experiment: str = EXPERIMENT
               ) -> bool:
    """Log a cell ``record`` to ``tracker`` under ``folder`` (see the module docstring). Never raises for a tracker's
    failure: it warns (:class:`TrackerWarning`) and returns ``False``."""
    if tracker is None:
        return False
    try:
        if tracker == "tensorboard":
            _tensorboard(record, Path(folder))
        elif tracker == "mlflow":
            _mlflow(record, Path(folder), experiment)
        else:
            raise ConfigError(f"unknown tracker {tracker!r}")
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # noqa: BLE001 - the cell JSON is the source of truth: a tracker never costs it
        warnings.warn(f"tracker {tracker} could not log cell {record.get('cell_id')}: {type(exc).__name__}: {exc}",
                      TrackerWarning, stacklevel=2)
        return False
    return True
