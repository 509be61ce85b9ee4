"""Where and how a cell runs: device choice, seeding, thread count, subnormal floats, memory high-water mark, versions.

Subnormal floats: a leaky neuron's membrane or gradient that decays by beta = 0.2 per step without input falls below
float32's normal range (about 1.2e-38) after some 55 steps, and x86 CPUs compute with such subnormal numbers up to
100 times slower. In SGnet's backward the gradient carried back through 250 steps is mostly subnormal, which made one
matrix product of its training step 3x slower (profiled). :func:`flush_denormals` turns on flush-to-zero /
denormals-are-zero for the block (``torch.set_flush_denormal``); ``fit``, ``evaluate``, the prefix evaluation,
the latency timing and every bench cell run inside it. Values that small change no sum they are added to, so the
results are the same up to those negligible terms. The setting belongs to the calling thread (and to threads it
starts later); the CLI turns it on before torch starts its thread pool, so multi-threaded runs get it everywhere.

Peak memory: on Linux the process's resident-set high-water mark (``VmHWM`` in ``/proc/self/status``) is reset at the
start of a measurement by writing ``5`` to ``/proc/self/clear_refs``, so each cell reports its own peak even in a
long-lived process or worker. Where that is impossible the value is ``resource.getrusage(...).ru_maxrss``, the peak
since the process started (an upper bound for the cell); without that too (Windows has neither ``/proc`` nor the
``resource`` module) the peak is None and the cell runs all the same; :attr:`PeakMemory.source` says which. On CUDA
the peak of ``torch.cuda.max_memory_allocated`` is recorded too.
"""

from __future__ import annotations

import contextlib
import functools
import os
import platform
import random
import re
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .._env import env_flag
from ..errors import ConfigError

__all__ = ["resolve_device", "seed_everything", "PeakMemory", "count_parameters", "versions", "set_threads",
           "flush_denormals", "cpu_isa"]


def resolve_device(device: str | torch.device | None = "auto", *, here: bool = True) -> torch.device:
    """The torch device ``device`` names: ``"auto"`` (or ``None``) = CUDA when available, else CPU; ``"cpu"``,
    ``"cuda"``, ``"cuda:N"``, ``"mps"``.

    Args:
        device: the name (the CLI's ``--device``), or a ``torch.device`` (returned as is).
        here: also check that this machine has the device (its GPU ``N`` included); ``False`` checks the name only,
            for cells that run on other machines (a Dask scheduler's workers).

    Raises:
        ConfigError: not a device name, a device type tactile-zoo does not run on, or one this machine lacks.
    """
    if isinstance(device, torch.device):
        return device
    if device is not None and not isinstance(device, str):
        raise ConfigError(f"--device must be a device name (auto, cpu, cuda, cuda:N, mps), got {device!r}")
    name = (device or "auto").strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError as exc:
        raise ConfigError(f"--device {device!r} is not a device name (auto, cpu, cuda, cuda:N, mps): {exc}") from None
    if dev.type not in _DEVICE_TYPES:  # meta, xla, ...: torch parses them, training on them is not supported
        raise ConfigError(f"--device {device!r}: tactile-zoo runs on {', '.join(_DEVICE_TYPES)} (or auto), not "
                          f"{dev.type!r}")
    if not here or dev.type == "cpu":
        return dev
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"--device {device!r}: CUDA is not available on this machine (torch "
                          f"{torch.__version__}); use --device cpu or auto")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ConfigError(f"--device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s), "
                          f"cuda:0 to cuda:{torch.cuda.device_count() - 1}")
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise ConfigError(f"--device {device!r}: Apple's MPS is not available on this machine; use --device cpu")
    return dev


#: the device types a cell can run on
_DEVICE_TYPES = ("cpu", "cuda", "mps")


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch (all devices): model initialisation and dropout then repeat exactly on CPU."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def set_threads(threads: int | None) -> None:
    """Intra-op threads for this process (``None``: leave torch's choice)."""
    if threads is not None and threads > 0 and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


_FTZ = threading.local()


