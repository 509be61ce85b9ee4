"""Where and how a cell runs: device choice, seeding, thread count, memory high-water mark, versions.

Peak memory: on Linux the process's resident-set high-water mark (``VmHWM`` in ``/proc/self/status``) is reset at the
start of a measurement by writing ``5`` to ``/proc/self/clear_refs``, so each cell reports its own peak even in a
long-lived process or worker. Where that is impossible the value is ``resource.getrusage(...).ru_maxrss``, the peak
since the process started (an upper bound for the cell); :attr:`PeakMemory.source` says which. On CUDA the peak of
``torch.cuda.max_memory_allocated`` is recorded too.
"""

from __future__ import annotations

import functools
import os
import platform
import random
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import ConfigError

__all__ = ["resolve_device", "seed_everything", "PeakMemory", "count_parameters", "versions", "set_threads"]


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """``"auto"`` (or ``None``) = CUDA when available, else CPU; ``"cuda"`` without a GPU is a :class:`ConfigError`."""
    if isinstance(device, torch.device):
        return device
    name = (device or "auto").strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError as exc:
        raise ConfigError(f"--device {device!r} is not a device name (auto, cpu, cuda, cuda:N): {exc}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"--device {device!r}: CUDA is not available on this machine (torch "
                          f"{torch.__version__}); use --device cpu or auto")
    return dev


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch (all devices): model initialisation and dropout then repeat exactly on CPU."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def set_threads(threads: int | None) -> None:
    """Intra-op threads for this process (``None``: leave torch's choice)."""
    if threads is not None and threads > 0 and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


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
            import resource

            kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux
            if sys.platform == "darwin":  # bytes there
                kb //= 1024
            self.source = "ru_maxrss"
        self.mb = round(kb / 1024, 1)
        if self.device.type == "cuda":
            self.gpu_mb = round(torch.cuda.max_memory_allocated(self.device) / 2**20, 1)


def versions() -> dict[str, str]:
    """Versions of the packages a result depends on."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def _versions() -> dict[str, str]:
    from importlib import metadata

    from .. import __version__

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


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
