"""The interval's two parts (tactile_zoo.bench.intervals): the test units drawn once for the runs of one test set,
the runs' spread with its own t quantile."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from tactile_zoo.bench.intervals import bootstrap_accuracy, variance_components

R = 2000


def _runs(correct: np.ndarray, keys: list[bytes]) -> list[tuple[np.ndarray, np.ndarray, bytes]]:
    return [(row.astype(float), np.ones(row.size), key) for row, key in zip(correct, keys)]


def test_runs_on_one_test_set_share_the_draw_and_keep_its_noise() -> None:
    # Three identical runs on 50 samples, 35 right: the seeds add nothing, and the interval is that of one run on
    # 50 samples (sqrt(0.7 * 0.3 / 50) = 0.065 of standard error), not sqrt(3) narrower as with a draw per seed
    correct = np.tile(np.arange(50) < 35, (3, 1))
    parts = variance_components(_runs(correct, [b"t"] * 3), resamples=R)
    assert parts.v_seed == pytest.approx(0.0, abs=1e-12) and parts.n_test_sets == 1 and parts.n_units == 50
    assert np.sqrt(parts.v_test) == pytest.approx(np.sqrt(0.7 * 0.3 / 50), rel=0.1)
    one = bootstrap_accuracy([([0] * 50, np.where(correct[0], 0, 1).tolist())], resamples=R)
    three = bootstrap_accuracy([([0] * 50, np.where(row, 0, 1).tolist()) for row in correct], resamples=R)
    assert one is not None and three is not None
    assert three[1] - three[0] == pytest.approx(one[1] - one[0], rel=0.01)


def test_the_seed_noise_on_shared_units_is_counted_once() -> None:
    # Seeds that err on different samples of one test set, no sample hard for all: the spread of the seeds holds that
    # noise, the shared draw holds it too; after the correction the variance is near the truth (one seed's binomial
    # variance over S * n), not twice it. 40 seeds, so that their spread is itself measured to about 25 %
    rng = np.random.default_rng(0)
    s, n = 40, 400
    correct = rng.random((s, n)) < 0.8
    parts = variance_components(_runs(correct, [b"t"] * s), resamples=R)
    truth = 0.8 * 0.2 / (s * n)
    assert parts.v_seed + parts.v_test == pytest.approx(truth, rel=0.35)
    assert correct.mean(axis=1).var(ddof=1) / s + parts.v_test > 1.6 * truth  # uncorrected: about twice


def test_runs_on_test_sets_of_their_own_take_t_over_the_runs() -> None:
    # k-fold: every run its own test set, the runs independent; the interval is mean +- t_{S-1} s / sqrt(S)
    rng = np.random.default_rng(1)
    cells = [(rng.integers(0, 3, 30).tolist(), rng.integers(0, 3, 30).tolist()) for _ in range(4)]
    accs = np.array([np.mean(np.equal(t, p)) for t, p in cells])
    half = stats.t.ppf(0.975, 3) * accs.std(ddof=1) / 2
    low, high = bootstrap_accuracy(cells, resamples=R)
    assert (low, high) == pytest.approx((max(0.0, accs.mean() - half), accs.mean() + half))


def test_biotac_folds_share_the_recordings_of_the_unseen_objects() -> None:
    # Two folds scored on one set of 10 recordings of 6 windows: the unit is the recording, drawn once for both
    groups = [g for g in range(10) for _ in range(6)]
    right = np.repeat(np.arange(10) < 7, 6)
    cells = [([0] * 60, np.where(right, 0, 1).tolist())] * 2
    by_window = bootstrap_accuracy(cells, resamples=R)
    by_recording = bootstrap_accuracy(cells, groups=[groups, groups], resamples=R)
    assert by_window is not None and by_recording is not None
    assert by_recording[1] - by_recording[0] > 2 * (by_window[1] - by_window[0])  # 10 units, not 60
    with pytest.raises(ValueError, match="cell 1: 5 groups for 60 samples"):
        bootstrap_accuracy(cells, groups=[groups, groups[:5]], resamples=R)


def test_a_repeated_interval_is_remembered_and_any_other_input_is_computed(monkeypatch: pytest.MonkeyPatch) -> None:
    """A page asks for one interval in several places: a repeat (the same runs, resamples and seed) is answered from
    the memo with the same components; another seed, resample count or run is drawn afresh; the memo is bounded."""
    from tactile_zoo.bench import intervals

    monkeypatch.setattr(intervals, "_MEMO", type(intervals._MEMO)())
    monkeypatch.setattr(intervals, "_MEMO_SIZE", 3)
    drawn = []
    real = intervals._variance_components
    monkeypatch.setattr(intervals, "_variance_components", lambda *a: drawn.append(a[1:]) or real(*a))
    correct = np.array([1.0, 0.0, 1.0, 1.0])
    runs = [(correct, np.ones(4), b"set"), (correct[::-1].copy(), np.ones(4), b"set")]
    first = variance_components(runs, resamples=50, seed=0)
    assert variance_components(runs, resamples=50, seed=0) == first and drawn == [(50, 0)]
    assert variance_components([(r[0].copy(), r[1].copy(), r[2]) for r in runs], resamples=50, seed=0) == first
    assert drawn == [(50, 0)]  # equal contents, other arrays: still a repeat
    variance_components(runs, resamples=50, seed=1)
    variance_components(runs, resamples=60, seed=0)
    other = variance_components(runs[:1], resamples=50, seed=0)
    assert drawn == [(50, 0), (50, 1), (60, 0), (50, 0)] and other != first
    assert len(intervals._MEMO) == 3
    variance_components(runs, resamples=50, seed=0)  # pushed out by the three after it: drawn again, equal
    assert drawn[-1] == (50, 0) and len(drawn) == 5 and variance_components(runs, resamples=50, seed=0) == first
