"""Intervals for accuracies: one method, shared by the report, the fidelity ledger, the recipe tables and the paired
comparison (:mod:`tactile_zoo.bench.paired`).

**What the interval is for.** A confidence interval for the *expected accuracy of this training procedure on this
task*: the mean, over training seeds (and validation folds, where they rotate), of the accuracy a trained model has
on the population the test set was drawn from. The training data are held fixed; the seeds and the test set are the
two sources of chance. ``tools/interval_coverage.py`` simulates such experiments and measures how often the 95 %
interval covers that expectation (its note: ``benchmarks/results/interval_coverage.md``).

**Why not one bootstrap over seeds and test units.** Every seed is scored on the *same* test set, so the test-sampling
noise is shared by all seeds and does not average away over them. The interval therefore has two parts:

- *test units*: one bootstrap draw of the test units per resample, shared by every run scored on that test set (the
  seeds, and BioTac-DoS's folds, which share the unseen objects); ``v_test`` is the variance, over resamples, of the
  mean accuracy of the runs, the runs held fixed. A unit is a test sample, or with ``groups`` a recording with all
  its windows (BioTac-DoS: about 27 windows per recording, far from independent);
- *seeds*: the spread of the runs' accuracies, ``v_seed = s^2 / S``. That spread also holds the part of the test noise
  that differs between seeds (a sample one seed gets right and another wrong), which ``v_test`` already counts; the
  bootstrap measures it (the mean per-run test variance minus ``v_test``, over ``S - 1``) and it is taken off once.

With 3-5 seeds, ``s^2`` rests on 2-4 degrees of freedom, and a percentile bootstrap over seeds (or a normal
quantile) is far too short: ``t`` with 2 degrees of freedom is 4.30, not 1.96. Each part gets its own small-sample
quantile, and the half-width is ``sqrt(t_{S-1}^2 v_seed + t_{U-1}^2 v_test)`` (U: test units). Under normal
parts it is right when either part dominates and errs wide in between; the simulation measures the result (93-96 %
over its designs). A seed spread far from normal (a recipe that collapses on some seeds) is beyond any 3-run interval.

Where every run has a test set of its own (k-fold protocols), the runs are independent and their spread holds all
the noise: the interval is the ``t`` interval over runs. Runs on several shared test sets (folds x seeds) draw each
test set's units independently and, without the correction, count the seed-dependent test noise twice (wide).
A single run has only its test part: the interval says nothing about another seed.

How to read an interval: "0.880 [0.851, 0.907] (3 seeds)" is a 95 % confidence interval for the expected accuracy of
the training procedure on the task; two models whose intervals overlap widely are not shown apart by these runs, and
a paper figure above the interval is one these runs do not reproduce.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

__all__ = ["Components", "variance_components", "units_of", "bootstrap_accuracy", "records_interval",
           "DEFAULT_RESAMPLES"]

DEFAULT_RESAMPLES = 2000
#: the last results of :func:`variance_components`, by their inputs: a page of tables asks for one interval in
#: several places (a row of the headline is a row of Table I too), and the bootstrap is most of a table's time; the
#: function is deterministic in its inputs and its seed, so a repeat is the same result
_MEMO: OrderedDict[tuple, Components] = OrderedDict()
_MEMO_SIZE = 256
_MEMO_LOCK = threading.Lock()


@dataclass(frozen=True)
class Components:
    """A mean over runs and the two parts of its variance.

    Attributes:
        estimate: mean over the runs of each run's statistic (accuracy, or a paired difference) on its full test set.
        v_seed: variance of ``estimate`` from the runs (seeds, folds), net of the test noise ``v_test`` counts.
        v_test: variance of ``estimate`` from drawing the test units, the draw shared by the runs of one test set.
        n_runs: runs (S).
        n_units: independent test units, summed over the distinct test sets (U).
        n_test_sets: distinct test sets among the runs.
    """

    estimate: float
    v_seed: float
    v_test: float
    n_runs: int
    n_units: int
    n_test_sets: int

    def half_width(self, quantile: float) -> float:
        """``sqrt(t_{S-1}(q)^2 v_seed + t_{U-1}(q)^2 v_test)``: each part with its own degrees of freedom."""
        seed_part = stats.t.ppf(quantile, self.n_runs - 1) ** 2 * self.v_seed if self.n_runs > 1 else 0.0
        df_test = max(self.n_units - self.n_test_sets, 1)
        return float(np.sqrt(seed_part + stats.t.ppf(quantile, df_test) ** 2 * self.v_test))

    def interval(self, level: float, bounds: tuple[float, float]) -> tuple[float, float]:
        """The two-sided ``level`` interval, clipped to ``bounds`` (an accuracy cannot leave [0, 1])."""
        half = self.half_width(1.0 - (1.0 - level) / 2)
        return max(bounds[0], self.estimate - half), min(bounds[1], self.estimate + half)


def variance_components(runs: Sequence[tuple[np.ndarray, np.ndarray, bytes]], *, resamples: int = DEFAULT_RESAMPLES,
                        seed: int = 0) -> Components:
    """The mean over ``runs`` of their per-run statistic and its two variance parts.

    Args:
        runs: per run, ``(numerator per unit, samples per unit, test-set key)``; the run's statistic is
            ``numerator.sum() / samples.sum()`` (an accuracy: correct samples per unit). Runs with equal keys were
            scored on one test set, unit for unit, and share each bootstrap draw.
        resamples: bootstrap resamples of the test units.
        seed: seeds the resampling, so a table regenerates to the same digits.
    """
    memo = (resamples, seed, tuple((num.dtype.str, num.tobytes(), counts.dtype.str, counts.tobytes(), key)
                                   for num, counts, key in runs))
    with _MEMO_LOCK:
        if memo in _MEMO:
            _MEMO.move_to_end(memo)
            return _MEMO[memo]
    result = _variance_components(runs, resamples, seed)
    with _MEMO_LOCK:
        _MEMO[memo] = result
        if len(_MEMO) > _MEMO_SIZE:
            _MEMO.popitem(last=False)
    return result


def _variance_components(runs: Sequence[tuple[np.ndarray, np.ndarray, bytes]], resamples: int, seed: int
                         ) -> Components:
    rng = np.random.default_rng(seed)
    by_set: dict[bytes, list[int]] = {}
    for i, (_, _, key) in enumerate(runs):
        by_set.setdefault(key, []).append(i)
    n_runs = len(runs)
    values = np.array([num.sum() / counts.sum() for num, counts, _ in runs])
    estimate = float(values.mean())
    n_units = sum(runs[members[0]][1].size for members in by_set.values())
    if n_runs > 1 and len(by_set) == n_runs:  # independent runs: their spread holds all the noise
        return Components(estimate, float(values.var(ddof=1) / n_runs), 0.0, n_runs, n_units, len(by_set))
    boot = np.empty((resamples, n_runs))  # per resample, each run's statistic on the drawn units
    for members in by_set.values():
        counts = runs[members[0]][1]
        weights = rng.multinomial(counts.size, np.full(counts.size, 1.0 / counts.size), size=resamples)
        numerators = np.stack([runs[i][0] for i in members], axis=1)  # (units, runs of this test set)
        boot[:, members] = (weights @ numerators) / (weights @ counts)[:, None]
    v_test = float(boot.mean(axis=1).var(ddof=1)) if resamples > 1 else 0.0
    if n_runs == 1:
        return Components(estimate, 0.0, v_test, 1, n_units, 1)
    v_seed = float(values.var(ddof=1) / n_runs)
    if len(by_set) == 1:
        # The spread of the seeds holds the test noise that differs between seeds: (mean per-run test variance -
        # v_test) * S / (S - 1) estimates it per run, a mean over S runs carries 1/S of it, and v_test counts it.
        per_run = float(boot.var(axis=0, ddof=1).mean()) if resamples > 1 else 0.0
        v_seed = max(0.0, v_seed - (per_run - v_test) / (n_runs - 1))
    return Components(estimate, v_seed, v_test, n_runs, n_units, len(by_set))


def units_of(targets: Sequence[int], group: Sequence | None) -> tuple[np.ndarray, bytes]:
    """Each sample's unit index (0..U-1) and the key that identifies the test set (its targets and units)."""
    t = np.asarray(targets)
    unit = np.arange(t.size) if group is None else np.unique(np.asarray(group), return_inverse=True)[1].reshape(-1)
    key = t.astype(np.int64).tobytes() + b"|" + unit.astype(np.int64).tobytes()
    return unit, key


