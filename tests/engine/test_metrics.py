from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn import metrics as skm

from tactile_zoo.engine.metrics import (
    accuracy,
    balanced_accuracy,
    classification_metrics,
    confusion_matrix,
    macro_f1,
    scores_to_probabilities,
)


@pytest.mark.filterwarnings("ignore:y_pred contains classes not in y_true")
@pytest.mark.parametrize("seed", range(5))
def test_metrics_match_scikit_learn(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = 5
    y_true = rng.integers(0, k - 1, size=40)  # class 4 never occurs in y_true
    y_pred = np.where(rng.random(40) < 0.6, y_true, rng.integers(0, k, size=40))
    assert accuracy(y_true, y_pred) == pytest.approx(skm.accuracy_score(y_true, y_pred))
    assert balanced_accuracy(y_true, y_pred, k) == pytest.approx(skm.balanced_accuracy_score(y_true, y_pred))
    assert macro_f1(y_true, y_pred, k) == pytest.approx(skm.f1_score(y_true, y_pred, average="macro",
                                                                     zero_division=0))
    np.testing.assert_array_equal(confusion_matrix(y_true, y_pred, k),
                                  skm.confusion_matrix(y_true, y_pred, labels=list(range(k))))


def test_confusion_rows_are_true_classes() -> None:
    cm = confusion_matrix([0, 0, 1], [1, 1, 1], 3)
    assert cm.tolist() == [[0, 2, 0], [0, 1, 0], [0, 0, 0]]
    out = classification_metrics(torch.tensor([0, 0, 1]), torch.tensor([1, 1, 1]), 3)
    assert out["accuracy"] == pytest.approx(1 / 3) and out["n"] == 3 and out["confusion"][0][1] == 2


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
