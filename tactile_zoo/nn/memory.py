"""Deprecated alias of :mod:`tactile_zoo.nn.hugepages`, kept because release 0.2.0 documented this path: its two
names, :func:`~tactile_zoo.nn.hugepages.empty` and :data:`~tactile_zoo.nn.hugepages.MIN_BYTES`, live there now (the
pool of reused storages is :mod:`tactile_zoo.nn.storage_pool`)."""

from .hugepages import MIN_BYTES, empty

__all__ = ["empty", "MIN_BYTES"]
