"""Running one cell anywhere (this process, a worker process, a Dask worker) and returning a JSON-able record.

:func:`run_cell` never raises for a problem of the cell itself: an exception in the model, a non-finite loss or an
out-of-memory error become a record with ``status="failed"``, the error and its traceback, so the grid goes on.
``KeyboardInterrupt`` and ``SystemExit`` do propagate (Ctrl-C stops the run). A model whose constructor raises
:class:`~tactile_zoo.errors.ConfigError` for a dataset declares that it cannot consume it: ``status="skipped"``.
"""

from __future__ import annotations

import gc
import importlib
import json
import socket
import sys
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import torch

from .. import registry
from ..engine import (
    PeakMemory,
    Recipe,
    evaluate,
    fit,
    prefix_evaluation,
    resolve_device,
    seed_everything,
    take,
    time_inference,
)
from ..engine.runtime import flush_denormals, set_threads, versions
from ..errors import ConfigError, PluginError

__all__ = ["CellTask", "run_cell", "load_splits", "setup_worker", "import_plugin_modules", "RECORD_FORMAT"]

RECORD_FORMAT = 1


@dataclass(frozen=True)
class CellTask:
    """Everything a worker needs to run a cell (picklable; nothing refers to the parent process)."""

    model: str
    dataset: str
    fold: int
    seed: int
    config_hash: str
    cell_id: str
    config: dict[str, Any]
    protocol: str = "fixed"
    extra_splits: tuple[str, ...] = ()
    root: str | None = None
    download: bool = False
    device: str = "auto"
    threads: int | None = None
    plugin_modules: tuple[str, ...] = ()
    sys_path: tuple[str, ...] = field(default=(), compare=False)


# ----------------------------------------------------------------------------------------------- worker set-up
_SETUP: dict[str, Any] = {}


def import_plugin_modules(modules: tuple[str, ...] | list[str]) -> None:
    """Import modules that register models/datasets (``--plugin-module``); a failure names the module."""
    for module in modules:
        if module in sys.modules:
            continue
        try:
            importlib.import_module(module)
        except Exception as exc:
            raise PluginError(f"--plugin-module {module!r} cannot be imported: {type(exc).__name__}: {exc}") from None


def setup_worker(plugin_modules: tuple[str, ...] = (), threads: int | None = None, sys_path: tuple[str, ...] = ()
                 ) -> None:
    """Idempotent per-process set-up: the parent's import path, plugin modules, torch threads."""
    for path in sys_path:
        if path not in sys.path:
            sys.path.append(path)
    if tuple(plugin_modules) != _SETUP.get("plugins"):
        import_plugin_modules(plugin_modules)
        _SETUP["plugins"] = tuple(plugin_modules)
    set_threads(threads)
    if not _SETUP.get("warm"):
        # the first optimiser step of a process imports torch._dynamo (seconds): pay it before any cell's clock runs
        param = torch.zeros(1, requires_grad=True)
        optimizer = torch.optim.Adam([param])
        param.sum().backward()
        optimizer.step()
        _SETUP["warm"] = True


# ----------------------------------------------------------------------------------------------- data
_SPLIT_CACHE: OrderedDict[str, dict[str, Any]] = OrderedDict()
_SPLIT_CACHE_SIZE = 2


def load_splits(name: str, root: str | None, fold: int, download: bool, kwargs: dict[str, Any],
                splits: tuple[str, ...] = ("train", "val", "test")) -> dict[str, Any]:
    """The requested splits of one fold, memoised (the last two (dataset, fold) pairs) so consecutive cells of the
    same dataset and fold (the grid runs model-innermost) load it once."""
    key = json.dumps([name, root, fold, kwargs], sort_keys=True, default=str)
    cached = _SPLIT_CACHE.setdefault(key, {})
    _SPLIT_CACHE.move_to_end(key)
    while len(_SPLIT_CACHE) > _SPLIT_CACHE_SIZE:
        _SPLIT_CACHE.popitem(last=False)
    for split in splits:
        if split not in cached:
            cached[split] = registry.load_dataset(name, root=root, split=split, fold=fold, download=download, **kwargs)
    return {split: cached[split] for split in splits}


