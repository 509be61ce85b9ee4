"""Is recipe b better than recipe a? A paired bootstrap of the accuracy difference, and Holm's correction.

Comparing two recipes by their separate intervals (:func:`~tactile_zoo.bench.intervals.bootstrap_accuracy`) wastes
most of the evidence. When both recipes are run on the same cells (same fold, same seed, same test set), most of the
chance in their accuracies is shared: a seed that splits the data badly, or a test sample that is hard, hurts both.
Each interval carries that shared noise in full, so two intervals can overlap widely while b beats a on every seed.
What the question needs is the interval of the *difference*, and the shared noise cancels in it.

:func:`paired_bootstrap` keeps the hierarchy of ``bootstrap_accuracy`` (cells with replacement, then the test units
of each drawn cell with replacement; a unit is a sample or, with ``groups``, a recording with all its windows) and
pairs the two recipes inside it: a resample draws one set of units per drawn cell and scores both recipes on exactly
those units. The statistic is the mean over the drawn cells of ``acc_b - acc_a``; its ``level`` percentiles are the
interval.

The one-sided p-value (H0: b is not better than a) comes from the same resamples, shifted: ``d* - d`` imitates how
the difference scatters around its true value, so under a true difference of zero it is a draw of the statistic
itself, and ``p = (1 + #{d* - d >= d}) / (resamples + 1)``. The added one counts the observed run among the draws,
so p never reads 0 from a finite number of resamples: its floor is ``1 / (resamples + 1)``.

When several recipes are tried against one baseline, the smallest of their p-values is small by chance alone;
:func:`holm` adjusts a family of p-values (Holm-Bonferroni step-down) so that the chance of any false "better" in the
family stays at the nominal level, without the full price of Bonferroni for the later, larger p-values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .intervals import DEFAULT_RESAMPLES

__all__ = ["PairedResult", "paired_bootstrap", "records_paired", "holm"]


@dataclass(frozen=True)
class PairedResult:
    """The accuracy of recipe b minus that of recipe a, over paired cells.

    Attributes:
        difference: mean over the paired cells of ``accuracy_b - accuracy_a`` on their full test sets.
        low: lower end of the ``level`` percentile interval of the bootstrap difference.
        high: upper end of that interval.
        p_value: one-sided p-value of H0 "b is not better than a"; at least ``1 / (resamples + 1)``.
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
    """Paired hierarchical bootstrap of the accuracy difference b - a over ``cells``.

    Args:
        cells: per paired cell, ``(targets, predictions_a, predictions_b)``: one test set scored by both recipes.
        groups: per cell, the independent unit of each sample (e.g. its recording); default: each sample its own.
        resamples: bootstrap resamples.
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

    # Per cell, per unit: (correct_b - correct_a) and the sample count. Only the difference of the correct counts is
    # needed, since both recipes are scored on the same drawn units; that sharing is the pairing.
    per_cell: list[tuple[np.ndarray, np.ndarray]] = []
    observed = []
    for i, (targets, pred_a, pred_b) in enumerate(cells):
        t, a, b = np.asarray(targets), np.asarray(pred_a), np.asarray(pred_b)
        if t.size == 0 or t.shape != a.shape or t.shape != b.shape:
            raise ValueError(f"cell {i}: {t.size} targets, {a.size} predictions of a and {b.size} of b")
        if groups is None:
            unit = np.arange(t.size)
        else:
            g = np.asarray(groups[i])
            if g.shape != t.shape:
                raise ValueError(f"cell {i}: {g.size} groups for {t.size} samples")
            unit = np.unique(g, return_inverse=True)[1].reshape(-1)
        gain = (b == t).astype(np.int64) - (a == t).astype(np.int64)
        per_cell.append((np.bincount(unit, weights=gain), np.bincount(unit).astype(np.float64)))
        # integer gain over the sample count, so that e.g. 30 of 100 reads 0.3, not 1.0 - 0.7
        observed.append(int(gain.sum()) / t.size)
    difference = float(np.mean(observed))

    rng = np.random.default_rng(seed)
    diffs = np.empty(resamples)
    for r in range(resamples):
        picked = rng.integers(0, len(per_cell), len(per_cell))  # cells (seeds) with replacement
        total = 0.0
        for c in picked:
            gain, counts = per_cell[c]
            units = rng.integers(0, counts.size, counts.size)  # one draw of units, scored for a and b alike
            total += gain[units].sum() / counts[units].sum()
        diffs[r] = total / len(picked)

    tail = (1.0 - level) / 2
    low, high = np.quantile(diffs, [tail, 1.0 - tail])
    p_value = (1 + int(np.count_nonzero(diffs - difference >= difference))) / (resamples + 1)
    return PairedResult(difference, float(low), float(high), p_value, len(per_cell), resamples)


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
