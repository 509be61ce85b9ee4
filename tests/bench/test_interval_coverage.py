"""The intervals cover by simulation: experiments with a known expected accuracy (tools.interval_coverage)."""

from __future__ import annotations

import numpy as np

from tools.interval_coverage import SETTINGS, Setting, coverage, false_positive_rate, per_seed_draw, simulate

EXPERIMENTS = 500  # binomial standard error of a coverage near 0.95: 0.010
RESAMPLES = 300  # per interval; the test part's variance to about 8 %, plenty next to the binomial error


def test_the_simulated_truth_is_the_expected_accuracy_over_seeds_and_test_sets() -> None:
    # the closed form against brute force: many seeds, each scored on the whole population
    setting = Setting(seeds=400, n_test=2000, m=0.9, sigma_unit=1.0, sigma_seed=0.4)
    truth, correct, _ = simulate(setting, 3, np.random.default_rng(0))
    assert np.abs(correct.mean(axis=(1, 2)) - truth).max() < 0.01


def test_the_95_percent_interval_covers_the_truth_93_to_97_percent_of_the_time() -> None:
    for i, name in enumerate(("Ev-Containers-like, 3 seeds", "Ev-Objects-like, 5 seeds")):
        res = coverage(SETTINGS[name], EXPERIMENTS, seed=10 + i, resamples=RESAMPLES, methods=("shared",))
        assert 0.93 <= res["shared_coverage"] <= 0.97, (name, res)


def test_the_per_seed_draw_of_b84155b_fails_the_coverage_test() -> None:
    res = coverage(SETTINGS["Ev-Containers-like, 3 seeds"], EXPERIMENTS, seed=10, resamples=RESAMPLES,
                   methods=("per_seed",))
    assert res["per_seed_coverage"] < 0.93, res


def test_the_per_seed_draw_is_the_earlier_code() -> None:
    # one seed, every unit right but one of four: the per-seed draw is the plain bootstrap of 3/4
    low, high = per_seed_draw(np.array([[1, 1, 1, 0]], dtype=bool), np.random.default_rng(0), resamples=4000)
    assert (low, high) == (0.25, 1.0)


def test_the_paired_test_rejects_a_true_difference_of_zero_about_alpha_of_the_time() -> None:
    rate = false_positive_rate(SETTINGS["Ev-Containers-like, 3 seeds"], 600, seed=3, resamples=RESAMPLES)
    assert 0.02 <= rate <= 0.075, rate  # alpha = 0.05; binomial standard error 0.009