def bootstrap_accuracy(cells: Sequence[tuple[Sequence[int], Sequence[int]]], *,
                       groups: Sequence[Sequence] | None = None, resamples: int = DEFAULT_RESAMPLES,
                       level: float = 0.95, seed: int = 0) -> tuple[float, float] | None:
    """The ``level`` confidence interval of the expected accuracy, from ``cells``, each ``(targets, predictions)``
    of one run (seed or fold).

    Args:
        cells: per cell (run), the test targets and the predictions (equal lengths). Cells with equal targets (and
            groups) are taken as scored on one test set and share each draw of its units.
        groups: per cell, the independent unit of each sample (e.g. its recording); default: each sample its own.
        resamples: bootstrap resamples of the test units.
        level: coverage, e.g. 0.95.
        seed: seeds the resampling, so a report regenerates to the same digits.

    Returns:
        ``(low, high)``, or ``None`` when there is nothing to resample.
    """
    if not cells:
        return None
    if groups is not None and len(groups) != len(cells):
        raise ValueError(f"groups lists {len(groups)} cells, cells are {len(cells)}")
    runs = []
    for i, (targets, predictions) in enumerate(cells):
        t, p = np.asarray(targets), np.asarray(predictions)
        if t.shape != p.shape or t.size == 0:
            raise ValueError(f"cell {i}: {t.size} targets and {p.size} predictions")
        if groups is not None and np.asarray(groups[i]).shape != t.shape:
            raise ValueError(f"cell {i}: {np.asarray(groups[i]).size} groups for {t.size} samples")
        unit, key = units_of(t, None if groups is None else groups[i])
        runs.append((np.bincount(unit, weights=(t == p).astype(np.float64)), np.bincount(unit).astype(np.float64),
                     key))
    return variance_components(runs, resamples=resamples, seed=seed).interval(level, (0.0, 1.0))


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
