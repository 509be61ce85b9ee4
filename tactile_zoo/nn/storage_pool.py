"""A pool of large CPU storages handed out again once nothing refers to them any more, so that rewriting an output
costs no page fault at all (the huge pages of :mod:`tactile_zoo.nn.hugepages` only shorten the faults).

Training calls the LIF once per batch with the same shapes, so its outputs (spikes forward, input gradient backward)
come from :func:`reusable`, a small pool of storages that are handed out again once nothing refers to them any more:
a rewrite of memory already mapped costs no fault at all (about 3 ms for 80 MB, against about 40 ms for a fresh
buffer). A storage is handed out again only when the pool's own reference is its last one (its C++ use count is 1):
no tensor, view, ``.grad``, tensor saved for backward or numpy array made from one still reaches it, so an output
that is still referenced is never overwritten.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence

import torch
from torch import Tensor

from .hugepages import empty

__all__ = ["reusable", "reusable_like", "POOL_BYTES", "POOL_MIN_BYTES", "pool_stats", "clear_pool"]

#: The most storage the pool of :func:`reusable` holds, in use and idle together (0 turns the pool off): a request
#: that would go over it evicts idle storages, least recently used first, and gets an unpooled tensor if that is not
#: enough. So the memory the pool keeps beyond what live tensors need is at most this much.
POOL_BYTES = 512 << 20
#: Smaller requests are not pooled: the heap reuses small blocks already faulted in.
POOL_MIN_BYTES = 1 << 20
_use_count = getattr(torch._C, "_storage_Use_Count", None)  # private torch API; without it there is no pool


class _Pool:
    """Storages keyed by their size in bytes, each with the pool's own reference; thread-safe (one lock)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.slots: OrderedDict[int, torch.UntypedStorage] = OrderedDict()  # id -> storage, least recent first
        self.bytes = 0
        self.reused = self.fresh = 0

    @staticmethod
    def _free(storage: torch.UntypedStorage) -> bool:
        return _use_count(storage._cdata) == 1  # the pool's reference is the only one

    def take(self, shape: tuple[int, ...], like: Tensor, nbytes: int) -> Tensor | None:
        """A ``shape`` tensor of ``like``'s dtype on an idle storage of ``nbytes`` bytes, or on a new one that the
        pool keeps (``None`` where the limit leaves no room)."""
        with self.lock:
            for key, storage in self.slots.items():
                if storage.nbytes() == nbytes and self._free(storage):
                    self.slots.move_to_end(key)
                    self.reused += 1
                    # the tensor's reference is taken under the lock: no other caller can be handed this storage now
                    return like.new_empty(0).set_(storage, 0, shape)
            if self.bytes + nbytes > POOL_BYTES:
                for key in [k for k, st in self.slots.items() if self._free(st)]:
                    self.bytes -= self.slots.pop(key).nbytes()
                    if self.bytes + nbytes <= POOL_BYTES:
                        break
                if self.bytes + nbytes > POOL_BYTES:
                    return None
            out = empty(shape, like)
            storage = out.untyped_storage()
            self.slots[id(storage)] = storage
            self.bytes += nbytes
            self.fresh += 1
            return out

    def clear(self) -> None:
        with self.lock:
            self.slots.clear()
            self.bytes = self.reused = self.fresh = 0


_POOL = _Pool()


def reusable(shape: Sequence[int], like: Tensor) -> Tensor:
    """An uninitialised tensor like :func:`empty`, on a storage reused from an earlier call where one of this size
    is no longer referenced anywhere (see the module docstring). For outputs that are written whole: the values are
    whatever the storage held. CPU tensors of at least :data:`POOL_MIN_BYTES`; others, and requests the pool has no
    room for (:data:`POOL_BYTES`), get :func:`empty`'s fresh tensor."""
    shape = tuple(shape)
    nbytes = like.element_size() * int(torch.Size(shape).numel())
    if like.device.type != "cpu" or nbytes < POOL_MIN_BYTES or POOL_BYTES <= 0 or _use_count is None:
        return empty(shape, like)
    out = _POOL.take(shape, like, nbytes)
    return empty(shape, like) if out is None else out


def reusable_like(x: Tensor, like: Tensor | None = None) -> Tensor:
    """:func:`reusable` with ``torch.empty_like(x)``'s shape and strides (those of ``x`` where it is dense, as a
    permuted view of a channels-last tensor is), on ``like``'s device and dtype (default ``x``'s; ``x`` may then be a
    meta tensor that only records a layout). For outputs whose layout matters beyond speed, such as a product's
    output, whose layout picks the BLAS kernel and with it the rounding."""
    strides = torch.empty_like(x, device="meta").stride()  # a meta tensor: the layout, without memory
    return reusable((x.numel(),), x if like is None else like).as_strided(x.shape, strides)


def pool_stats() -> dict[str, int]:
    """The pool's storages, bytes held and hand-outs so far (``reused`` from an idle storage, ``fresh`` new)."""
    with _POOL.lock:
        return dict(storages=len(_POOL.slots), bytes=_POOL.bytes, reused=_POOL.reused, fresh=_POOL.fresh)


def clear_pool() -> None:
    """Drop the pool's references: idle storages are freed, those in use are freed with their last tensor."""
    _POOL.clear()
