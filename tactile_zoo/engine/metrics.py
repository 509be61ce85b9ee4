"""Classification metrics and class probabilities, computed the same way for every model.

The definitions follow scikit-learn's, so numbers are comparable with papers that used it:

* ``accuracy``: fraction of correct predictions;
* ``balanced_accuracy``: mean recall over the classes present in ``y_true``;
* ``macro_f1``: mean F1 over the classes present in ``y_true`` or ``y_pred`` (a class never predicted has F1 0);
* ``confusion_matrix``: ``[true class, predicted class]`` counts over all ``num_classes`` classes.

Probabilities: ``softmax(scores)`` for a model trained with cross-entropy (``loss="ce"``, scores are logits);
for spike-rate outputs (``loss="mse_rate"``) the rates are clipped at 0 and normalised to sum 1, a sample whose rates
are all zero getting the uniform distribution.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

__all__ = ["accuracy", "balanced_accuracy", "macro_f1", "confusion_matrix", "classification_metrics",
           "scores_to_probabilities"]

ArrayLike = Sequence[int] | np.ndarray | torch.Tensor


def _np(labels: ArrayLike) -> np.ndarray:
    if isinstance(labels, torch.Tensor):
        labels = labels.detach().cpu().numpy()
    return np.asarray(labels, dtype=np.int64).reshape(-1)


def confusion_matrix(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> np.ndarray:
    """Counts ``[K, K]``: row = true class, column = predicted class."""
    t, p = _np(y_true), _np(y_pred)
    if t.shape != p.shape:
        raise ValueError(f"y_true has {t.size} labels, y_pred {p.size}")
    k = num_classes if num_classes is not None else int(max(t.max(initial=-1), p.max(initial=-1)) + 1)
    return np.bincount(t * k + p, minlength=k * k).reshape(k, k)


def accuracy(y_true: ArrayLike, y_pred: ArrayLike) -> float:
    t, p = _np(y_true), _np(y_pred)
    return float((t == p).mean()) if t.size else float("nan")


def balanced_accuracy(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> float:
    cm = confusion_matrix(y_true, y_pred, num_classes)
    support = cm.sum(axis=1)
    present = support > 0
    if not present.any():
        return float("nan")
    return float((np.diag(cm)[present] / support[present]).mean())


def macro_f1(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> float:
    cm = confusion_matrix(y_true, y_pred, num_classes)
    tp = np.diag(cm).astype(float)
    support, predicted = cm.sum(axis=1), cm.sum(axis=0)
    labels = (support > 0) | (predicted > 0)
    if not labels.any():
        return float("nan")
    denom = support + predicted  # F1 = 2 tp / (2 tp + fp + fn) = 2 tp / (support + predicted)
    f1 = np.divide(2 * tp, denom, out=np.zeros_like(tp), where=denom > 0)
    return float(f1[labels].mean())


def classification_metrics(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int) -> dict[str, Any]:
    """accuracy, balanced_accuracy, macro_f1 and the confusion matrix (as nested lists), for one split."""
    cm = confusion_matrix(y_true, y_pred, num_classes)
    return {"accuracy": accuracy(y_true, y_pred), "balanced_accuracy": balanced_accuracy(y_true, y_pred, num_classes),
            "macro_f1": macro_f1(y_true, y_pred, num_classes), "n": int(cm.sum()), "confusion": cm.tolist()}


def scores_to_probabilities(scores: torch.Tensor, loss: str = "ce") -> torch.Tensor:
    """Class probabilities ``[B, K]`` from a model's scores: softmax for ``ce``, normalised rates for ``mse_rate``."""
    scores = scores.float()
    if loss == "ce":
        return torch.softmax(scores, dim=-1)
    if loss == "mse_rate":
        rates = scores.clamp_min(0)
        total = rates.sum(dim=-1, keepdim=True)
        uniform = torch.full_like(rates, 1.0 / rates.shape[-1])
        return torch.where(total > 0, rates / total.clamp_min(torch.finfo(rates.dtype).tiny), uniform)
    raise ValueError(f"unknown loss {loss!r}; expected 'ce' or 'mse_rate'")