# ----------------------------------------------------------------------------------------------- the cell
def _error_text(exc: BaseException) -> str:
    text = str(exc).strip().replace("\n", " ")
    if isinstance(exc, torch.cuda.OutOfMemoryError) or isinstance(exc, MemoryError):
        text = f"out of memory: {text}" if text else "out of memory"
    return f"{type(exc).__name__}: {text}"[:2000]


def _base_record(task: CellTask) -> dict[str, Any]:
    return {"format": RECORD_FORMAT, "cell_id": task.cell_id, "model": task.model, "dataset": task.dataset,
            "fold": task.fold, "seed": task.seed, "config_hash": task.config_hash, "protocol": task.protocol,
            "status": "failed", "error": None, "config": task.config, "host": socket.gethostname(),
            "versions": versions(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def _eval_dict(result: Any) -> dict[str, Any]:
    return {"targets": result.targets, "predictions": result.predictions, "probabilities": result.probabilities}


@flush_denormals()
def run_cell(task: CellTask, progress: bool = False) -> dict[str, Any]:
    """Train and evaluate one cell; returns its record (``status`` ok, failed or skipped)."""
    record = _base_record(task)
    model = result = None
    start = time.perf_counter()
    try:
        setup_worker(task.plugin_modules, task.threads, task.sys_path)
        device = resolve_device(task.device)
        record["device"] = str(device)
        record["threads"] = torch.get_num_threads()
        cfg = task.config
        subset = cfg.get("subset") or {}
        splits = load_splits(task.dataset, task.root, task.fold, task.download, cfg.get("dataset_kwargs") or {},
                             ("train", "val", "test", *task.extra_splits))
        train = take(splits["train"], subset.get("train"))
        val = take(splits["val"], subset.get("val"))
        tests = {name: take(splits[name], subset.get("test")) for name in ("test", *task.extra_splits)}
        spec = train.spec
        record.update(n_train=len(train), n_val=len(val), n_test=len(tests["test"]), spec=spec.to_dict(),
                      class_names=list(spec.class_names))
        with PeakMemory(device) as peak:
            seed_everything(task.seed)  # the model's initial weights depend on the seed only
            try:
                model = registry.create_model(task.model, spec, **(cfg.get("hparams") or {}))
            except ConfigError as exc:  # the model declares it cannot consume this dataset
                record.update(status="skipped", error=f"model cannot consume this dataset: {exc}")
                return record
            recipe = Recipe.from_dict(cfg["recipe"], where=f"recipe of {task.model}")
            result = fit(model, train, recipe=recipe, seed=task.seed, val_dataset=val, device=device,
                         refit=bool(cfg.get("refit")), progress=progress)
            model = result.model
            evals = {name: evaluate(model, split, loss=recipe.loss, batch_size=recipe.eval_batch_size)
                     for name, split in tests.items()}
            prefix = prefix_evaluation(model, tests["test"], cfg.get("prefixes") or (1.0,),
                                       causal=bool(cfg.get("causal")), loss=recipe.loss,
                                       batch_size=recipe.eval_batch_size)
            infer_ms = time_inference(model, tests["test"])
        record.update(
            status="ok",
            metrics={"val": result.val.metrics if result.val is not None else None,
                     **{name: ev.metrics for name, ev in evals.items()}},
            predictions={name: _eval_dict(ev) for name, ev in evals.items()},
            curve=result.curve, refit_curve=result.refit_curve, best_epoch=result.best_epoch,
            epochs_run=result.epochs_run, train_seconds=round(result.train_seconds, 3), prefix=prefix,
            infer_ms_per_sample=infer_ms, params=result.params, peak_memory_mb=peak.mb,
            peak_memory_source=peak.source, peak_gpu_memory_mb=peak.gpu_mb, recipe=recipe.to_dict())
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # noqa: BLE001 - a cell's failure must never stop the grid
        record.update(status="failed", error=_error_text(exc), traceback=traceback.format_exc()[-8000:])
    finally:
        del model, result
        if torch.cuda.is_available():  # reference cycles may hold GPU tensors; on CPU a collection costs ~0.5 s
            gc.collect()
            torch.cuda.empty_cache()
        record["seconds"] = round(time.perf_counter() - start, 3)
        record["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    return record
