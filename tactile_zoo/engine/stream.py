"""Streaming replay: one recorded sample fed to a causal model frame by frame, as a robot would during a grasp.

:func:`replay` drives a model's streaming API (``init_state(batch_size)``, ``step(x_t, g_t, state) -> (scores,
state)``) over one sample at batch size 1 and records, after every frame, the running scores, the class
probabilities (:func:`~tactile_zoo.engine.metrics.scores_to_probabilities`, so spike rates and logits read the same)
and the wall time of the ``step`` call. :func:`settled_step` answers "from which frame on was the answer right?".

A step whose top score is shared by two or more classes (:func:`~tactile_zoo.engine.metrics.tied_top`: an SNN that
has not fired yet, all rates 0 and p = 1/K each) names no class: its prediction is ``None`` (undecided), which is
never correct, so it cannot start or continue a settled run.

Steps are counted from 1: step ``k`` is the state after reading frames ``0 .. k-1``, i.e. after ``k / T`` of the
recording, at time ``k * frame_period`` seconds when the dataset knows its frame period.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from ..errors import ConfigError
from .evaluate import model_loss
from .metrics import scores_to_probabilities, tied_top
from .progress import LOG_SECONDS, Progress

__all__ = ["StreamTrace", "replay", "settled_step", "check_streaming"]


@dataclass
class StreamTrace:
    """What :func:`replay` saw, one row per step (``T`` rows).

    Attributes:
        scores: the model's running scores ``(T, K)`` (logits, or spike rates for ``loss="mse_rate"``).
        probabilities: class probabilities ``(T, K)``.
        step_seconds: wall time of each ``step`` call ``(T,)``.
        target: the true class, or ``None`` when unknown.
        frame_period: seconds between frames, or ``None`` when the dataset does not say.
        loss: how scores became probabilities (``"ce"`` or ``"mse_rate"``).
    """

    scores: torch.Tensor
    probabilities: torch.Tensor
    step_seconds: list[float]
    target: int | None = None
    frame_period: float | None = None
    loss: str = "ce"

    @property
    def num_steps(self) -> int:
        return int(self.scores.shape[0])

    @property
    def predictions(self) -> list[int | None]:
        """The top class after each step, ``None`` where the top score is tied (undecided)."""
        tied = self.ties
        return [None if t else int(p) for p, t in zip(self.scores.argmax(dim=-1).tolist(), tied)]

    @property
    def ties(self) -> list[bool]:
        """Whether each step's top score is shared by two or more classes (:func:`tied_top`)."""
        return tied_top(self.scores, self.loss).tolist()

    def tied_classes(self, step: int) -> list[int]:
        """The classes sharing the top score after ``step`` frames (1-based); one class when there is no tie."""
        values = self.scores[step - 1].float()
        values = values.clamp_min(0) if self.loss == "mse_rate" else values
        return torch.nonzero(values == values.max()).flatten().tolist()

    @property
    def settled(self) -> int | None:
        """The step (1-based) from which the prediction is the true class until the end, or ``None``."""
        return None if self.target is None else settled_step(self.predictions, self.target)

    def time_of(self, step: int) -> float | None:
        """Seconds into the recording after ``step`` frames (1-based), when the frame period is known."""
        return None if self.frame_period is None else step * self.frame_period

    def latency_ms(self) -> dict[str, float]:
        """Median, mean and max milliseconds per ``step`` call."""
        ms = [1000.0 * s for s in self.step_seconds]
        return {"median": statistics.median(ms), "mean": statistics.fmean(ms), "max": max(ms)}


def settled_step(predictions: Sequence[int | None], target: int) -> int | None:
    """The first step (1-based) from which every prediction equals ``target``; ``None`` if the last one is wrong.

    A prediction that is right early, wrong for a while, then right again settles at the start of its last run of
    correct steps: only an answer that is not revised afterwards counts. An undecided step (``None``, a tie) is not
    right.
    """
    settled = None
    for k, pred in enumerate(predictions, start=1):
        if pred != target:
            settled = None
        elif settled is None:
            settled = k
    return settled


def check_streaming(name: str, meta: dict[str, Any] | None = None, model: torch.nn.Module | None = None) -> None:
    """A :class:`ConfigError` naming model ``name`` if its registry ``meta`` says ``streaming=False`` or ``model``
    lacks ``init_state``/``step`` (either check is skipped when its argument is ``None``)."""
    if meta is not None and not meta.get("streaming", False):
        why = "it is registered with streaming=False" + ("" if meta.get("causal") else " (it is not causal)")
    elif model is not None and not (callable(getattr(model, "init_state", None))
                                    and callable(getattr(model, "step", None))):
        why = f"{type(model).__name__} has no init_state/step methods"
    else:
        return
    raise ConfigError(f"model {name!r} does not stream: {why}. Use prefix evaluation instead: `tactile-zoo train` "
                      "and `tactile-zoo bench` report accuracy_at_<p> on growing prefixes of each test sequence")


def replay(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None = None, y: int | None = None, *,
           loss: str | None = None, frame_period: float | None = None, device: torch.device | None = None,
           warmup: bool = True, progress: bool = True) -> StreamTrace:
    """Feed one sample ``x (T, N, C)``, ``g (T, G)`` to ``model.step`` frame by frame at batch size 1.

    Args:
        model: a streaming model (``init_state``/``step``); run in eval mode under ``inference_mode``.
        x, g: the sample's frames and global features (``g`` with 0 columns or ``None``: no globals).
        y: the true class, if known (for :attr:`StreamTrace.settled`).
        loss: ``"ce"`` or ``"mse_rate"`` (default: what the model was trained with, see ``model_loss``).
        frame_period: seconds between frames, if known.
        device: where to run (the model is moved there; default: where its parameters are).
        warmup: run one untimed step on a throw-away state first, so one-off costs (allocator, lazy init) do not
            land in the first step's latency.
        progress: report the frames (a bar on a terminal, log records otherwise: :mod:`.progress`), outside the
            timed ``step`` calls; ``False``: nothing.
    """
    check_streaming(type(model).__name__, model=model)
    if x.dim() != 3 or x.shape[0] == 0:
        raise ConfigError(f"replay takes one sample x of shape (T, N, C) with T >= 1, got {tuple(x.shape)}")
    if device is None:
        device = next((t.device for t in (*model.parameters(), *model.buffers())), torch.device("cpu"))
    else:
        model.to(device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    frames = x.to(device).unsqueeze(1).unbind(0)  # T x (1, N, C)
    globs: Sequence[torch.Tensor | None] = (
        [None] * len(frames) if g is None or g.shape[-1] == 0 else g.to(device).unsqueeze(1).unbind(0))  # T x (1, G)
    was_training = model.training
    model.eval()
    scores, seconds = [], []
    try:
        with torch.inference_mode():
            if warmup:
                model.step(frames[0], globs[0], model.init_state(1))
            state = model.init_state(1)
            with Progress(len(frames), f"stream {type(model).__name__}", "frames", enabled=progress,
                          log_every=LOG_SECONDS) as bar:
                for x_t, g_t in zip(frames, globs):
                    sync()
                    start = time.perf_counter()
                    out, state = model.step(x_t, g_t, state)
                    sync()
                    seconds.append(time.perf_counter() - start)
                    scores.append(out.float().cpu())
                    bar.update(1)
    finally:
        model.train(was_training)
    stacked = torch.cat(scores) if scores else torch.empty(0, 0)  # (T, K)
    loss = loss or model_loss(model)
    return StreamTrace(stacked, scores_to_probabilities(stacked, loss), seconds, None if y is None else int(y),
                       frame_period, loss)
