"""Where a cell's ingredients come from: a dataset's splits and a model built from its registry name.

Both the training loop (:mod:`.train`, which accepts names) and the harness's cell (:mod:`.cell`) need them, so they
sit below both: the loop never has to import the cell to build a model.

- :func:`load_splits` is the one place a dataset's splits are loaded (memoised for consecutive cells).
- :func:`build_model` is the one place a model is built from its registry name (seeded first, so its initial weights
  depend on the seed only), at the revision a cell records. :class:`~tactile_zoo.errors.ModelCannotConsume` is the
  one signal that a model cannot take a dataset.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from .. import registry
from .runtime import seed_everything

__all__ = ["SPLITS", "load_splits", "build_model"]

SPLITS = ("train", "val", "test")


_SPLIT_CACHE: OrderedDict[str, dict[str, Any]] = OrderedDict()
_SPLIT_CACHE_SIZE = 2
def load_splits(name: str, root: Any = None, fold: int = 0, download: bool = False,
                kwargs: Mapping[str, Any] | None = None, splits: Sequence[str] = SPLITS) -> dict[str, Any]:
    """The requested splits of one fold of dataset ``name``.

    Memoised over the last two (dataset, root, fold, kwargs) keys: the harness runs model-innermost, so consecutive
    cells share a fold, and a loaded split (up to hundreds of MB of dense events) is not read twice.
    """
    kwargs = dict(kwargs or {})
    key = json.dumps([name, None if root is None else str(root), fold, kwargs], sort_keys=True, default=str)
    cached = _SPLIT_CACHE.setdefault(key, {})
    _SPLIT_CACHE.move_to_end(key)
    while len(_SPLIT_CACHE) > _SPLIT_CACHE_SIZE:
        _SPLIT_CACHE.popitem(last=False)
    for split in splits:
        if split not in cached:
            cached[split] = registry.load_dataset(name, root=root, split=split, fold=fold, download=download, **kwargs)
    return {split: cached[split] for split in splits}


def build_model(name: str, spec: Any, hparams: Mapping[str, Any] | None = None, seed: int = 0,
                revision: int | None = None) -> torch.nn.Module:
    """Model ``name`` built for ``spec`` right after seeding, so its initial weights depend on ``seed`` only, at
    revision ``revision`` (``None``: the model's default; a cell passes its recorded ``model_revision``).

    Raises:
        ModelCannotConsume: the model declares it cannot take this dataset (raised by its constructor, explicitly:
            a :class:`~tactile_zoo.errors.ConfigError` for a bad hyper-parameter value stays what it is, an error).
    """
    seed_everything(seed)
    return registry.instantiate_model(name, spec, revision=revision, **dict(hparams or {}))


