"""Paired bootstrap of an accuracy difference (tactile_zoo.bench.paired) and Holm's adjustment."""

from __future__ import annotations

import random

import numpy as np
import pytest
from scipy import stats

from tactile_zoo.bench.intervals import bootstrap_accuracy
from tactile_zoo.bench.paired import PairedResult, holm, paired_bootstrap, records_paired

R = 500  # resamples: plenty for these margins, and the module runs in about two seconds


def _correlated_cells(n_cells: int = 3, n: int = 200, shared_wrong: int = 60, fixed: int = 8, broken: int = 2,
                      seed: int = 0) -> list[tuple[list[int], list[int], list[int]]]:
    """Seeds scored on one test set where a and b share most errors; b fixes ``fixed`` of a's errors and breaks
    ``broken`` of a's hits."""
    rng = np.random.default_rng(seed)
    cells = []
    targets = rng.integers(0, 5, n)
    for _ in range(n_cells):
        order = rng.permutation(n)
        a_wrong = order[:shared_wrong + fixed]
        b_wrong = np.concatenate([order[fixed:shared_wrong + fixed], order[shared_wrong + fixed:][:broken]])
        a, b = targets.copy(), targets.copy()
        a[a_wrong] = (a[a_wrong] + 1) % 5
        b[b_wrong] = (b[b_wrong] + 1) % 5
        cells.append((targets.tolist(), a.tolist(), b.tolist()))
    return cells


def test_identical_predictions_give_no_difference_and_p_one() -> None:
    cells = _correlated_cells()
    same = [(t, a, a) for t, a, _ in cells]
    res = paired_bootstrap(same, resamples=R)
    assert res == PairedResult(0.0, 0.0, 0.0, 1.0, 3, R)


def test_b_right_everywhere_against_a_wrong_on_30_percent() -> None:
    cells = []
    targets = [i % 4 for i in range(100)]
    for k in range(3):
        a = [(t + 1) % 4 if (i + k) % 10 < 3 else t for i, t in enumerate(targets)]  # wrong on 30 of 100
        cells.append((targets, a, list(targets)))
    res = paired_bootstrap(cells, resamples=R)
    assert res.difference == 0.3
    # the seeds agree on the difference (no seed part), and 0.3 lies about 6.5 standard errors (sqrt(0.21 / 100))
    # above 0: the p-value is that of t with 99 degrees of freedom, far below any level
    assert res.p_value < 1e-6
    assert 0.2 < res.low < 0.3 < res.high < 0.4
    assert res.n_cells == 3 and res.resamples == R


def test_pairing_shows_a_small_consistent_gain_that_separate_intervals_miss() -> None:
    cells = _correlated_cells()  # a: 0.66, b: 0.69 on every cell; b's gain is +6 samples of 200, always
    res = paired_bootstrap(cells, resamples=R)
    assert res.difference == pytest.approx(0.03)
    assert res.p_value < 0.05
    assert 0 < res.low < res.difference < res.high
    a_low, a_high = bootstrap_accuracy([(t, a) for t, a, _ in cells], resamples=R)
    b_low, b_high = bootstrap_accuracy([(t, b) for t, _, b in cells], resamples=R)
    assert b_low < a_high and a_low < b_high  # the separate intervals overlap: unpaired, no visible difference
    # the interval of the difference is far narrower than either separate interval: the shared errors cancel
    assert res.high - res.low < 0.75 * min(a_high - a_low, b_high - b_low)


def test_the_seed_part_takes_t_with_s_minus_1_degrees_of_freedom() -> None:
    # Four seeds scored on one test sample: b fixes a's error on seed 0 only, so d = 1/4 and the test part is 0 (the
    # one unit is drawn every time). The seed part is var(1, 0, 0, 0) / 4 = 1/16, the standard error 1/4, and with 3
    # degrees of freedom the interval is 1/4 +- t_3(0.975) / 4, the p-value P(T_3 >= 1).
    cells = [([0], [1], [0])] + [([0], [0], [0])] * 3
    res = paired_bootstrap(cells, resamples=R, seed=2)
    assert res.difference == 0.25
    assert res.p_value == pytest.approx(stats.t.sf(1.0, 3), abs=1e-9)
    assert res.low == pytest.approx(0.25 - stats.t.ppf(0.975, 3) / 4)
    assert res.high == 1.0  # 0.25 + 0.80 is clipped: a difference of accuracies cannot exceed 1


def test_groups_widen_the_interval_when_a_recordings_windows_move_together() -> None:
    rng = np.random.default_rng(1)
    cells, groups = [], []
    for _ in range(3):
        # 20 recordings of 10 windows; per recording, a and b are right or wrong on all its windows at once. Every
        # cell has the same difference (a right on 12 recordings, b on 15), so the cells add no spread of their own
        targets = np.zeros(200, dtype=int)
        a_right = np.repeat(rng.permutation(20) < 12, 10)
        b_right = np.repeat(rng.permutation(20) < 15, 10)
        cells.append((targets.tolist(), np.where(a_right, 0, 1).tolist(), np.where(b_right, 0, 1).tolist()))
        groups.append(np.repeat(np.arange(20), 10).tolist())
    narrow = paired_bootstrap(cells, resamples=R)
    wide = paired_bootstrap(cells, groups=groups, resamples=R)
    assert wide.difference == narrow.difference
    assert wide.high - wide.low > 2 * (narrow.high - narrow.low)  # 20 independent units per cell, not 200


