"""Deprecated alias of :mod:`tactile_zoo.nn.hugepages`, kept because release 0.2.0 documented this path: its two
names, :func:`~tactile_zoo.nn.hugepages.empty` and :data:`~tactile_zoo.nn.hugepages.MIN_BYTES`, live there now (the
pool of reused storages is :mod:`tactile_zoo.nn.storage_pool`). Reading either name here warns once per use with a
:class:`DeprecationWarning` naming the new home; nothing is defined here, so ``__all__`` is empty."""

from __future__ import annotations

import warnings
from typing import Any

from . import hugepages

__all__: list[str] = []

#: the names 0.2.0 documented here
_MOVED = ("empty", "MIN_BYTES")


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        warnings.warn(f"tactile_zoo.nn.memory.{name} moved to tactile_zoo.nn.hugepages.{name}; this alias goes in a "
                      f"later release", DeprecationWarning, stacklevel=2)
        return getattr(hugepages, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
