"""glibc malloc settings for training processes: keep some large freed blocks mapped, so rewriting them costs no page
faults, without raising D-CNN's peak memory above its 3 GB target.

torch's CPU allocator takes every tensor from glibc (``posix_memalign``, 64-byte aligned). glibc serves a block above
its mmap threshold (128 KiB at first, rising with freed blocks up to 32 MiB on 64-bit) with a fresh ``mmap`` and
unmaps it on ``free``; the kernel zero-fills the next one a 4 KiB page per fault as it is first written. A training
step allocates and frees the same activations every batch, so D-CNN on Ev-Containers took some 900k faults per batch.

Serving everything from the heap (``M_MMAP_MAX=0``) halves those faults but raises the peak from 2.4 to 3.3 GB after
one epoch and 3.8 GB after three: an aligned request needs its size plus the alignment plus 32 bytes from glibc
(before 2.38), so a freed block of the same size is never handed out again for it and the heap keeps growing.
:data:`SETTINGS` is the compromise measured in docs/performance.md: blocks of 32 MiB and more are mapped while
fewer than 12 are live (the rest come from the heap and stay faulted in), smaller ones always come from the heap,
and the heap is trimmed once 256 MiB at its top are free.

:func:`tune_malloc` applies them once, at the start of a training process (``tactile-zoo train``, every bench worker
through ``setup_worker``). It changes where blocks live, never what is computed: the same seed trains the same
numbers. Nothing happens when ``tactile_zoo`` is imported (a library user's process keeps its allocator as it was),
off glibc Linux (nothing else has these settings), or with ``TACTILE_ZOO_DEFAULT_MALLOC=1``.
"""

from __future__ import annotations

import ctypes
import platform
import sys
from collections.abc import Callable, Mapping

from .._env import env_flag

__all__ = ["tune_malloc", "apply_mallopt", "SETTINGS", "PARAMETERS"]

#: glibc's ``mallopt`` parameter numbers (``<malloc.h>``)
PARAMETERS = {"M_TRIM_THRESHOLD": -1, "M_TOP_PAD": -2, "M_MMAP_THRESHOLD": -3, "M_MMAP_MAX": -4, "M_ARENA_MAX": -8}

#: the settings :func:`tune_malloc` applies (see docs/performance.md for the measurements that chose them)
SETTINGS: dict[str, int] = {"M_MMAP_THRESHOLD": 32 << 20, "M_MMAP_MAX": 12, "M_TRIM_THRESHOLD": 256 << 20}

_APPLIED: dict[str, int] = {}


def _mallopt() -> Callable[[int, int], int] | None:
    """glibc's ``mallopt``, or None off glibc Linux (musl, macOS, Windows)."""
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return None
    try:
        fn = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return fn


def apply_mallopt(settings: Mapping[str, int]) -> dict[str, int] | None:
    """Call ``mallopt`` for each of ``settings`` (names from :data:`PARAMETERS`); returns each call's return value
    (1: applied, 0: refused), or None off glibc Linux, where nothing is done.

    Raises:
        KeyError: a name that is not in :data:`PARAMETERS`.
    """
    fn = _mallopt()
    if fn is None:
        return None
    return {name: int(fn(PARAMETERS[name], int(value))) for name, value in settings.items()}


def tune_malloc() -> dict[str, int] | None:
    """Apply :data:`SETTINGS` once per process (later calls return the first result); None where skipped: off glibc
    Linux, or with ``TACTILE_ZOO_DEFAULT_MALLOC=1`` (the allocator's defaults, as before).

    Raises:
        ConfigError: ``TACTILE_ZOO_DEFAULT_MALLOC`` is not a boolean.
    """
    if env_flag("TACTILE_ZOO_DEFAULT_MALLOC"):
        return None
    if not _APPLIED:
        result = apply_mallopt(SETTINGS)
        if result is None:
            return None
        _APPLIED.update(result)
    return dict(_APPLIED)