@contextlib.contextmanager
def flush_denormals() -> Iterator[bool]:
    """Flush subnormal floats to zero on CPU inside the block (see the module docstring); re-entrant.

    Yields whether the mode is on: False where the CPU lacks it (it needs x86 SSE3) or with the environment variable
    ``TACTILE_ZOO_KEEP_DENORMALS=1``, which turns this off everywhere. The outermost block turns the mode off again
    on exit, so a caller who turned it on with ``torch.set_flush_denormal(True)`` should wrap their own code
    in this context instead. Also usable as a decorator: ``@flush_denormals()``.
    """
    if env_flag("TACTILE_ZOO_KEEP_DENORMALS"):  # opt-out: compute with subnormals as they come
        yield False
        return
    depth = getattr(_FTZ, "depth", 0)
    if depth == 0:
        _FTZ.supported = torch.set_flush_denormal(True)
    _FTZ.depth = depth + 1
    try:
        yield _FTZ.supported
    finally:
        _FTZ.depth -= 1
        if _FTZ.depth == 0 and _FTZ.supported:
            torch.set_flush_denormal(False)


def count_parameters(model: torch.nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))


_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def _vm_hwm_kb() -> int | None:
    try:
        match = re.search(r"VmHWM:\s+(\d+)\s+kB", _STATUS.read_text())
    except OSError:
        return None
    return int(match.group(1)) if match else None


def _ru_maxrss_kb() -> int | None:
    """The process's peak RSS in kB from getrusage, or None where the resource module is missing (Windows)."""
    try:
        import resource
    except ImportError:
        return None
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux
    return kb // 1024 if sys.platform == "darwin" else kb  # bytes there


class PeakMemory:
    """Measure a block's peak memory: ``with PeakMemory(device) as peak: ...; peak.mb, peak.gpu_mb, peak.source``."""

    def __init__(self, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        self.mb: float | None = None
        self.gpu_mb: float | None = None
        self.source = "ru_maxrss"

    def __enter__(self) -> PeakMemory:
        try:
            _CLEAR_REFS.write_text("5")  # resets VmHWM to the current RSS (Linux >= 4.0)
            self.source = "vmhwm" if _vm_hwm_kb() is not None else "ru_maxrss"
        except OSError:
            self.source = "ru_maxrss"
        if self.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(self.device)
        return self

    def __exit__(self, *exc: Any) -> None:
        kb = _vm_hwm_kb() if self.source == "vmhwm" else None
        if kb is None:
            kb = _ru_maxrss_kb()
            self.source = "ru_maxrss" if kb is not None else "unavailable"
        # no /proc and no resource module (Windows): the cell still runs, with its peak memory unknown
        self.mb = round(kb / 1024, 1) if kb is not None else None
        if self.device.type == "cuda":
            self.gpu_mb = round(torch.cuda.max_memory_allocated(self.device) / 2**20, 1)


def versions() -> dict[str, str]:
    """Versions of the packages a result depends on."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def _versions() -> dict[str, str]:
    from importlib import metadata

    from .._version import __version__

    out = {"tactile_zoo": __version__, "torch": torch.__version__, "numpy": np.__version__,
           "python": platform.python_version()}
    for dist in ("torch_geometric", "snntorch"):  # from the installed metadata: importing them costs seconds
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


#: the instruction-set flags that decide which kernels torch, oneDNN and MKL run, and so a cell's rounding
_ISA_FLAG = re.compile(r"^(sse\w*|ssse3|avx\w*|fma\w*|f16c|amx\w*)$")


def cpu_isa() -> dict[str, Any]:
    """What decides which CPU kernels ran: torch's dispatch level (``get_cpu_capability()``, e.g. ``AVX512``) and the
    processor's vector and matrix instruction-set flags. The same seed can train differently where these differ."""
    flags: list[str] = []
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                flags = sorted(f for f in line.split(":", 1)[1].split() if _ISA_FLAG.match(f))
                break
    except OSError:
        pass
    return {"capability": torch.backends.cpu.get_cpu_capability(), "flags": flags}


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
