"""Large CPU outputs backed by transparent huge pages, so that writing them does not cost a page fault per 4 KiB.

A fresh CPU tensor of tens of megabytes is a fresh ``mmap`` (glibc serves every allocation above its largest mmap
threshold, 32 MiB by default, that way and unmaps it on free), and the kernel zero-fills it one 4 KiB page per fault
as it is first written. For the multi-step LIF's outputs (spikes ``[T, B, N * F]`` forward, the input gradient
backward: 78 MB each at SGnet's shapes) those faults were about 45 % of the fused forward + backward (profiled on
1 thread: 37 ms to first-write 78 MB, 9.5 ms with huge pages). Where Linux hands out huge pages only on request
(``/sys/kernel/mm/transparent_hugepage/enabled`` is ``madvise``), :func:`empty` asks for them with
``madvise(MADV_HUGEPAGE)`` before anything is written. The advice changes no value, only how the memory is mapped; it
is skipped for smaller tensors (which may share heap memory with others), off Linux, off CPU, where huge pages are
already the default or disabled, and with ``TACTILE_ZOO_NO_HUGEPAGES=1``.

Huge pages shorten the faults; :func:`reusable` avoids them. Training calls the LIF once per batch with the same
shapes, so its outputs (spikes forward, input gradient backward) come from a small pool of storages that are handed
out again once nothing refers to them any more: a rewrite of memory already mapped costs no fault at all (about
3 ms for 80 MB, against about 40 ms for a fresh buffer). A storage is handed out again only when the pool's own
reference is its last one (its C++ use count is 1): no tensor, view, ``.grad``, tensor saved for backward or numpy
array made from one still reaches it, so an output that is still referenced is never overwritten.
"""

from __future__ import annotations

import ctypes
import functools
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path

import torch
from torch import Tensor

from .._env import env_flag

__all__ = ["empty", "reusable", "MIN_BYTES", "POOL_BYTES", "POOL_MIN_BYTES", "pool_stats", "clear_pool"]

#: Smallest tensor advised: glibc's mmap threshold never rises above 32 MiB (64-bit), so anything larger has a mapping
#: of its own and the advice ends with it; smaller blocks may come from the heap and be reused already faulted in.
MIN_BYTES = 32 << 20
_HUGE_PAGE = 2 << 20  # x86-64 and arm64 (4 KiB base pages) transparent huge page size
_MADV_HUGEPAGE = 14
_THP_MODE = Path("/sys/kernel/mm/transparent_hugepage/enabled")


@functools.cache
def _madvise() -> Callable[[int, int, int], int] | None:
    """libc's ``madvise`` when huge pages are granted on request only, else ``None`` (nothing to ask for)."""
    if not sys.platform.startswith("linux") or env_flag("TACTILE_ZOO_NO_HUGEPAGES"):
        return None
    try:
        if "[madvise]" not in _THP_MODE.read_text():  # "[always]": already huge; "[never]": the advice is ignored
            return None
        fn = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int], ctypes.c_int
    return fn


def empty(shape: Sequence[int], like: Tensor) -> Tensor:
    """``like.new_empty(shape)``, advised to use transparent huge pages when it is a large CPU tensor (see the module
    docstring). Call it before anything is written to the tensor: pages already faulted in stay small."""
    out = like.new_empty(tuple(shape))
    nbytes = out.numel() * out.element_size()
    if out.device.type != "cpu" or nbytes < MIN_BYTES or (madvise := _madvise()) is None:
        return out
    start = -(-out.data_ptr() // _HUGE_PAGE) * _HUGE_PAGE  # the whole huge pages inside the tensor's memory
    end = (out.data_ptr() + nbytes) // _HUGE_PAGE * _HUGE_PAGE
    if end > start:
        madvise(start, end - start, _MADV_HUGEPAGE)  # a hint: if refused, the memory is mapped as before
    return out



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


def pool_stats() -> dict[str, int]:
    """The pool's storages, bytes held and hand-outs so far (``reused`` from an idle storage, ``fresh`` new)."""
    with _POOL.lock:
        return dict(storages=len(_POOL.slots), bytes=_POOL.bytes, reused=_POOL.reused, fresh=_POOL.fresh)


def clear_pool() -> None:
    """Drop the pool's references: idle storages are freed, those in use are freed with their last tensor."""
    _POOL.clear()
