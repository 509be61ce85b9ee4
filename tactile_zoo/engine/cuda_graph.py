"""A model's training forward and backward replayed from CUDA graphs, so a GPU is not left waiting on kernel launches.

The spiking and recurrent models step through time in Python: SGnet launches a few kernels per LIF layer at each of
250 time steps, ConvLSTM one gate product and its element-wise chain per frame, forward and backward. On a GPU each
launch costs a few microseconds of host time, longer than the kernel it starts at these sizes, so the GPU idles
between them: on the H200 SGnet's epoch (3.1 s) was barely faster than two CPU cores. A CUDA graph records the
kernels of one call once and replays them with a single launch.

:class:`GraphedForward` wraps a model for its training run with :func:`torch.cuda.make_graphed_callables`: the forward
and the autograd backward of a batch of the captured shape are each one graph replay; the loss, the optimiser step,
gradient clipping and the weight average stay eager (a handful of launches per batch). A batch of another shape (the
last, shorter one of an epoch), evaluation mode and every call after :meth:`GraphedForward.release` run the model's
own forward, so the model leaves training unchanged.

What capture needs from a model, and what happens otherwise:

- **no host synchronisation inside ``forward``** (``.item()``, ``nonzero``, shapes that depend on values). The
  models here take their dense products off the CPU (SGnet's event lists are CPU-only), so they qualify; one that
  does not raises :class:`CaptureError` naming the model, before its first training step.
- **the same parameters for the whole run:** the graph reads them at fixed addresses. The optimiser updates them in
  place, and ``load_state_dict`` copies into them, so both are safe.

Capture runs three warm-up calls on the first batch (the CUDA caching allocator and cuDNN need them). Their side
effects on the model are undone: its buffers (batch-norm running statistics and their counters) are restored to
their values before capture, so the first recorded update is that of the first real step. Their random numbers are
not given back, so a graphed run draws different dropout masks from an eager one with the same seed: the two agree
in distribution, not bit for bit. CUDA training is not bitwise repeatable anyway (atomics in the backward of
scatters and convolutions).

The engine turns this on with ``fit(..., cuda_graphs=True)`` or the environment variable
``TACTILE_ZOO_CUDA_GRAPHS=1`` (read for CUDA devices only). It is opt-in and unmeasured on this project's machines
until a GPU check has timed it (``python -m benchmarks.gpu_check``, step ``gpu_epoch``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from ..errors import TactileZooError

__all__ = ["GraphedForward", "CaptureError"]

#: what builds the graphed callable: torch's, replaced only by the CPU tests of the dispatch around it
Capture = Callable[..., Any]


class CaptureError(TactileZooError):
    """A model's training forward could not be recorded in a CUDA graph."""


class _Inputs(torch.nn.Module):
    """``model(x, g)`` as a module of tensors only: graph capture takes no ``None`` argument."""

    def __init__(self, model: torch.nn.Module, with_g: bool) -> None:
        super().__init__()
        self.model, self.with_g = model, with_g

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self.model(x, g if self.with_g else None)


class GraphedForward:
    """``model(x, g)`` for one training run, replayed from a CUDA graph for batches shaped like the first.

    Args:
        model: the model being trained, on a CUDA device, in training mode.
        x: the first batch's input ``(B, T, N, C)``; its shape (and ``g``'s) is the one recorded.
        g: the first batch's global features ``(B, T, G)``, or None.
        capture: the function that records the graphs (:func:`torch.cuda.make_graphed_callables`); the tests of
            the dispatch pass another.

    Raises:
        CaptureError: the model's forward or backward cannot be recorded (host synchronisation, values that set
            shapes); the message names the model and torch's reason.
    """

    def __init__(self, model: torch.nn.Module, x: Tensor, g: Tensor | None = None, *,
                 capture: Capture | None = None) -> None:
        self.model = model
        self.shapes = (tuple(x.shape), None if g is None else tuple(g.shape))
        self.replays = 0
        inner = _Inputs(model, g is not None)
        args = (x,) if g is None else (x, g)
        saved = {name: buf.detach().clone() for name, buf in model.named_buffers()}
        record = capture if capture is not None else torch.cuda.make_graphed_callables
        try:
            # allow_unused_input: a parameter that a forward never reaches (a head a model keeps for streaming)
            # gets no gradient, as in eager mode
            self._graphed: Any = record(inner, args, allow_unused_input=True)
        except RuntimeError as exc:  # torch.cuda.CudaError included
            raise CaptureError(f"{type(model).__name__}'s training forward could not be recorded in a CUDA graph: "
                               f"{exc}; train it without cuda_graphs (TACTILE_ZOO_CUDA_GRAPHS unset)") from exc
        with torch.no_grad():  # undo the warm-up calls' updates of running statistics
            for name, buf in model.named_buffers():
                if name in saved:
                    buf.copy_(saved[name])

    def matches(self, x: Tensor, g: Tensor | None) -> bool:
        """Whether ``(x, g)`` is shaped as the recorded batch (and the model is training, as it was recorded)."""
        if self._graphed is None or not self.model.training:
            return False
        return (tuple(x.shape), None if g is None else tuple(g.shape)) == self.shapes

    def __call__(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        if self.matches(x, g):
            self.replays += 1
            return self._graphed(x) if g is None else self._graphed(x, g)
        return self.model(x, g)

    def release(self) -> None:
        """Drop the graphs and their memory pool; every later call runs the model's own forward."""
        self._graphed = None
