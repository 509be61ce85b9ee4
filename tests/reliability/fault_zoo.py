"""Models that fail in the ways a long benchmark meets on shared machines, registered on import.

Importing this module registers them (so ``--plugin-module fault_zoo`` works in a subprocess or a worker process);
the reliability tests' fixture calls :func:`register` / :func:`unregister` around each test. Each model is the tiny
zoo's :class:`TinyMLP` with one fault added, so a fault is the only difference from a model that trains fine.

    fault_late_nan     trains normally for a few steps, then its outputs turn NaN (a diverging run).
    fault_eval_error   trains, but raises as soon as it is evaluated (a bug in eval-only code).
    fault_oom_runtime  RuntimeError("CUDA error: out of memory"), the message older CUDA paths raise.
    fault_torch_oom    torch.OutOfMemoryError, what the caching allocator raises.
    fault_host_oom     MemoryError with no message (host memory exhausted).
    fault_ctor_error   a KeyError in the constructor (a bug, not a declared incompatibility).
    fault_worker_kill  SIGKILLs the worker process it runs in (the kernel's OOM killer); raises in the main process.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from typing import Any

import torch
from tiny_zoo import TINY_RECIPE, TinyMLP

from tactile_zoo import registry


class LateNaN(TinyMLP):
    def __init__(self, spec: Any, **kw: Any) -> None:
        super().__init__(spec, **kw)
        self.steps = 0

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        out = super().forward(x, g)
        if self.training:
            self.steps += 1
        return out * float("nan") if self.steps > 4 else out


class EvalError(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        if not self.training:
            raise ValueError("fault_eval_error: evaluation failed on purpose")
        return super().forward(x, g)


class OOMRuntime(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        raise RuntimeError("CUDA error: out of memory (fault_oom_runtime)")


class TorchOOM(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        raise torch.OutOfMemoryError("Tried to allocate 64.00 GiB (fault_torch_oom)")


class HostOOM(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        raise MemoryError()


class CtorError(TinyMLP):
    def __init__(self, spec: Any, **kw: Any) -> None:
        raise KeyError("fault_ctor_error: a bug in the constructor")


class WorkerKill(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        if multiprocessing.parent_process() is None:  # never kill the test runner itself
            raise RuntimeError("fault_worker_kill only kills worker processes")
        os.kill(os.getpid(), signal.SIGKILL)
        raise AssertionError("unreachable")


MODELS = {"fault_late_nan": LateNaN, "fault_eval_error": EvalError, "fault_oom_runtime": OOMRuntime,
          "fault_torch_oom": TorchOOM, "fault_host_oom": HostOOM, "fault_ctor_error": CtorError,
          "fault_worker_kill": WorkerKill}


def register() -> None:
    """(Re-)register the fault models (idempotent)."""
    for name, cls in MODELS.items():
        registry.register_model(name, recipe=TINY_RECIPE, tags=["test"])(cls)


def unregister() -> None:
    table = registry._TABLES["model"]
    for name in MODELS:
        table.builtin.pop(registry.normalize_name(name), None)


register()
