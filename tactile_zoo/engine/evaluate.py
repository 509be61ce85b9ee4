"""Inference: class scores in batches under ``torch.inference_mode``, metrics, prefixes, latency.

``evaluate(model, dataset)`` is the public entry point; the harness also uses :func:`prefix_evaluation` (early
classification: the selected model on the first 10/25/50/75/100 % of every test sequence, no retraining) and
:func:`time_inference` (batch-1 latency).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from .metrics import (
    accuracy,
    balanced_accuracy,
    classification_metrics,
    confusion_matrix,
    scores_to_probabilities,
    tied_top,
)
from .progress import LOG_SECONDS, Progress
from .runtime import flush_denormals, resolve_device
from .tensors import as_split

__all__ = ["EvalResult", "evaluate", "predict_scores", "prefix_evaluation", "time_inference", "model_loss",
           "DEFAULT_PREFIXES", "earliness", "prefix_steps"]

DEFAULT_PREFIXES = (0.1, 0.25, 0.5, 0.75, 1.0)


@dataclass
class EvalResult:
    """Metrics and per-sample outputs of one split."""

    metrics: dict[str, Any]
    predictions: list[int]
    probabilities: list[list[float]]
    targets: list[int]
    loss: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def accuracy(self) -> float:
        return float(self.metrics["accuracy"])

    def to_dict(self) -> dict[str, Any]:
        return {"metrics": self.metrics, "predictions": self.predictions, "probabilities": self.probabilities,
                "targets": self.targets, "loss": self.loss}


def model_loss(model: torch.nn.Module, default: str = "ce") -> str:
    """The loss a model was (or will be) trained with: what :func:`fit` recorded, else its registered recipe."""
    loss = getattr(model, "zoo_loss", None)
    if loss is None:
        meta = getattr(model, "zoo_meta", None) or {}
        loss = (meta.get("recipe") or {}).get("loss")
    return loss or default


def _device_of(model: torch.nn.Module) -> torch.device:
    for tensor in (*model.parameters(), *model.buffers()):
        return tensor.device
    return torch.device("cpu")


def predict_scores(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, batch_size: int = 256,
                   device: torch.device | None = None, progress: Progress | None = None) -> torch.Tensor:
    """The model's scores ``[S, K]`` on CPU, computed in eval mode, in batches, under ``inference_mode``;
    ``progress`` (a :class:`~tactile_zoo.engine.progress.Progress` over batches) is updated after each batch."""
    device = device or _device_of(model)
    was_training = model.training
    model.eval()
    outs = []
    try:
        with torch.inference_mode():
            for start in range(0, x.shape[0], batch_size):
                xb = x[start:start + batch_size].to(device, non_blocking=True)  # (B, T, N, C)
                gb = None if g is None or g.shape[-1] == 0 else g[start:start + batch_size].to(device)  # (B, T, G)
                out = model(xb, gb)
                if out.dim() != 2 or out.shape[0] != xb.shape[0]:
                    raise RuntimeError(f"{type(model).__name__}.forward returned shape {tuple(out.shape)}; expected "
                                       f"[batch={xb.shape[0]}, num_classes]")
                outs.append(out.float().cpu())
                if progress is not None:
                    progress.update(1)
    finally:
        model.train(was_training)
    return torch.cat(outs) if outs else torch.empty(0, 0)


def _result(scores: torch.Tensor, y: torch.Tensor, num_classes: int, loss: str) -> EvalResult:
    probs = scores_to_probabilities(scores, loss)
    pred = scores.argmax(dim=-1)
    metrics = classification_metrics(y, pred, num_classes)
    return EvalResult(metrics, pred.tolist(), probs.tolist(), y.tolist())


@flush_denormals()
def evaluate(model: torch.nn.Module, dataset: Any, *, loss: str | None = None, batch_size: int = 256,
             device: str | torch.device | None = None, progress: bool = True) -> EvalResult:
    """Evaluate ``model`` on a whole split: metrics (accuracy, balanced accuracy, macro F1, confusion matrix),
    per-sample predictions and probabilities.

    Args:
        model: a model following the zoo contract ``forward(x, g=None) -> scores [B, K]``.
        dataset: a split (anything with ``.spec`` and ``.tensors()``, or a dataset of ``TactileSample``).
        loss: ``"ce"`` or ``"mse_rate"``: how scores become probabilities (default: what :func:`fit` or the
            model's registered recipe says, else ``"ce"``).
        device: where to run (default: where the model's parameters are; ``"auto"`` = CUDA when available).
        progress: a bar over batches on a terminal, log records otherwise (see
            :mod:`tactile_zoo.engine.progress`); ``False``: nothing.
    """
    split = as_split(dataset)
    dev = resolve_device(device) if device is not None else _device_of(model)
    if device is not None:
        model.to(dev)
    name = getattr(split.spec, "name", "data")
    with Progress(-(-split.x.shape[0] // batch_size), f"evaluate {type(model).__name__} on {name}", "batches",
                  enabled=progress, log_every=LOG_SECONDS) as bar:
        scores = predict_scores(model, split.x, split.g, batch_size, dev, progress=bar)
    return _result(scores, split.y, split.spec.num_classes, loss or model_loss(model))


def prefix_steps(num_steps: int, fractions: Sequence[float]) -> list[int]:
    """Time steps kept for each prefix fraction: ``round(fraction * T)``, at least 1."""
    return [max(1, min(num_steps, int(math.floor(f * num_steps + 0.5)))) for f in fractions]


def earliness(fractions: Sequence[float], accuracies: Sequence[float | None], full_accuracy: float,
              ratio: float = 0.9) -> float | None:
    """The smallest prefix fraction whose accuracy reaches ``ratio`` x the full-sequence accuracy."""
    for frac, acc in sorted(zip(fractions, accuracies)):
        if acc is not None and acc >= ratio * full_accuracy - 1e-12:
            return float(frac)
    return None


@flush_denormals()
def prefix_evaluation(model: torch.nn.Module, dataset: Any, fractions: Sequence[float] = DEFAULT_PREFIXES, *,
                      causal: bool = False, loss: str | None = None, batch_size: int = 256,
                      device: torch.device | None = None) -> dict[str, Any]:
    """Accuracy of the (already trained) model on the first ``fraction`` of every sequence, for each fraction.

    A causal model just stops reading. A non-causal model gets the prefix as its whole input; if it cannot take a
    shorter sequence (it raises), the unseen rest is zero-filled instead, and ``input`` says ``"zero_padded"``.

    A sample whose top score is tied (:func:`~tactile_zoo.engine.metrics.tied_top`: an SNN that has not fired yet)
    is undecided at that prefix: it counts as wrong in ``accuracy`` and ``balanced_accuracy``, and ``undecided``
    holds the fraction of such samples per prefix. (The full-sequence test metrics of :func:`evaluate` keep
    ``argmax``, so ``accuracy`` at 1.0 can be below the test accuracy: by the tied samples whose true class
    happened to be argmax's pick, the lowest tied class.)
    """
    split = as_split(dataset)
    loss = loss or model_loss(model)
    fractions = sorted({float(f) for f in fractions} | {1.0})
    num_steps = split.x.shape[1]
    steps = prefix_steps(num_steps, fractions)
    mode = "truncated"
    accuracies: list[float] = []
    balanced: list[float] = []
    undecided: list[float] = []
    for t in steps:
        x, g = split.x[:, :t], split.g[:, :t]  # (S, t, N, C), (S, t, G)
        if mode == "truncated":
            try:
                scores = predict_scores(model, x, g, batch_size, device)
            except Exception:
                if t == num_steps:
                    raise
                mode = "zero_padded"
        if mode == "zero_padded":
            xz, gz = torch.zeros_like(split.x), torch.zeros_like(split.g)
            xz[:, :t], gz[:, :t] = x, g
            scores = predict_scores(model, xz, gz, batch_size, device)
        acc, bal, tied = _decided_scores(scores, split.y, split.spec.num_classes, loss)
        accuracies.append(acc)
        balanced.append(bal)
        undecided.append(tied)
    full = accuracies[-1]
    return {"causal": bool(causal), "input": "causal" if causal else mode, "fractions": fractions, "steps": steps,
            "accuracy": accuracies, "balanced_accuracy": balanced, "earliness": earliness(fractions, accuracies, full),
            "undecided": undecided}


def _decided_scores(scores: torch.Tensor, y: torch.Tensor, num_classes: int, loss: str) -> tuple[float, float, float]:
    """``(accuracy, balanced accuracy, fraction undecided)`` of one prefix, a tie (:func:`tied_top`) counting as
    undecided: as a prediction of no class, never correct."""
    pred = scores.argmax(dim=-1)
    tied = tied_top(scores, loss)
    confusion_matrix(y, pred, num_classes)  # the labels' range check, as for the full test metrics
    pred = torch.where(tied, torch.full_like(pred, num_classes), pred)  # a class no sample has: never a hit
    return accuracy(y, pred), balanced_accuracy(y, pred), float(tied.float().mean()) if len(y) else 0.0


@flush_denormals()
def time_inference(model: torch.nn.Module, dataset: Any, samples: int = 8, device: torch.device | None = None
                   ) -> float | None:
    """Mean milliseconds per sample at batch size 1 over up to ``samples`` samples (after one warm-up call)."""
    split = as_split(dataset)
    if len(split) == 0:
        return None
    device = device or _device_of(model)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    was_training = model.training
    model.eval()
    times = []
    try:
        with torch.inference_mode():
            n = min(samples, len(split))
            for i in range(-1, n):  # i = -1: warm-up
                j = max(i, 0)
                xb = split.x[j:j + 1].to(device)
                gb = None if split.g.shape[-1] == 0 else split.g[j:j + 1].to(device)
                sync()
                start = time.perf_counter()
                model(xb, gb)
                sync()
                if i >= 0:
                    times.append(time.perf_counter() - start)
    finally:
        model.train(was_training)
    return round(1000 * sum(times) / len(times), 4)
