"""``fit``, the engine's public entry point: train a model on a dataset with its recipe, select the epoch on
validation, evaluate on test.

It is the one public signature. A registered model name with a registered dataset name runs exactly the harness's
cell (:mod:`.cell`), so its numbers equal the leaderboard's; anything else (a module, or explicit splits) is resolved
here (the recipe through :func:`.config.resolve_model_recipe`, the one recipe resolution) and handed to the training
loop (:func:`.train.train_model`), which takes the resolved recipe as it is. Keeping the dispatch here, above both,
is what lets the cell use the loop without the loop importing the cell.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from .. import registry
from ..errors import ConfigError
from ..recipe import Recipe
from .build import build_model, load_splits
from .cell import train_cell
from .config import resolve_cell, resolve_model_recipe
from .tensors import as_split
from .train import FitResult, train_model

__all__ = ["fit"]


def fit(model: torch.nn.Module | str, dataset: Any, recipe: Recipe | dict[str, Any] | str | None = None, seed: int = 0,
        val_dataset: Any = None, device: str | torch.device = "auto", epochs: int | None = None, *,
        test_dataset: Any = None, refit: bool = False, hparams: dict[str, Any] | None = None, root: Any = None,
        fold: int = 0, dataset_kwargs: dict[str, Any] | None = None, progress: bool = True,
        callback: Callable[[dict[str, Any]], None] | None = None, cuda_graphs: bool | None = None) -> FitResult:
    """Train ``model`` on ``dataset`` (the train split) and select the epoch on ``val_dataset``.

    Args:
        model: a ``torch.nn.Module`` (trained in place), or a registered model name (built for the dataset's spec
            with ``hparams``, after seeding, so the initial weights repeat too).
        dataset: the training split, or a registered dataset name (then its ``train``/``val``/``test`` splits of
            ``fold`` are loaded from ``root`` with ``dataset_kwargs``, unless given explicitly). A model name with a
            dataset name runs exactly the harness's cell (:func:`tactile_zoo.engine.cell.train_cell`): the dataset's
            epoch budget applies and the numbers equal the leaderboard's for the same settings and thread count.
        recipe: a :class:`Recipe` (used as is), a registered recipe's name (``"source"``), a dict of overrides on
            top of the model's default recipe, or ``None`` for that default (the harness default for a model that
            registers none).
        seed: seeds model initialisation (name given), dropout and the batch order.
        val_dataset: the split that selects the epoch and drives early stopping; never the test split.
        device: ``"auto"`` (CUDA when available), ``"cpu"``, ``"cuda"``...
        epochs: replaces the recipe's ``max_epochs``.
        test_dataset: evaluated once, with the selected (or refit) model.
        refit: retrain on train + val for the selected epoch count (needs ``val_dataset``).
        progress: report the epochs (default ``True``): a bar when stderr is a terminal or in a notebook, else
            one INFO record per epoch on the ``tactile_zoo.progress`` logger, shown once logging is configured
            (:mod:`tactile_zoo.engine.progress`); ``False``: nothing.
        callback: called with each epoch's curve row.
        cuda_graphs: on a CUDA device, replay the training forward and backward of each full batch from CUDA graphs
            (:mod:`tactile_zoo.engine.cuda_graph`: one launch instead of one per kernel; not bit for bit the eager
            run, whose dropout masks it does not share). ``None`` (default) reads ``TACTILE_ZOO_CUDA_GRAPHS``; True on
            another device is an error.
    """
    if isinstance(model, str) and isinstance(dataset, str) and val_dataset is None and test_dataset is None:
        config = resolve_cell(model, dataset, recipe=recipe, hparams=hparams, epochs=epochs,
                              dataset_kwargs=dataset_kwargs, refit=refit)
        return train_cell(config, fold=fold, seed=seed, root=root, device=device, measure=False, progress=progress,
                          callback=callback, cuda_graphs=cuda_graphs).fit
    if isinstance(dataset, str):
        named = load_splits(dataset, root, fold, False, dataset_kwargs)
        dataset, val_dataset = named["train"], val_dataset if val_dataset is not None else named["val"]
        test_dataset = test_dataset if test_dataset is not None else named["test"]
    train = as_split(dataset)
    module, meta = _named_model(model, train.spec, hparams, seed)
    # a model built by the caller: the recipe's model and dataset settings cannot apply any more, only its training
    # keys (the by-name cell above applies all three)
    rec = resolve_model_recipe(meta, recipe if isinstance(recipe, str) else None, getattr(train.spec, "name", None),
                               None if isinstance(recipe, str) else recipe, epochs,
                               owner=f"model {meta.get('name', type(module).__name__)!r}").recipe
    return train_model(module, train, rec, seed, val_dataset, device, test_dataset=test_dataset, refit=refit,
                       progress=progress, callback=callback, cuda_graphs=cuda_graphs)


def _named_model(model: Any, spec: Any, hparams: dict[str, Any] | None, seed: int
                 ) -> tuple[torch.nn.Module, Any]:
    """A module (built from its registry name after seeding) and its registry metadata (its named recipes)."""
    if isinstance(model, str):
        return build_model(model, spec, hparams, seed), registry.get_model_entry(model).meta
    if not isinstance(model, torch.nn.Module):
        raise ConfigError(f"fit() needs a torch.nn.Module or a registered model name, got {type(model).__name__}")
    if hparams:
        raise ConfigError("hparams only apply when fit() builds the model from its name")
    return model, getattr(model, "zoo_meta", None) or {}
