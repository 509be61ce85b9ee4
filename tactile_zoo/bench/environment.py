"""The environment a run happened in (``run.json``): versions, CPU, threads, GPU, git commit."""

from __future__ import annotations

import functools
import platform
import socket
import subprocess
from pathlib import Path
from typing import Any

import torch

from ..engine.runtime import cpu_count, cpu_model, versions

__all__ = ["environment", "git_commit"]


def git_commit() -> str | None:
    """The commit of a source checkout of tactile-zoo (``None`` for an installed wheel or without git)."""
    repo = Path(__file__).resolve().parents[2]
    if not (repo / ".git").exists():
        return None
    try:
        out = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=5, check=False)
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    if not commit:
        return None
    return commit + ("+dirty" if dirty.stdout.strip() else "")


@functools.lru_cache(maxsize=1)
def _static() -> dict[str, Any]:
    import sys

    gpu = None
    if torch.cuda.is_available():
        props = torch.cuda.get_device_properties(0)
        gpu = {"count": torch.cuda.device_count(), "name": torch.cuda.get_device_name(0), "cuda": torch.version.cuda,
               "memory_gb": round(props.total_memory / 2**30, 1)}
    return {"versions": versions(), "python": sys.version.split()[0], "platform": platform.platform(),
            "hostname": socket.gethostname(), "cpu_model": cpu_model(), "cpu_cores": cpu_count(), "gpu": gpu,
            "git_commit": git_commit()}


def environment() -> dict[str, Any]:
    """Package versions, CPU model and cores, torch threads, GPU, git commit (computed once per process)."""
    return {**_static(), "torch_threads": torch.get_num_threads()}
