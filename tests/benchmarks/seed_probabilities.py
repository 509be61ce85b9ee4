"""Test helper shared by the ensemble tests: five seeds whose averaged probabilities beat every seed alone."""

from __future__ import annotations


def one_wrong_each(targets: list[int], seed: int, classes: int = 3) -> tuple[list[list[float]], list[int]]:
    """Class probabilities and predictions of one seed that is confidently wrong on sample ``seed`` only and mildly
    right on the others: every seed scores ``len(targets) - 1`` right, and the mean over the seeds is right on all."""
    probabilities = [[0.1] * classes for _ in targets]
    for i, t in enumerate(targets):
        probabilities[i][t] = 0.5
    probabilities[seed][targets[seed]], probabilities[seed][(targets[seed] + 1) % classes] = 0.0, 0.9
    return probabilities, [max(range(classes), key=row.__getitem__) for row in probabilities]
