"""Running one cell anywhere (this process, a worker process, a Dask worker) and returning a JSON-able record.

:func:`run_cell` never raises for a problem of the cell itself: an exception in the model, a non-finite loss or an
out-of-memory error become a record with ``status="failed"``, the error and its traceback, so the grid goes on.
``KeyboardInterrupt`` and ``SystemExit`` do propagate (Ctrl-C stops the run). A model whose constructor raises
:class:`~tactile_zoo.errors.ModelCannotConsume` declares that it cannot consume the dataset: ``status="skipped"``.
Nothing else becomes a skip: a bad hyper-parameter value is refused before any cell runs (:mod:`.grid`).
"""

from __future__ import annotations

import gc
import json
import socket
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from .. import registry
from .._files import atomic_path
from ..engine.cell import CellResult, train_cell
from ..engine.config import CellConfig
from ..engine.malloc import tune_malloc
from ..engine.runtime import cpu_isa, cpu_model, flush_denormals, resolve_device, set_threads, versions
from ..errors import ConfigError, ModelCannotConsume
from .progress import ProgressWriter
from .schema import RECORD_FORMAT, nan_to_null
from .teachers import Teacher, find_teachers

__all__ = ["CellTask", "run_cell", "setup_worker", "save_weights", "RECORD_FORMAT"]


@dataclass(frozen=True)
class CellTask:
    """Everything a worker needs to run a cell (picklable; nothing refers to the parent process)."""

    model: str
    dataset: str
    fold: int
    seed: int
    config_hash: str
    cell_id: str
    config: CellConfig  # resolved once by the grid, shipped as it is (picklable), never resolved again
    protocol: str = "fixed"
    extra_splits: tuple[str, ...] = ()
    root: str | None = None
    download: bool = False
    device: str = "auto"
    threads: int | None = None
    plugin_modules: tuple[str, ...] = ()
    sys_path: tuple[str, ...] = field(default=(), compare=False)
    #: the run's progress folder (``--out/progress``): the worker writes the cell's epochs there (see .progress)
    progress_dir: str | None = field(default=None, compare=False)
    #: the tactile-zoo commit of the bench command that scheduled the cell (``+dirty``: uncommitted changes;
    #: ``None``: not a git checkout); an audit compares it with the commit that froze a recipe
    commit: str | None = field(default=None, compare=False)
    #: ``--save-weights``: the folder the worker writes the trained weights to (``<cell id>.safetensors``)
    weights_dir: str | None = field(default=None, compare=False)
    #: ``--tracker``: log the finished cell to this tracker (tensorboard or mlflow) under ``tracker_dir``
    tracker: str | None = field(default=None, compare=False)
    tracker_dir: str | None = field(default=None, compare=False)
    #: distillation: the bench folder holding the cell's teachers (the ``teachers`` setting's, resolved)
    teacher_dir: str | None = field(default=None, compare=False)


# ----------------------------------------------------------------------------------------------- worker set-up
_SETUP: dict[str, Any] = {}


def setup_worker(plugin_modules: tuple[str, ...] = (), threads: int | None = None, sys_path: tuple[str, ...] = ()
                 ) -> None:
    """Idempotent per-process set-up: malloc settings, the parent's import path, plugin modules, torch threads."""
    tune_malloc()  # more large freed blocks come back already faulted in (tactile_zoo.engine.malloc)
    for path in sys_path:
        if path not in sys.path:
            sys.path.append(path)
    if tuple(plugin_modules) != _SETUP.get("plugins"):
        registry.import_plugin_modules(plugin_modules)
        _SETUP["plugins"] = tuple(plugin_modules)
    set_threads(threads)
    if not _SETUP.get("warm"):
        # the first optimiser step of a process imports torch._dynamo (seconds): pay it before any cell's clock runs
        param = torch.zeros(1, requires_grad=True)
        optimizer = torch.optim.Adam([param])
        param.sum().backward()
        optimizer.step()
        _SETUP["warm"] = True


