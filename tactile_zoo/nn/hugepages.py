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

The pool of reused storages (:mod:`tactile_zoo.nn.storage_pool`) allocates its storages here.
"""

from __future__ import annotations

import ctypes
import functools
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from torch import Tensor

from .._env import env_flag

__all__ = ["empty", "MIN_BYTES"]

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