def test_invalid_cells_name_their_index() -> None:
    good = ([0, 1, 2], [0, 1, 1], [0, 1, 2])
    with pytest.raises(ValueError, match="cell 1"):
        paired_bootstrap([good, ([0, 1], [0, 1], [0])], resamples=R)
    with pytest.raises(ValueError, match="cell 2"):
        paired_bootstrap([good, good, ([], [], [])], resamples=R)
    with pytest.raises(ValueError, match="cell 0"):
        paired_bootstrap([good], groups=[[0, 0]], resamples=R)
    with pytest.raises(ValueError, match="no paired cells"):
        paired_bootstrap([], resamples=R)


def test_holm_matches_a_hand_worked_example() -> None:
    # sorted: a 0.01 (x3 = 0.03), c 0.03 (x2 = 0.06), b 0.04 (x1 = 0.04, raised to 0.06 by c)
    adjusted = holm({"a": 0.01, "b": 0.04, "c": 0.03})
    assert list(adjusted) == ["a", "b", "c"]
    assert adjusted == pytest.approx({"a": 0.03, "b": 0.06, "c": 0.06})
    assert holm({}) == {}
    assert holm({"only": 0.2}) == {"only": 0.2}


def test_holm_is_monotone_in_the_raw_order_and_capped_at_one() -> None:
    assert holm({"x": 0.5, "y": 0.6, "z": 0.02}) == pytest.approx({"z": 0.06, "x": 1.0, "y": 1.0})
    rng = random.Random(3)
    raw = {f"h{i}": rng.random() ** 3 for i in range(12)}
    adjusted = holm(raw)
    ranked = sorted(raw, key=raw.get)
    assert all(adjusted[k] >= raw[k] for k in raw)
    assert all(adjusted[x] <= adjusted[y] for x, y in zip(ranked, ranked[1:]))
    assert max(adjusted.values()) == 1.0


def _record(cell_id: str, fold: int, seed: int, targets: list[int], predictions: list[int],
            groups: list[int] | None = None) -> dict:
    test = {"targets": targets, "predictions": predictions}
    if groups is not None:
        test["groups"] = groups
    return {"cell_id": cell_id, "model": cell_id.split("__")[0], "dataset": "ds", "fold": fold, "seed": seed,
            "predictions": {"test": test}}


def test_records_paired_pairs_by_fold_and_seed_and_ignores_unpaired_cells() -> None:
    cells = _correlated_cells(n_cells=3)
    records_a = [_record(f"a__f{f}s{s}", f, s, t, a) for (f, s), (t, a, _) in zip([(0, 0), (0, 1), (1, 0)], cells)]
    records_b = [_record(f"b__f{f}s{s}", f, s, t, b) for (f, s), (t, _, b) in zip([(0, 0), (0, 1), (1, 0)], cells)]
    # an extra cell in b only (its test set differs, so pairing it would raise), and b listed in another order
    records_b.append(_record("b__f2s0", 2, 0, [0, 1], [0, 1]))
    expected = paired_bootstrap(cells, resamples=R, seed=4)
    assert records_paired(records_a, records_b[::-1], resamples=R, seed=4) == expected
    assert records_paired(records_a[::-1], records_b, resamples=R, seed=4) == expected
    # only (0, 1) in common: a's (0, 0) and (1, 0) are left out
    only = records_paired(records_a, [r for r in records_b if (r["fold"], r["seed"]) in {(0, 1), (2, 0)}],
                          resamples=R, seed=4)
    assert only == paired_bootstrap(cells[1:2], resamples=R, seed=4)


def test_records_paired_uses_the_groups_of_record_a() -> None:
    cells = _correlated_cells(n_cells=2)
    groups = [[i // 10 for i in range(200)]] * 2
    records_a = [_record(f"a{k}", 0, k, t, a, g) for k, ((t, a, _), g) in enumerate(zip(cells, groups))]
    records_b = [_record(f"b{k}", 0, k, t, b) for k, (t, _, b) in enumerate(cells)]
    res = records_paired(records_a, records_b, resamples=R)
    assert res == paired_bootstrap(cells, groups=groups, resamples=R)
    assert res != paired_bootstrap(cells, resamples=R)


def test_records_paired_refuses_mismatched_targets_and_no_overlap() -> None:
    records_a = [_record("mlp__f0__s0", 0, 0, [0, 1, 2], [0, 1, 1])]
    records_b = [_record("tcn__f0__s0", 0, 0, [0, 1, 1], [0, 1, 1])]
    with pytest.raises(ValueError, match=r"mlp__f0__s0 and tcn__f0__s0"):
        records_paired(records_a, records_b, resamples=R)
    with pytest.raises(ValueError, match=r"no \(fold, seed\) in common"):
        records_paired(records_a, [_record("tcn__f0__s1", 0, 1, [0, 1, 2], [0, 1, 2])], resamples=R)
    with pytest.raises(ValueError, match="no stored predictions for split 'test_textures'"):
        records_paired(records_a, records_a, "test_textures", resamples=R)


def test_the_result_is_deterministic_for_a_seed() -> None:
    cells = _correlated_cells()
    first = paired_bootstrap(cells, resamples=R, seed=7)
    assert paired_bootstrap(cells, resamples=R, seed=7) == first
    other = paired_bootstrap(cells, resamples=R, seed=8)
    assert other.difference == first.difference  # the observation does not depend on the resampling
    assert (other.low, other.high, other.p_value) != (first.low, first.high, first.p_value)
