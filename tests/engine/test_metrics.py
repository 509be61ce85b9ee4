from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn import metrics as skm

from tactile_zoo.engine.metrics import (
    MetricError,
    MetricInputMissing,
    accuracy,
    balanced_accuracy,
    classification_metrics,
    confusion_matrix,
    macro_f1,
    metric_value,
    register_metric,
    registered_metrics,
    scores_to_probabilities,
    unregister_metric,
)
from tactile_zoo.errors import ConfigError


@pytest.mark.filterwarnings("ignore:y_pred contains classes not in y_true")
@pytest.mark.parametrize("seed", range(5))
def test_metrics_match_scikit_learn(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = 5
    y_true = rng.integers(0, k - 1, size=40)  # class 4 never occurs in y_true
    y_pred = np.where(rng.random(40) < 0.6, y_true, rng.integers(0, k, size=40))
    # exactly scikit-learn's numbers (these metrics are computed by it), not approximately
    assert accuracy(y_true, y_pred) == skm.accuracy_score(y_true, y_pred)
    assert balanced_accuracy(y_true, y_pred, k) == skm.balanced_accuracy_score(y_true, y_pred)
    assert macro_f1(y_true, y_pred, k) == skm.f1_score(y_true, y_pred, average="macro", zero_division=0)
    np.testing.assert_array_equal(confusion_matrix(y_true, y_pred, k),
                                  skm.confusion_matrix(y_true, y_pred, labels=list(range(k))))


def test_confusion_rows_are_true_classes() -> None:
    cm = confusion_matrix([0, 0, 1], [1, 1, 1], 3)
    assert cm.tolist() == [[0, 2, 0], [0, 1, 0], [0, 0, 0]]
    out = classification_metrics(torch.tensor([0, 0, 1]), torch.tensor([1, 1, 1]), 3)
    assert out["accuracy"] == pytest.approx(1 / 3) and out["n"] == 3 and out["confusion"][0][1] == 2


@pytest.mark.filterwarnings("error")  # the conventions below are deliberate: no sklearn warning may leak
def test_class_absent_from_y_true_counts_in_f1_not_in_balanced_accuracy() -> None:
    y_true, y_pred = [0, 0, 1, 1], [0, 2, 1, 1]  # class 2 predicted once, never true; class 3 in neither
    out = classification_metrics(y_true, y_pred, 4)
    assert out["accuracy"] == 0.75 and out["n"] == 4
    assert out["balanced_accuracy"] == 0.75  # recalls of classes 0 and 1 only: (0.5 + 1) / 2
    assert out["macro_f1"] == pytest.approx((2 / 3 + 1 + 0) / 3)  # classes 0, 1, 2; F1 of class 2 is 0
    assert out["confusion"] == [[1, 0, 1, 0], [0, 2, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]


@pytest.mark.filterwarnings("error")
def test_class_never_predicted_has_f1_zero() -> None:
    y_true, y_pred = [0, 1, 2, 2], [0, 0, 0, 2]  # class 1 never predicted
    assert balanced_accuracy(y_true, y_pred, 4) == 0.5  # (1 + 0 + 0.5) / 3
    assert macro_f1(y_true, y_pred, 4) == pytest.approx((0.5 + 0 + 2 / 3) / 3)  # class 3 (in neither) not counted


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("k", [1, 3])
def test_a_single_class(k: int) -> None:
    out = classification_metrics([0, 0, 0], [0, 0, 0], k)
    assert (out["accuracy"], out["balanced_accuracy"], out["macro_f1"]) == (1.0, 1.0, 1.0)
    assert out["confusion"][0][0] == 3 and len(out["confusion"]) == k
    assert (balanced_accuracy([1, 1], [0, 0]), macro_f1([1, 1], [0, 0])) == (0.0, 0.0)


def test_empty_split_is_nan_and_zero_counts() -> None:
    out = classification_metrics([], [], 3)
    assert all(np.isnan(out[m]) for m in ("accuracy", "balanced_accuracy", "macro_f1"))
    assert out["n"] == 0 and out["confusion"] == [[0] * 3] * 3


@pytest.mark.parametrize(("y_true", "y_pred"), [([0, 1], [0, 2]), ([0, -1], [0, 0]), ([3], [0])])
def test_labels_out_of_range_are_an_error(y_true: list[int], y_pred: list[int]) -> None:
    with pytest.raises(ValueError, match="labels must lie in"):
        classification_metrics(y_true, y_pred, 2)
    with pytest.raises(ValueError, match="labels"):
        confusion_matrix([0, 1], [0], 2)


def test_probabilities_softmax_for_ce() -> None:
    scores = torch.tensor([[2.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    probs = scores_to_probabilities(scores, "ce")
    torch.testing.assert_close(probs, torch.softmax(scores, -1))


def test_probabilities_rates_normalised_and_uniform_when_silent() -> None:
    rates = torch.tensor([[0.2, 0.6, 0.2], [0.0, 0.0, 0.0], [-0.1, 0.3, 0.1]])
    probs = scores_to_probabilities(rates, "mse_rate")
    torch.testing.assert_close(probs[0], torch.tensor([0.2, 0.6, 0.2]))
    torch.testing.assert_close(probs[1], torch.full((3,), 1 / 3))
    torch.testing.assert_close(probs[2], torch.tensor([0.0, 0.75, 0.25]))  # negative rates clip to 0
    torch.testing.assert_close(probs.sum(-1), torch.ones(3))
    with pytest.raises(ValueError, match="unknown loss"):
        scores_to_probabilities(rates, "hinge")


# ----------------------------------------------------------------------------------------------- the registry
def test_the_three_fixed_metrics_are_registered_first_and_match_the_stored_ones() -> None:
    fixed = registered_metrics()[:3]
    assert [(m.name, m.needs, m.label) for m in fixed] == [
        ("accuracy", "predictions", "accuracy"), ("balanced_accuracy", "predictions", "balanced acc."),
        ("macro_f1", "predictions", "macro-F1")]
    split = {"targets": [0, 1, 2, 2, 1, 0, 2], "predictions": [0, 2, 2, 2, 1, 1, 0]}
    stored = classification_metrics(split["targets"], split["predictions"], 3)
    assert {m.name: metric_value(m, split) for m in fixed} == {k: stored[k] for k in (m.name for m in fixed)}


@pytest.mark.parametrize(("name", "needs"), [("Top2", "predictions"), ("accuracy_test", "predictions"),
                                             ("2nd", "predictions"), ("ok_name", "logits"),
                                             ("accuracy", "predictions")])
def test_a_bad_or_taken_name_or_need_is_refused(name: str, needs: str) -> None:
    before = registered_metrics()
    with pytest.raises(ConfigError, match=repr(name)):
        register_metric(name, needs=needs)(lambda labels, predictions: 0.0)
    assert registered_metrics() == before


def test_metric_value_reads_the_stored_split_and_names_a_broken_metric() -> None:
    seen = []

    @register_metric("probe_mean_prob", needs="probabilities")
    def probe(labels: np.ndarray, probabilities: np.ndarray) -> float:
        seen.append((labels.dtype, labels.shape, probabilities.dtype, probabilities.shape))
        return float(probabilities[np.arange(len(labels)), labels].mean())

    register_metric("probe_text")(lambda labels, predictions: "high")
    register_metric("probe_nan")(lambda labels, predictions: float("nan"))
    try:
        metric = {m.name: m for m in registered_metrics()}
        split = {"targets": [1, 0], "predictions": [1, 1], "probabilities": [[0.25, 0.75], [0.5, 0.5]]}
        assert metric_value(metric["probe_mean_prob"], split) == 0.625
        assert seen == [(np.dtype(np.int64), (2,), np.dtype(np.float64), (2, 2))]
        with pytest.raises(MetricInputMissing, match="probabilities"):
            metric_value(metric["probe_mean_prob"], {"targets": [1], "predictions": [1]})
        with pytest.raises(MetricError, match=r"metric 'probe_text' returned 'high' on cell x; expected a number"):
            metric_value(metric["probe_text"], split, "cell x")
        assert metric_value(metric["probe_nan"], split) is None  # as an empty split's accuracy: no number
        with pytest.raises(MetricError, match=r"metric 'probe_mean_prob' .*failed on cell y: IndexError"):
            metric_value(metric["probe_mean_prob"], {"targets": [5], "probabilities": [[0.5, 0.5]]}, "cell y")
    finally:
        for name in ("probe_mean_prob", "probe_text", "probe_nan"):
            unregister_metric(name)
    assert "probe_text" not in {m.name for m in registered_metrics()}