# ----------------------------------------------------------------------------------------------- the cell
def _error_text(exc: BaseException) -> str:
    text = str(exc).strip().replace("\n", " ")
    if isinstance(exc, torch.cuda.OutOfMemoryError) or isinstance(exc, MemoryError):
        text = f"out of memory: {text}" if text else "out of memory"
    return f"{type(exc).__name__}: {text}"[:2000]


def _base_record(task: CellTask) -> dict[str, Any]:
    return {"format": RECORD_FORMAT, "cell_id": task.cell_id, "model": task.model, "dataset": task.dataset,
            "fold": task.fold, "seed": task.seed, "config_hash": task.config_hash, "protocol": task.protocol,
            "status": "failed", "error": None, "config": task.config.to_dict(), "host": socket.gethostname(),
            "cpu": cpu_model(), "cpu_isa": cpu_isa(), "versions": versions(), "commit": task.commit,
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


#: decimals kept of each stored class probability: enough to average seeds into an ensemble, a third of the bytes
PROBABILITY_DECIMALS = 6
#: test splits larger than this keep targets and predictions but no class probabilities. BioTac-DoS's whole test
#: split (5290 windows; 10705 for the sliding-window models SGnet and ConvLSTM) is over it; its three unseen sets
#: (1519-2250 windows; 3076-4549) are not, and store theirs, so that seed ensembles can be read on the textures set
#: the paper reports. 5000 covers the largest, 4549, with 10 % to spare and stays below 5290, so the 1-window models
#: keep storing the subsets rather than their whole split (issue 51; before, 2500 left SGnet's and ConvLSTM's out)
MAX_PROBABILITY_ROWS = 5000


def _eval_dict(result: Any, groups: list[int] | None, probabilities: bool) -> dict[str, Any]:
    out: dict[str, Any] = {"targets": result.targets, "predictions": result.predictions}
    if groups is not None and len(set(groups)) < len(groups):
        out["groups"] = groups  # samples share recordings: intervals resample recordings, not samples
    if probabilities and len(result.targets) <= MAX_PROBABILITY_ROWS:
        out["probabilities"] = [[round(p, PROBABILITY_DECIMALS) for p in row] for row in result.probabilities]
    return out


def _predictions(result: CellResult) -> dict[str, Any]:
    """Each test split's targets and predictions, and the class probabilities of the splits that are small enough:
    the main ``test`` split, or, when it is too large, its extra splits (subsets such as ``test_textures``); storing
    both would repeat the same rows, which once made a BioTac-DoS record 4.5 MB."""
    main = result.tests.get("test")
    main_stored = main is not None and len(main.targets) <= MAX_PROBABILITY_ROWS
    return {name: _eval_dict(ev, result.test_groups.get(name), name == "test" or not main_stored)
            for name, ev in result.tests.items()}


def _ok_record(result: CellResult) -> dict[str, Any]:
    fit = result.fit
    # the measured numbers go through nan_to_null: JSON has no NaN, and an empty split's scores (NaN from
    # engine.metrics) or a validation loss that overflowed are written null; the schema says where null may stand
    return dict(
        status="ok", n_train=result.n_train, n_val=result.n_val, n_test=result.n_test, spec=result.spec.to_dict(),
        class_names=list(result.spec.class_names),
        metrics=nan_to_null({"val": fit.val.metrics if fit.val is not None else None,
                             **{name: ev.metrics for name, ev in result.tests.items()}}),
        predictions=_predictions(result),
        curve=nan_to_null(fit.curve), refit_curve=nan_to_null(fit.refit_curve), best_epoch=fit.best_epoch,
        epochs_run=fit.epochs_run, train_seconds=round(fit.train_seconds, 3), prefix=nan_to_null(result.prefix),
        infer_ms_per_sample=result.infer_ms_per_sample, params=fit.params, peak_memory_mb=result.peak_memory_mb,
        peak_memory_source=result.peak_memory_source, peak_gpu_memory_mb=result.peak_gpu_memory_mb,
        recipe=fit.recipe.to_dict(), test_reads=result.test_reads,
        **({"reference": nan_to_null(result.reference)} if result.reference is not None else {}))


def save_weights(model: torch.nn.Module, path: Path, metadata: dict[str, str]) -> dict[str, Any]:
    """Write ``model``'s state dict as safetensors (atomically) and return ``{file, sha256, bytes}`` for the record.

    The file is the cell's own trained model, written by the run that computed the cell, so the accuracy in the
    record is the accuracy of exactly these weights.
    """
    from safetensors.torch import save

    from ..data.base import file_sha256

    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    with atomic_path(path) as tmp:
        tmp.write_bytes(_sorted_metadata(save(tensors, metadata=metadata)))
    return {"file": f"weights/{path.name}", "sha256": file_sha256(path), "bytes": path.stat().st_size}


def _sorted_metadata(data: bytes) -> bytes:
    """``data`` (a safetensors file) with its ``__metadata__`` keys in sorted order.

    safetensors writes the metadata map in a random order on every call, so two runs that trained the same tensors
    would write files with different sha256; sorting makes a deterministic rerun reproduce the file byte for byte.
    The header is a JSON object after its 8-byte length, padded with spaces; reordering keys keeps its length.
    """
    n = int.from_bytes(data[:8], "little")
    header = json.loads(data[8:8 + n])
    if "__metadata__" not in header:
        return data
    header["__metadata__"] = dict(sorted(header["__metadata__"].items()))
    text = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
    if len(text) > n:  # cannot happen for a pure reordering; keep the original rather than corrupt the file
        return data
    return data[:8] + text + b" " * (n - len(text)) + data[8 + n:]


def _teachers(task: CellTask) -> list[Teacher]:
    """The cell's teachers, found and checked in its teachers' folder (none for a cell that distils nothing)."""
    if not task.config.teacher_seeds:
        return []
    if task.teacher_dir is None:
        raise ConfigError(f"{task.cell_id}: the cell distils from teachers, but no teachers folder was given")
    return find_teachers(task.teacher_dir, task.config, task.fold)


@flush_denormals()
def run_cell(task: CellTask, progress: bool = False) -> dict[str, Any]:
    """Train and evaluate one cell (:func:`tactile_zoo.engine.cell.train_cell`); returns its record (``status`` ok,
    failed or skipped)."""
    record = _base_record(task)
    result = None
    start = time.perf_counter()
    try:
        setup_worker(task.plugin_modules, task.threads, task.sys_path)
        record["device"] = str(resolve_device(task.device))
        record["threads"] = torch.get_num_threads()
        config = task.config
        # the writer only reads each finished epoch's curve row: no RNG, no model state, so numbers are unchanged
        callback = ProgressWriter(task.progress_dir, record, config.recipe.max_epochs) if task.progress_dir else None
        teachers = _teachers(task)
        if teachers:  # which weights the student learnt from, whatever becomes of the teachers' folder later
            record["teachers"] = [t.to_record() for t in teachers]
        try:
            result = train_cell(config, fold=task.fold, seed=task.seed, root=task.root, download=task.download,
                                device=task.device, extra_splits=task.extra_splits, progress=progress,
                                callback=callback, teachers=[t.path for t in teachers])
        except ModelCannotConsume as exc:  # the model declares it cannot consume this dataset
            record.update(status="skipped", error=f"model cannot consume this dataset: {exc}")
            return record
        record.update(_ok_record(result))
        if task.weights_dir is not None:
            record["weights"] = save_weights(result.fit.model, Path(task.weights_dir) / f"{task.cell_id}.safetensors",
                                             {"cell_id": task.cell_id, "config_hash": task.config_hash,
                                              "model": task.model, "dataset": task.dataset})
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # noqa: BLE001 - a cell's failure must never stop the grid
        record.update(status="failed", error=_error_text(exc), traceback=traceback.format_exc()[-8000:])
    finally:
        del result
        if torch.cuda.is_available():  # reference cycles may hold GPU tensors; on CPU a collection costs ~0.5 s
            gc.collect()
            torch.cuda.empty_cache()
        record["seconds"] = round(time.perf_counter() - start, 3)
        record["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    if task.tracker is not None and record["status"] == "ok":
        from .trackers import log_record

        # here, in the process that ran the cell (a pool or Dask worker too); a failure only warns
        log_record(task.tracker, record, task.tracker_dir or ".")
    return record
