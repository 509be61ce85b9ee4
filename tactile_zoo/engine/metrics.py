"""Classification metrics and class probabilities, computed the same way for every model.

The metrics are scikit-learn's (``sklearn.metrics``), so numbers are comparable with papers that used it:

* ``accuracy``: fraction of correct predictions (``accuracy_score``);
* ``balanced_accuracy``: mean recall over the classes present in ``y_true`` (``balanced_accuracy_score``);
* ``macro_f1``: mean F1 over the classes present in ``y_true`` or ``y_pred``, a class never predicted having F1 0
  (``f1_score(average="macro", zero_division=0)``);
* ``confusion_matrix``: ``[true class, predicted class]`` counts over all ``num_classes`` classes
  (``confusion_matrix(labels=range(num_classes))``).

An empty split gives NaN scores and an all-zero confusion matrix (scikit-learn raises there instead). Labels must lie in
``[0, num_classes)``: scikit-learn would silently drop the others from the confusion matrix.

The tables and ``tactile-zoo report`` read their test metrics from a registry (:func:`register_metric`): each
registered metric is one function of the labels and either the predictions or the class probabilities, computed
from what every cell record stores of its test split, so a metric added here appears for every finished cell,
committed ones included. ``accuracy``, ``balanced_accuracy`` and ``macro_f1`` are registered below.

Probabilities: ``softmax(scores)`` for a model trained with cross-entropy (``loss="ce"``, scores are logits);
for spike-rate outputs (``loss="mse_rate"``) the rates are clipped at 0 and normalised to sum 1, a sample whose rates
are all zero getting the uniform distribution.

Ties (:func:`tied_top`): when two or more classes share the top score (an SNN whose output neurons have not fired
yet: all rates 0, p = 1/K each), the model has named no class. Early classification
(:func:`~tactile_zoo.engine.evaluate.prefix_evaluation`) and streaming (:mod:`tactile_zoo.engine.stream`) count such
a sample as undecided, never as correct. The full-sequence test metrics above keep ``argmax`` (the lowest tied class
index), as every published cell computed them.
"""

from __future__ import annotations

import contextlib
import math
import re
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import torch

from ..errors import ConfigError, TactileZooError

__all__ = ["accuracy", "balanced_accuracy", "macro_f1", "confusion_matrix", "classification_metrics",
           "scores_to_probabilities", "tied_top", "Metric", "MetricError", "MetricInputMissing", "NEEDS",
           "register_metric", "unregister_metric", "registered_metrics", "metric_value"]

ArrayLike = Sequence[int] | np.ndarray | torch.Tensor
_F = TypeVar("_F", bound=Callable[..., Any])

#: what a metric can be computed from, besides the true labels: the predicted classes, or the class probabilities
NEEDS = ("predictions", "probabilities")
# a metric becomes a table column (``leaderboard.csv``) and ``<name>_mean`` (``summary.csv``): a plain lower-case name
_NAME = re.compile(r"[a-z][a-z0-9_]*")


class MetricError(TactileZooError):
    """A registered metric that raised, or returned something other than a number; the message names the metric."""


class MetricInputMissing(LookupError):
    """A split stores no ``needs`` (class probabilities, or predictions) for the metric ``name``."""

    def __init__(self, name: str, needs: str) -> None:
        super().__init__(f"metric {name!r} needs {needs}, which the split does not store")
        self.name, self.needs = name, needs


@dataclass(frozen=True)
class Metric:
    """One registered metric: ``fn(labels, predictions)`` or ``fn(labels, probabilities)`` -> a number.

    Attributes:
        name: the column name (``leaderboard.csv``; ``<name>_mean`` in ``summary.csv``).
        needs: ``"predictions"`` (int64 class indices ``[N]``) or ``"probabilities"`` (float64 ``[N, K]``).
        fn: the function; the labels it gets are int64 ``[N]``.
        label: the column title in ``report.md``.
    """

    name: str
    needs: str
    fn: Callable[[np.ndarray, np.ndarray], float]
    label: str


_METRICS: dict[str, Metric] = {}


