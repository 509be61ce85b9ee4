"""Is recipe b better than recipe a? A paired interval of the accuracy difference, and Holm's correction.

Comparing two recipes by their separate intervals (:func:`~tactile_zoo.bench.intervals.bootstrap_accuracy`) wastes
most of the evidence. When both recipes are run on the same cells (same fold, same seed, same test set), most of the
chance in their accuracies is shared: a seed that splits the data badly, or a test sample that is hard, hurts both.
Each interval carries that shared noise in full, so two intervals can overlap widely while b beats a on every seed.
What the question needs is the interval of the *difference*, and the shared noise cancels in it.

:func:`paired_bootstrap` uses the method of :mod:`tactile_zoo.bench.intervals` on the per-unit gain ``correct_b -
correct_a``: one bootstrap draw of the test units per resample, shared by every pair of runs scored on that test set
and scoring both recipes on exactly those units (a unit is a sample or, with ``groups``, a recording with all its
windows), gives the test part of the variance; the spread of the pairs' differences over seeds gives the seed part.
The statistic is the mean over the pairs of ``acc_b - acc_a``; the interval is that mean plus or minus
``sqrt(t_{S-1}^2 v_seed + t_{U-1}^2 v_test)``.

The one-sided p-value (H0: b is not better than a) inverts the same construction: p is the ``alpha`` at which the
one-sided lower bound ``d - sqrt(t_{S-1}(1-alpha)^2 v_seed + t_{U-1}(1-alpha)^2 v_test)`` reaches 0, so "p < 0.05"
and "the one-sided 95 % lower bound is above 0" say the same. ``tools/interval_coverage.py`` measures its
false-positive rate under a true difference of zero.

When several recipes are tried against one baseline, the smallest of their p-values is small by chance alone;
:func:`holm` adjusts a family of p-values (Holm-Bonferroni step-down) so that the chance of any false "better" in the
family stays at the nominal level, without the full price of Bonferroni for the later, larger p-values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from .intervals import DEFAULT_RESAMPLES, Components, units_of, variance_components

__all__ = ["PairedResult", "paired_bootstrap", "records_paired", "holm", "P_FLOOR"]

P_FLOOR = 1e-9  #: the smallest p-value reported


@dataclass(frozen=True)
class PairedResult:
    """The accuracy of recipe b minus that of recipe a, over paired cells.

    Attributes:
        difference: mean over the paired cells of ``accuracy_b - accuracy_a`` on their full test sets.
        low: lower end of the ``level`` confidence interval of the expected difference.
        high: upper end of that interval.
        p_value: one-sided p-value of H0 "b is not better than a".
        n_cells: number of paired cells.
        resamples: bootstrap resamples behind ``low``, ``high`` and ``p_value``.
    """

    difference: float
    low: float
    high: float
    p_value: float
    n_cells: int
    resamples: int


def paired_bootstrap(cells: Sequence[tuple[Sequence[int], Sequence[int], Sequence[int]]], *,
                     groups: Sequence[Sequence] | None = None, resamples: int = DEFAULT_RESAMPLES,
                     level: float = 0.95, seed: int = 0) -> PairedResult:
    """The paired interval of the accuracy difference b - a over ``cells``, and its one-sided p-value.

    Args:
        cells: per paired cell, ``(targets, predictions_a, predictions_b)``: one test set scored by both recipes.
        groups: per cell, the independent unit of each sample (e.g. its recording); default: each sample its own.
        resamples: bootstrap resamples of the test units.
        level: coverage of the interval, e.g. 0.95.
        seed: seeds the resampling, so a table regenerates to the same digits.

    Returns:
        The observed difference, its interval and the one-sided p-value.

    Raises:
        ValueError: no cells, a cell whose targets and predictions differ in length or are empty, ``groups`` that do
            not match the cells, or ``resamples``/``level`` out of range.
    """
    if not cells:
        raise ValueError("no paired cells to compare")
    if resamples < 1:
        raise ValueError(f"resamples must be at least 1, got {resamples}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie strictly between 0 and 1, got {level}")
    if groups is not None and len(groups) != len(cells):
        raise ValueError(f"groups lists {len(groups)} cells, cells are {len(cells)}")

    runs = []
    for i, (targets, pred_a, pred_b) in enumerate(cells):
        t, a, b = np.asarray(targets), np.asarray(pred_a), np.asarray(pred_b)
        if t.size == 0 or t.shape != a.shape or t.shape != b.shape:
            raise ValueError(f"cell {i}: {t.size} targets, {a.size} predictions of a and {b.size} of b")
        if groups is not None and np.asarray(groups[i]).shape != t.shape:
            raise ValueError(f"cell {i}: {np.asarray(groups[i]).size} groups for {t.size} samples")
        unit, key = units_of(t, None if groups is None else groups[i])
        # Only the difference of the correct counts is needed, since both recipes are scored on the same drawn
        # units; that sharing is the pairing
        gain = (b == t).astype(np.int64) - (a == t).astype(np.int64)
        runs.append((np.bincount(unit, weights=gain), np.bincount(unit).astype(np.float64), key))
    parts = variance_components(runs, resamples=resamples, seed=seed)
    # integer gains over the sample counts, so that e.g. 30 of 100 reads 0.3, not 1.0 - 0.7
    difference = float(np.mean([num.sum() / counts.sum() for num, counts, _ in runs]))
    parts = Components(difference, parts.v_seed, parts.v_test, parts.n_runs, parts.n_units, parts.n_test_sets)
    low, high = parts.interval(level, (-1.0, 1.0))
    return PairedResult(difference, low, high, _p_value(parts), parts.n_runs, resamples)


def _p_value(parts: Components) -> float:
    """One-sided p of H0 "the expected difference is at most 0": the alpha whose one-sided lower bound is 0."""
    d = parts.estimate
    if parts.v_seed == 0.0 and parts.v_test == 0.0:  # no spread at all: the sign is all there is
        return 0.0 if d > 0 else 1.0
    if d == 0.0:
        return 0.5
    # the lower bound |d| - half_width(1 - alpha) rises with alpha on (0, 0.5]; half_width(0.5) = 0. Below
    # P_FLOOR, 1 - alpha rounds too close to 1 for the t quantiles: p is reported as that floor.
    def bound(alpha: float) -> float:
        return abs(d) - parts.half_width(1.0 - alpha)

    tail = P_FLOOR if bound(P_FLOOR) >= 0 else optimize.brentq(bound, P_FLOOR, 0.5, xtol=1e-12)
    return tail if d > 0 else 1.0 - tail


def records_paired(records_a: Sequence[dict[str, Any]], records_b: Sequence[dict[str, Any]], split: str = "test", *,
                   resamples: int = DEFAULT_RESAMPLES, level: float = 0.95, seed: int = 0) -> PairedResult:
    """:func:`paired_bootstrap` over two recipes' harness cell records, paired by ``(fold, seed)``.

    Only the ``(fold, seed)`` keys present in both lists are compared; the pairs are taken in key order, so the
    result does not depend on the order of the records. Groups (a recording per sample) come from record a.

    Raises:
        ValueError: no key in common, two records of one list with the same key, a record without predictions
            for ``split``, or paired cells whose targets differ (the message names both cell ids).
    """
    by_key_a, by_key_b = _by_fold_seed(records_a), _by_fold_seed(records_b)
    keys = sorted(by_key_a.keys() & by_key_b.keys())
    if not keys:
        raise ValueError(f"no (fold, seed) in common between the {len(records_a)} and {len(records_b)} cell records")
    cells, groups = [], []
    for key in keys:
        rec_a, rec_b = by_key_a[key], by_key_b[key]
        pred_a, pred_b = _split_predictions(rec_a, split), _split_predictions(rec_b, split)
        if not np.array_equal(np.asarray(pred_a["targets"]), np.asarray(pred_b["targets"])):
            # different test sets (another dataset, fold definition or ordering): a paired difference means nothing
            raise ValueError(f"cells {rec_a.get('cell_id', '?')} and {rec_b.get('cell_id', '?')}: "
                             f"the targets of split {split!r} differ")
        cells.append((pred_a["targets"], pred_a["predictions"], pred_b["predictions"]))
        groups.append(pred_a.get("groups") or list(range(len(pred_a["targets"]))))
    return paired_bootstrap(cells, groups=groups, resamples=resamples, level=level, seed=seed)


def holm(pvalues: Mapping[str, float]) -> dict[str, float]:
    """Holm-Bonferroni adjusted p-values, under the same keys.

    Sorted ascending, the i-th smallest (from 0) of m p-values is multiplied by ``m - i``, capped at 1 and raised to
    the largest adjusted value before it: a hypothesis is rejected only if all smaller ones are, so the adjusted
    values must not decrease along the order. Reject where the adjusted value is at most the family's level.
    """
    m = len(pvalues)
    adjusted: dict[str, float] = {}
    running = 0.0
    for i, (key, p) in enumerate(sorted(pvalues.items(), key=lambda item: item[1])):
        running = max(running, min(1.0, (m - i) * float(p)))
        adjusted[key] = running
    return {key: adjusted[key] for key in pvalues}


def _by_fold_seed(records: Sequence[dict[str, Any]]) -> dict[tuple[int, int], dict[str, Any]]:
    out: dict[tuple[int, int], dict[str, Any]] = {}
    for rec in records:
        key = (int(rec["fold"]), int(rec["seed"]))
        if key in out:
            # two cells for one key (two datasets or models mixed in one list) would pair arbitrarily
            raise ValueError(f"cells {out[key].get('cell_id', '?')} and {rec.get('cell_id', '?')} share fold "
                             f"{key[0]} and seed {key[1]}")
        out[key] = rec
    return out


def _split_predictions(rec: dict[str, Any], split: str) -> dict[str, Any]:
    pred = (rec.get("predictions") or {}).get(split)
    if not pred:
        raise ValueError(f"cell {rec.get('cell_id', '?')}: no stored predictions for split {split!r}")
    return pred
