"""One cell: one model trained on one fold of one dataset with one seed, selected on validation, tested once.

This is the only place a cell is run. The harness (``tactile-zoo bench``, one call per cell, under any executor),
``tactile-zoo train`` and the by-name ``tactile_zoo.fit("sgnet", "sim_evtouch")`` all go through
:func:`~.config.resolve_cell` (what to run: a :class:`~.config.CellConfig`, resolved once in :mod:`.config`) and
:func:`train_cell` (running it, with the resolved recipe as it is), so the three cannot drift apart: the same
command-line settings give the same numbers whichever of them ran the cell. The splits and the model built by name
come from :mod:`.build`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from ..data.guard import tuning
from ..errors import ConfigError
from ..recipe import Recipe
from .build import build_model, load_splits
from .config import MERGED_EVALUATIONS, CellConfig
from .distill import load_teachers, teacher_probabilities
from .evaluate import EvalResult, evaluate, predict_scores, prefix_evaluation, time_inference
from .runtime import PeakMemory, flush_denormals, resolve_device
from .tensors import TensorSplit, concat, take
from .train import FitResult, train_model

__all__ = ["CellResult", "train_cell"]


# ----------------------------------------------------------------------------------------------- the cell
@dataclass
class CellResult:
    """A finished cell: the fit (``fit.test`` is the test split's evaluation) and what was measured after it."""

    config: CellConfig
    fold: int
    seed: int
    fit: FitResult
    tests: dict[str, EvalResult]  # "test" and any extra test split of the dataset
    spec: Any
    n_train: int
    n_val: int
    n_test: int
    device: str
    prefix: dict[str, Any] | None = None
    infer_ms_per_sample: float | None = None
    peak_memory_mb: float | None = None
    peak_memory_source: str | None = None
    peak_gpu_memory_mb: float | None = None
    reference: dict[str, Any] | None = None  # evaluation="reference": final and best-test-epoch accuracy
    #: how many trained states of the model were evaluated on the test split: 1 (validation), one per epoch
    #: (reference), 0 (tuning, where reading it raises)
    test_reads: int = 1
    #: per test split, the independent unit (recording) of each sample, in prediction order: what an interval resamples
    test_groups: dict[str, list[int]] = field(default_factory=dict)


@flush_denormals()
def train_cell(config: CellConfig, *, fold: int = 0, seed: int = 0, root: Any = None, download: bool = False,
               device: str | torch.device = "auto", extra_splits: Sequence[str] = (), measure: bool = True,
               progress: bool = False, callback: Callable[[dict[str, Any]], None] | None = None,
               teachers: Sequence[str | os.PathLike] = (), cuda_graphs: bool | None = None,
               read_test: bool = True) -> CellResult:
    """Load the splits, seed, build, fit (selecting on validation) and evaluate one cell; the test split is read once.

    Args:
        config: from :func:`resolve_cell`.
        fold, seed: the cell's fold and seed (the seed drives initial weights, dropout and the batch order).
        root, download: the data home, and whether missing raw files may be downloaded.
        device: ``"auto"``, ``"cpu"``, ``"cuda"``, ...
        extra_splits: further test splits of the dataset, evaluated with the selected model.
        measure: also evaluate the test split's prefixes and time inference (the harness's per-cell extras).
        progress, callback: report the epochs (:mod:`.progress`: a bar on a terminal, log records otherwise); a
            function called with each epoch's curve row.
        teachers: distillation: the weight files of the cell's teachers, one per ``config.teacher_seeds`` in order
            (:mod:`.distill`; the harness finds and checks them).
        cuda_graphs: replay the training forward from CUDA graphs (:mod:`.cuda_graph`); None reads
            ``TACTILE_ZOO_CUDA_GRAPHS`` on a CUDA device.
        read_test: False trains the same model and neither loads nor evaluates a test split (``tests`` is empty,
            ``test_reads`` 0): how :mod:`tactile_zoo.bench.rebuild` remakes a finished cell's weights without a
            second read of its test split. Loading and evaluating come after every random draw of the fit, so the
            weights are the same either way.

    Raises:
        ModelCannotConsume: the model's constructor refused the dataset.
        ConfigError: teachers given to a cell without ``teacher_seeds``, or not one per teacher seed; ``read_test``
            False for a ``reference`` cell, whose training reads the test split after every epoch.
    """
    if teachers and not config.teacher_seeds:
        raise ConfigError(f"{config.model} on {config.dataset}: teacher weights given, but the cell has no teachers")
    if not read_test and config.evaluation == "reference":
        raise ConfigError(f"{config.model} on {config.dataset}: a reference cell reads the test split after every "
                          "epoch of its training, so it cannot be trained without reading it (read_test=False)")
    if config.evaluation == "tuning":
        with tuning():
            return _tune_cell(config, fold, seed, root, download, resolve_device(device), progress, callback,
                              teachers, cuda_graphs)
    dev = resolve_device(device)
    test_names = ("test", *extra_splits) if read_test else ()
    splits = load_splits(config.dataset, root, fold, download, config.dataset_kwargs, ("train", "val", *test_names))
    subset = config.subset or {}
    train = take(splits["train"], subset.get("train"))
    val = take(splits["val"], subset.get("val"))
    tests = {name: take(splits[name], subset.get("test")) for name in test_names}
    rec = config.recipe
    prefix = infer_ms = reference = None
    with PeakMemory(dev) as peak:
        train, val = _taught(config, teachers, train, val, dev)
        model = build_model(config.model, train.spec, config.hparams, seed, config.model_revision)
        if config.evaluation == "reference":
            result, reference = _fit_reference(model, train, val, tests["test"], rec, seed, dev, progress, callback,
                                               cuda_graphs)
        elif config.evaluation == "final":  # the resolved recipe copied without early stopping, not resolved again
            result = train_model(model, concat(train, val), recipe=replace(rec, patience=None), seed=seed, device=dev,
                                 progress=progress, callback=callback, cuda_graphs=cuda_graphs)
        else:
            result = train_model(model, train, recipe=rec, seed=seed, val_dataset=val, device=dev,
                                 refit=config.refit, progress=progress, callback=callback, cuda_graphs=cuda_graphs)
        evals = {name: evaluate(result.model, split, loss=rec.loss, batch_size=rec.eval_batch_size, progress=False)
                 for name, split in tests.items()}
        if measure and read_test:
            prefix = prefix_evaluation(result.model, tests["test"], config.prefixes or (1.0,), causal=config.causal,
                                       loss=rec.loss, batch_size=rec.eval_batch_size)
            infer_ms = time_inference(result.model, tests["test"])
    result.test = evals.get("test")
    if reference is not None:
        reference["final_epoch_accuracy"] = evals["test"].metrics["accuracy"]
    merged = config.evaluation in MERGED_EVALUATIONS  # trained on train + val, selected nothing
    return CellResult(config=config, fold=fold, seed=seed, fit=result, tests=evals, spec=train.spec,
                      n_train=len(train) + (len(val) if merged else 0), n_val=0 if merged else len(val),
                      n_test=len(tests["test"]) if read_test else 0, device=str(dev), prefix=prefix,
                      infer_ms_per_sample=infer_ms, peak_memory_mb=peak.mb, peak_memory_source=peak.source,
                      peak_gpu_memory_mb=peak.gpu_mb, reference=reference,
                      test_groups={name: split.unit_ids() for name, split in tests.items()},
                      test_reads=result.epochs_run if config.evaluation == "reference" else int(read_test))


def _taught(config: CellConfig, teachers: Sequence[str | os.PathLike], train: TensorSplit, val: TensorSplit,
            dev: torch.device) -> tuple[TensorSplit, TensorSplit]:
    """``train`` and ``val`` with the teachers' probabilities attached (unchanged for a cell without teachers).
    Both splits get them: a ``final`` cell and a refit train on train + val. The teachers are built before the
    student, whose :func:`build_model` seeds afresh, so they change none of its random draws."""
    if not config.teacher_seeds:
        return train, val
    models = load_teachers(config, train.spec, teachers)
    t, batch = config.recipe.distill_temperature, config.recipe.eval_batch_size
    return (replace(train, soft=teacher_probabilities(models, train, t, batch, dev)),
            replace(val, soft=teacher_probabilities(models, val, t, batch, dev)))


def _tune_cell(config: CellConfig, fold: int, seed: int, root: Any, download: bool, dev: torch.device,
               progress: bool, callback: Callable[[dict[str, Any]], None] | None,
               teachers: Sequence[str | os.PathLike] = (), cuda_graphs: bool | None = None) -> CellResult:
    """The ``tuning`` evaluation: :func:`train_cell` without the test split (called inside the tuning guard)."""
    splits = load_splits(config.dataset, root, fold, download, config.dataset_kwargs, ("train", "val"))
    subset = config.subset or {}
    train, val = take(splits["train"], subset.get("train")), take(splits["val"], subset.get("val"))
    with PeakMemory(dev) as peak:
        train, val = _taught(config, teachers, train, val, dev)
        model = build_model(config.model, train.spec, config.hparams, seed, config.model_revision)
        result = train_model(model, train, recipe=config.recipe, seed=seed, val_dataset=val, device=dev,
                             refit=config.refit, progress=progress, callback=callback, cuda_graphs=cuda_graphs)
    return CellResult(config=config, fold=fold, seed=seed, fit=result, tests={}, spec=train.spec, n_train=len(train),
                      n_val=len(val), n_test=0, device=str(dev), peak_memory_mb=peak.mb, peak_memory_source=peak.source,
                      peak_gpu_memory_mb=peak.gpu_mb, test_reads=0)


def _fit_reference(model: torch.nn.Module, train: Any, val: Any, test: Any, recipe: Recipe, seed: int,
                   device: torch.device, progress: bool, callback: Callable[[dict[str, Any]], None] | None,
                   cuda_graphs: bool | None = None) -> tuple[FitResult, dict[str, Any]]:
    """The ``reference`` evaluation: every training recording, the fixed epoch budget, the test split after each
    epoch, reduced on the spot to the final and the best epoch's accuracy (the per-epoch figures are not kept)."""
    best = {"accuracy": -1.0, "epoch": 0}

    def after_epoch(row: dict[str, Any]) -> None:
        scores = predict_scores(model, test.x, test.g, recipe.eval_batch_size, device)
        accuracy = float((scores.argmax(-1) == test.y).float().mean())
        if accuracy > best["accuracy"]:  # the first of equal epochs, as a running maximum does
            best.update(accuracy=accuracy, epoch=row["epoch"])
        if callback is not None:
            callback(row)

    result = train_model(model, concat(train, val), recipe=replace(recipe, patience=None), seed=seed, device=device,
                         progress=progress, callback=after_epoch, cuda_graphs=cuda_graphs)
    # final_epoch_accuracy is filled in by train_cell from its one evaluation of the test split
    return result, {"best_test_epoch_accuracy": best["accuracy"],
                    "best_test_epoch": best["epoch"], "epochs": result.epochs_run,
                    "note": "best_test_epoch_accuracy is chosen on the test set (the sources' optimistic protocol); "
                            "final_epoch_accuracy selects nothing"}