def register_metric(name: str, needs: str = "predictions", label: str | None = None) -> Callable[[_F], _F]:
    """Decorator: register ``fn(labels, predictions)`` (or ``fn(labels, probabilities)``) as the metric ``name``.

    The function is returned unchanged. The tables compute it from each cell record's stored test split; a record
    that lacks what it ``needs`` shows a marker instead (see :mod:`tactile_zoo.bench.tables`).

    Args:
        name: a lower-case name (``[a-z][a-z0-9_]*``), not yet registered and not starting with ``accuracy_`` (the
            tables' per-split and per-prefix accuracy columns).
        needs: ``"predictions"`` or ``"probabilities"``.
        label: the column title in ``report.md`` (default: ``name``).

    Raises:
        ConfigError: a bad or taken name, or an unknown ``needs``.
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name) or name.startswith("accuracy_"):
        raise ConfigError(f"metric name {name!r}: expected lower-case letters, digits and _ (not accuracy_...)")
    if needs not in NEEDS:
        raise ConfigError(f"metric {name!r}: needs={needs!r}; expected one of {', '.join(NEEDS)}")
    if name in _METRICS:
        raise ConfigError(f"metric {name!r} is already registered (by {_METRICS[name].fn.__module__})")

    def decorate(fn: _F) -> _F:
        _METRICS[name] = Metric(name, needs, fn, label or name)
        return fn

    return decorate


def unregister_metric(name: str) -> None:
    """Remove the metric ``name`` (a test's own metric, when the test ends); an unknown name is left alone."""
    _METRICS.pop(name, None)


def registered_metrics() -> tuple[Metric, ...]:
    """Every registered metric, in registration order (the order of the table columns)."""
    return tuple(_METRICS.values())


def metric_value(metric: Metric, split: Mapping[str, Any], where: str = "") -> float | None:
    """``metric`` computed from one stored split (``{"targets", "predictions"[, "probabilities"]}``, as a cell
    record keeps it); ``None`` for an empty split or a NaN result.

    Raises:
        MetricInputMissing: the split stores no ``metric.needs``.
        MetricError: the metric raised or returned something other than a real number (``where``, e.g. the cell,
            is named with the metric).
    """
    values = split.get(metric.needs)
    if values is None or split.get("targets") is None:
        raise MetricInputMissing(metric.name, metric.needs)
    at = f" on {where}" if where else ""
    try:
        labels = _np(split["targets"])
        inputs = _np(values) if metric.needs == "predictions" else np.asarray(values, dtype=np.float64)
        result = metric.fn(labels, inputs)
    except Exception as exc:  # whatever a metric's own code raises, one error that names it
        raise MetricError(f"metric {metric.name!r} ({metric.fn.__module__}.{metric.fn.__qualname__}) failed{at}: "
                          f"{type(exc).__name__}: {exc}") from exc
    if isinstance(result, (bool, np.bool_)) or not isinstance(result, (int, float, np.integer, np.floating)):
        raise MetricError(f"metric {metric.name!r} returned {result!r}{at}; expected a number")
    result = float(result)
    if math.isinf(result):
        raise MetricError(f"metric {metric.name!r} returned {result}{at}; expected a finite number")
    return None if math.isnan(result) else result


def _np(labels: ArrayLike) -> np.ndarray:
    if isinstance(labels, torch.Tensor):
        labels = labels.detach().cpu().numpy()
    return np.asarray(labels, dtype=np.int64).reshape(-1)


def _pair(y_true: ArrayLike, y_pred: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    t, p = _np(y_true), _np(y_pred)
    if t.shape != p.shape:
        raise ValueError(f"y_true has {t.size} labels, y_pred {p.size}")
    return t, p


def _skm() -> Any:
    """``sklearn.metrics``, imported on first use: with the scipy and pandas parts it loads it adds about a second to
    ``import tactile_zoo``, which every command and worker process would pay while only evaluation needs it."""
    from sklearn import metrics

    return metrics


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the two sklearn warnings about conventions that are deliberate here."""
    with warnings.catch_warnings():
        # balanced accuracy leaves classes absent from y_true out of the mean, which is the definition used here (a
        # split need not hold every class), but sklearn warns about it
        warnings.filterwarnings("ignore", message="y_pred contains classes not in y_true")
        # a 1 x 1 confusion matrix (one class seen, or num_classes=1) is correct here, yet sklearn suspects a
        # forgotten `labels`
        warnings.filterwarnings("ignore", message="A single label was found")
        yield


def confusion_matrix(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> np.ndarray:
    """Counts ``[K, K]`` (int64): row = true class, column = predicted class; ``K = num_classes``, else the largest
    label + 1."""
    t, p = _pair(y_true, y_pred)
    k = num_classes if num_classes is not None else int(max(t.max(initial=-1), p.max(initial=-1)) + 1)
    if t.size == 0:
        return np.zeros((k, k), dtype=np.int64)  # sklearn refuses an empty split (or an empty label list)
    low, high = min(int(t.min()), int(p.min())), max(int(t.max()), int(p.max()))
    if low < 0 or high >= k:
        # sklearn would drop such samples from the counts without a word; a label out of range is a caller's bug
        raise ValueError(f"labels must lie in [0, {k}); got {low}..{high}")
    with _quiet():
        return _skm().confusion_matrix(t, p, labels=np.arange(k)).astype(np.int64, copy=False)


@register_metric("accuracy", label="accuracy")
def accuracy(y_true: ArrayLike, y_pred: ArrayLike) -> float:
    t, p = _pair(y_true, y_pred)
    return float(_skm().accuracy_score(t, p)) if t.size else float("nan")


@register_metric("balanced_accuracy", label="balanced acc.")
def balanced_accuracy(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> float:
    """Mean recall over the classes that occur in ``y_true``; ``num_classes`` only validates the labels (a class
    absent from ``y_true`` has no recall, whatever the number of classes)."""
    t, p = _pair(y_true, y_pred)
    if num_classes is not None:
        confusion_matrix(t, p, num_classes)  # same label check as the other metrics
    if not t.size:
        return float("nan")
    with _quiet():
        return float(_skm().balanced_accuracy_score(t, p))


@register_metric("macro_f1", label="macro-F1")
def macro_f1(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int | None = None) -> float:
    """Mean F1 over the classes in ``y_true`` or ``y_pred`` (classes in neither do not count, whatever
    ``num_classes``, which only validates the labels)."""
    t, p = _pair(y_true, y_pred)
    if num_classes is not None:
        confusion_matrix(t, p, num_classes)
    if not t.size:
        return float("nan")
    # labels=None: sklearn averages over the union of the labels seen; zero_division=0 scores a class never predicted
    # 0 without a warning (its F1 = 2 tp / (support + predicted) is defined anyway since support > 0)
    return float(_skm().f1_score(t, p, average="macro", zero_division=0))


def classification_metrics(y_true: ArrayLike, y_pred: ArrayLike, num_classes: int) -> dict[str, Any]:
    """accuracy, balanced_accuracy, macro_f1 and the confusion matrix (as nested lists), for one split."""
    t, p = _pair(y_true, y_pred)
    cm = confusion_matrix(t, p, num_classes)
    return {"accuracy": accuracy(t, p), "balanced_accuracy": balanced_accuracy(t, p),
            "macro_f1": macro_f1(t, p), "n": int(cm.sum()), "confusion": cm.tolist()}


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


def tied_top(scores: torch.Tensor, loss: str = "ce") -> torch.Tensor:
    """``[B]`` bool: whether the top score of each row of ``scores [B, K]`` is shared by two or more classes (an
    undecided answer; ``argmax`` would silently pick the lowest tied class). Spike rates (``loss="mse_rate"``) are
    compared as the probabilities see them, clipped at 0, so all-silent outputs are a tie."""
    values = scores.float()
    if loss == "mse_rate":
        values = values.clamp_min(0)
    if values.shape[-1] < 2:
        return torch.zeros(values.shape[:-1], dtype=torch.bool)
    top = values.max(dim=-1, keepdim=True).values
    return (values == top).sum(dim=-1) > 1
