"""One cell: one model trained on one fold of one dataset with one seed, selected on validation, tested once.

This is the only place a cell is assembled. The harness (``tactile-zoo bench``, one call per cell, under any
executor), ``tactile-zoo train`` and the by-name ``tactile_zoo.fit("sgnet", "sim_evtouch")`` all go through
:func:`resolve_cell` (what to run) and :func:`train_cell` (running it), so the three cannot drift apart: the same
command-line settings give the same numbers whichever of them ran the cell.

- :class:`CellConfig` is the resolved configuration: the model with its constructor keywords, the fully resolved
  recipe (the dataset's epoch budget applied), the dataset with its keyword arguments, and the computational
  revisions of both, which the harness's cell hash covers.
- Its ingredients, the splits and the model built by name, come from :mod:`.build`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from .. import registry
from ..data.guard import tuning
from ..errors import ConfigError
from ..recipe import Recipe, cap_epochs, recipe_name_of, resolve_recipe
from .build import SPLITS, build_model, load_splits
from .evaluate import DEFAULT_PREFIXES, EvalResult, evaluate, predict_scores, prefix_evaluation, time_inference
from .runtime import PeakMemory, flush_denormals, resolve_device
from .tensors import concat, take
from .train import FitResult, train_model

__all__ = ["CellConfig", "CellResult", "EVALUATIONS", "MERGED_EVALUATIONS", "UNHASHED_KEYS", "resolve_cell",
           "train_cell"]

#: Keys of a stored cell configuration that are labels, not settings: the cell hash leaves them out.
UNHASHED_KEYS = ("causal", "recipe_name")
#: How a cell reaches its test figure.
#: ``validation`` (the zoo's honest protocol): the epoch is selected on the validation split, then the test split is
#: read once. ``reference`` (the protocol of the sources that publish their best test epoch): train on train + val
#: for the recipe's fixed epoch budget (no early stopping, nothing selected), evaluate the test split after every
#: epoch and keep only two numbers: the final epoch's accuracy (honest: nothing was chosen) and the best epoch's
#: (optimistic: chosen on the test set itself, reported only as the sources' figure). No per-epoch test curve is
#: stored, so it can never steer a later choice. ``tuning`` (for choosing a recipe): train and select on validation
#: exactly as ``validation`` does, but never read a test split: the cell runs in tuning mode
#: (:mod:`tactile_zoo.data.guard`), where loading one raises, and records the validation score only. ``final``
#: (honest, for a recipe whose epoch count was declared beforehand from validation evidence, such as ``full``):
#: train on train + val for the recipe's fixed epochs, nothing selected, and read the test split once, at the end.
EVALUATIONS = ("validation", "reference", "tuning", "final")
#: the evaluations that train on every training recording (train + val) and select nothing
MERGED_EVALUATIONS = ("reference", "final")


@dataclass(frozen=True)
class CellConfig:
    """What one cell runs, fold and seed aside: everything that can change its numbers.

    ``to_dict()`` is the plain form stored in a cell record; every key but ``causal`` (a property of the model, not
    a setting) and ``recipe_name`` (a label: the resolved recipe itself is hashed) enters the harness's cell hash.
    """

    model: str  # the listed registry name (``dist:name`` for a shadowed or clashing plugin)
    dataset: str
    recipe: Recipe
    recipe_name: str = "source"  # which of the model's named recipes ``recipe`` started from (overrides on top)
    model_source: str = "builtin"  # the plugin distribution, or "builtin"
    hparams: Mapping[str, Any] = field(default_factory=dict)
    dataset_kwargs: Mapping[str, Any] = field(default_factory=dict)
    refit: bool = False
    subset: Mapping[str, int] | None = None  # at most this many samples per split (``--quick``)
    prefixes: tuple[float, ...] = DEFAULT_PREFIXES
    causal: bool = False
    model_revision: int = registry.DEFAULT_REVISION
    dataset_revision: int = registry.DEFAULT_REVISION
    evaluation: str = "validation"  # or "reference", "tuning": see EVALUATIONS

    def hashed(self) -> dict[str, Any]:
        """The part of :meth:`to_dict` a cell hash covers."""
        return {"model": self.model, "model_source": self.model_source, "hparams": dict(self.hparams),
                "recipe": self.recipe.to_dict(), "dataset": self.dataset, "dataset_kwargs": dict(self.dataset_kwargs),
                "refit": self.refit, "subset": None if self.subset is None else dict(self.subset),
                "prefixes": list(self.prefixes), "model_revision": self.model_revision,
                "dataset_revision": self.dataset_revision,
                # the default is left out, so that the hashes of cells from before the setting existed still hold
                **({"evaluation": self.evaluation} if self.evaluation != "validation" else {})}

    def to_dict(self) -> dict[str, Any]:
        return {**self.hashed(), "causal": self.causal, "recipe_name": self.recipe_name}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> CellConfig:
        """The inverse of :meth:`to_dict` (a record's ``config``; revisions absent from older records mean 1)."""
        return cls(model=values["model"], dataset=values["dataset"],
                   recipe=Recipe.from_dict(values["recipe"], where=f"recipe of {values['model']}"),
                   recipe_name=recipe_name_of(values),
                   model_source=values.get("model_source", "builtin"), hparams=dict(values.get("hparams") or {}),
                   dataset_kwargs=dict(values.get("dataset_kwargs") or {}), refit=bool(values.get("refit")),
                   subset=values.get("subset") or None, prefixes=tuple(values.get("prefixes") or (1.0,)),
                   causal=bool(values.get("causal")),
                   model_revision=int(values.get("model_revision", registry.DEFAULT_REVISION)),
                   dataset_revision=int(values.get("dataset_revision", registry.DEFAULT_REVISION)),
                   evaluation=str(values.get("evaluation", "validation")))


def resolve_cell(model: str, dataset: str, *, recipe: Recipe | Mapping[str, Any] | str | None = None,
                 recipe_name: str | None = None,
                 hparams: Mapping[str, Any] | None = None, epochs: int | None = None,
                 dataset_kwargs: Mapping[str, Any] | None = None, refit: bool = False,
                 subset: Mapping[str, int] | None = None, prefixes: Sequence[float] = DEFAULT_PREFIXES,
                 evaluation: str | None = None) -> CellConfig:
    """The configuration of ``model`` on ``dataset``.

    Args:
        model: a registered model name, as listed (``list_models()``).
        dataset: a registered dataset name, as listed.
        recipe: overrides of single keys on top of the model's named recipe, a :class:`Recipe` used as is, or a
            recipe name (the same as ``recipe_name``).
        recipe_name: which of the model's registered recipes to start from (``"source"``...); default: the model's
            default recipe.
        hparams: the model's constructor keywords.
        epochs: replaces ``max_epochs`` (the CLI's ``--epochs``); without it the dataset's epoch budget (registry
            metadata ``max_epochs``) caps an overriding-dict or registered recipe, its schedule compressed to fit.
        dataset_kwargs: keyword arguments of the dataset.
        refit: retrain on train + val for the selected epoch count.
        subset: at most this many (class-balanced) samples per split, keyed ``train``/``val``/``test``.
        prefixes: early-classification prefix fractions evaluated on the test split.
        evaluation: one of :data:`EVALUATIONS`; default: the one the named recipe declares, else ``"validation"``.
    """
    if evaluation is not None and evaluation not in EVALUATIONS:
        raise ConfigError(f"--evaluation must be one of {', '.join(EVALUATIONS)}, got {evaluation!r}")
    entry = registry.get_model_entry(model)
    data_entry = registry.get_dataset_entry(dataset)
    if isinstance(recipe, str):
        recipe, recipe_name = None, recipe
    custom = isinstance(recipe, Recipe)
    named = registry.resolve_model_recipe(entry.meta, recipe_name, dataset, None if custom else recipe, epochs,
                                          owner=f"model {model!r}")
    # a named recipe may carry the model's and the dataset's settings; the user's own (hparams, dataset_kwargs) win
    evaluation = evaluation or named.evaluation or "validation"
    if evaluation in MERGED_EVALUATIONS and refit:
        raise ConfigError(f"--evaluation {evaluation} already trains on train + val; it does not combine with --refit")
    hparams = {**named.hparams, **dict(hparams or {})}
    dataset_kwargs = {**named.dataset_kwargs, **dict(dataset_kwargs or {})}
    if custom:
        name, resolved = "custom", resolve_recipe(recipe, None, epochs)
    else:
        name, resolved = named.name, named.recipe
        budget = data_entry.meta.get("max_epochs")
        if epochs is None and budget is not None:
            resolved = cap_epochs(resolved, int(budget))
    return CellConfig(model=model, dataset=dataset, recipe=resolved, recipe_name=name,
                      model_source=entry.dist or "builtin", hparams=dict(hparams or {}),
                      dataset_kwargs=dict(dataset_kwargs or {}), refit=bool(refit),
                      subset=dict(subset) if subset else None, prefixes=tuple(prefixes),
                      causal=bool(entry.meta.get("causal", False)), model_revision=registry.revision_of(entry),
                      dataset_revision=registry.revision_of(data_entry), evaluation=evaluation)


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
               progress: bool = False, callback: Callable[[dict[str, Any]], None] | None = None) -> CellResult:
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

    Raises:
        ModelCannotConsume: the model's constructor refused the dataset.
    """
    if config.evaluation == "tuning":
        with tuning():
            return _tune_cell(config, fold, seed, root, download, resolve_device(device), progress, callback)
    dev = resolve_device(device)
    splits = load_splits(config.dataset, root, fold, download, config.dataset_kwargs,
                         (*SPLITS, *extra_splits))
    subset = config.subset or {}
    train = take(splits["train"], subset.get("train"))
    val = take(splits["val"], subset.get("val"))
    tests = {name: take(splits[name], subset.get("test")) for name in ("test", *extra_splits)}
    rec = config.recipe
    prefix = infer_ms = reference = None
    with PeakMemory(dev) as peak:
        model = build_model(config.model, train.spec, config.hparams, seed)
        if config.evaluation == "reference":
            result, reference = _fit_reference(model, train, val, tests["test"], rec, seed, dev, progress, callback)
        elif config.evaluation == "final":
            result = train_model(model, concat(train, val), recipe=rec.replace(patience=None), seed=seed, device=dev,
                                 progress=progress, callback=callback)
        else:
            result = train_model(model, train, recipe=rec, seed=seed, val_dataset=val, device=dev,
                                 refit=config.refit, progress=progress, callback=callback)
        evals = {name: evaluate(result.model, split, loss=rec.loss, batch_size=rec.eval_batch_size, progress=False)
                 for name, split in tests.items()}
        if measure:
            prefix = prefix_evaluation(result.model, tests["test"], config.prefixes or (1.0,), causal=config.causal,
                                       loss=rec.loss, batch_size=rec.eval_batch_size)
            infer_ms = time_inference(result.model, tests["test"])
    result.test = evals["test"]
    if reference is not None:
        reference["final_epoch_accuracy"] = evals["test"].metrics["accuracy"]
    merged = config.evaluation in MERGED_EVALUATIONS  # trained on train + val, selected nothing
    return CellResult(config=config, fold=fold, seed=seed, fit=result, tests=evals, spec=train.spec,
                      n_train=len(train) + (len(val) if merged else 0), n_val=0 if merged else len(val),
                      n_test=len(tests["test"]), device=str(dev), prefix=prefix,
                      infer_ms_per_sample=infer_ms, peak_memory_mb=peak.mb, peak_memory_source=peak.source,
                      peak_gpu_memory_mb=peak.gpu_mb, reference=reference,
                      test_groups={name: split.unit_ids() for name, split in tests.items()},
                      test_reads=result.epochs_run if config.evaluation == "reference" else 1)


def _tune_cell(config: CellConfig, fold: int, seed: int, root: Any, download: bool, dev: torch.device,
               progress: bool, callback: Callable[[dict[str, Any]], None] | None) -> CellResult:
    """The ``tuning`` evaluation: :func:`train_cell` without the test split (called inside the tuning guard)."""
    splits = load_splits(config.dataset, root, fold, download, config.dataset_kwargs, ("train", "val"))
    subset = config.subset or {}
    train, val = take(splits["train"], subset.get("train")), take(splits["val"], subset.get("val"))
    with PeakMemory(dev) as peak:
        model = build_model(config.model, train.spec, config.hparams, seed)
        result = train_model(model, train, recipe=config.recipe, seed=seed, val_dataset=val, device=dev,
                             refit=config.refit, progress=progress, callback=callback)
    return CellResult(config=config, fold=fold, seed=seed, fit=result, tests={}, spec=train.spec, n_train=len(train),
                      n_val=len(val), n_test=0, device=str(dev), peak_memory_mb=peak.mb, peak_memory_source=peak.source,
                      peak_gpu_memory_mb=peak.gpu_mb, test_reads=0)


def _fit_reference(model: torch.nn.Module, train: Any, val: Any, test: Any, recipe: Recipe, seed: int,
                   device: torch.device, progress: bool, callback: Callable[[dict[str, Any]], None] | None
                   ) -> tuple[FitResult, dict[str, Any]]:
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

    result = train_model(model, concat(train, val), recipe=recipe.replace(patience=None), seed=seed, device=device,
                         progress=progress, callback=after_epoch)
    # final_epoch_accuracy is filled in by train_cell from its one evaluation of the test split
    return result, {"best_test_epoch_accuracy": best["accuracy"],
                    "best_test_epoch": best["epoch"], "epochs": result.epochs_run,
                    "note": "best_test_epoch_accuracy is chosen on the test set (the sources' optimistic protocol); "
                            "final_epoch_accuracy selects nothing"}
