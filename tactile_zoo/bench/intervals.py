"""Intervals for accuracies: one bootstrap, shared by the report, the fidelity ledger and the recipe tables.

A figure such as "0.880 +- 0.011 over 3 seeds" mixes two sources of chance: which seeds were run and which test
samples were drawn. :func:`bootstrap_accuracy` resamples both, hierarchically: a resample draws the cells (seeds)
with replacement, then, within each drawn cell, its test units with replacement, and averages the accuracies. The
2.5 and 97.5 percentiles of those means are the 95 % interval.

The test *units* must be independent. For the Ev datasets a unit is a test sample; for windowed datasets (BioTac-DoS:
about 27 windows per recording, far from independent) pass ``groups`` (the recording of each sample) and a unit is a
recording with all its windows. Cell records carry it (``predictions[split]["groups"]``, written when samples share
a recording), and :func:`records_interval` passes it on, so every table that quotes a cell gets the same interval.

How to read an interval: "0.880 [0.851, 0.907] (3 seeds)" says that rerunning the experiment with fresh seeds and a
fresh test set of the same size would give a mean accuracy in that range 95 times in 100. Two models whose intervals
overlap widely are not shown apart by these runs; a paper figure above the interval is one these runs do not
reproduce.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["bootstrap_accuracy", "records_interval", "DEFAULT_RESAMPLES"]

DEFAULT_RESAMPLES = 2000


def bootstrap_accuracy(cells: Sequence[tuple[Sequence[int], Sequence[int]]], *,
                       groups: Sequence[Sequence] | None = None, resamples: int = DEFAULT_RESAMPLES,
                       level: float = 0.95, seed: int = 0) -> tuple[float, float] | None:
    """The ``level`` interval of the mean accuracy over ``cells``, each ``(targets, predictions)`` of one seed.

    Args:
        cells: per cell (seed), the test targets and the predictions (equal lengths).
        groups: per cell, the independent unit of each sample (e.g. its recording); default: each sample its own.
        resamples: bootstrap resamples (the interval's Monte-Carlo error is about 1/sqrt(resamples) of its width).
        level: coverage, e.g. 0.95.
        seed: seeds the resampling, so a report regenerates to the same digits.

    Returns:
        ``(low, high)``, or ``None`` when there is nothing to resample.
    """
    if not cells:
        return None
    rng = np.random.default_rng(seed)
    per_cell = []  # per cell: (units, correct count per unit, sample count per unit)
    for i, (targets, predictions) in enumerate(cells):
        t, p = np.asarray(targets), np.asarray(predictions)
        if t.shape != p.shape or t.size == 0:
            raise ValueError(f"cell {i}: {t.size} targets and {p.size} predictions")
        unit = np.arange(t.size) if groups is None else np.unique(np.asarray(groups[i]), return_inverse=True)[1]
        correct = np.bincount(unit, weights=(t == p).astype(np.float64))
        counts = np.bincount(unit).astype(np.float64)
        per_cell.append((correct, counts))
    means = np.empty(resamples)
    for r in range(resamples):
        picked = rng.integers(0, len(per_cell), len(per_cell))  # seeds with replacement
        accs = []
        for c in picked:
            correct, counts = per_cell[c]
            units = rng.integers(0, counts.size, counts.size)  # test units with replacement
            accs.append(correct[units].sum() / counts[units].sum())
        means[r] = float(np.mean(accs))
    tail = (1.0 - level) / 2
    low, high = np.quantile(means, [tail, 1.0 - tail])
    return float(low), float(high)


def records_interval(records: Sequence[dict[str, Any]], split: str = "test", *, level: float = 0.95,
                     resamples: int = DEFAULT_RESAMPLES, seed: int = 0) -> tuple[float, float] | None:
    """:func:`bootstrap_accuracy` over harness cell records (one per seed or fold), on ``split``'s stored predictions;
    a record that lists each sample's recording (``groups``) is resampled by recording."""
    cells, groups = [], []
    for rec in records:
        pred = (rec.get("predictions") or {}).get(split)
        if not pred:
            raise ValueError(f"cell {rec.get('cell_id', '?')}: no stored predictions for split {split!r}")
        cells.append((pred["targets"], pred["predictions"]))
        groups.append(pred.get("groups") or list(range(len(pred["targets"]))))
    return bootstrap_accuracy(cells, groups=groups, resamples=resamples, level=level, seed=seed)
