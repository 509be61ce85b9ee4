"""Do the intervals cover? Simulated experiments with a known truth, for :mod:`tactile_zoo.bench.intervals` and
:mod:`tactile_zoo.bench.paired`.

    python -m tools.interval_coverage          # print the note
    python -m tools.interval_coverage --write  # write benchmarks/results/interval_coverage.md

**The estimand.** The expected accuracy of a training procedure on a task: the mean over training seeds of the
accuracy a trained model has on the population the test set is drawn from (the training data held fixed).

**The simulated experiment** (a probit model, so that the truth has a closed form). A population of ``population``
test units; unit ``i`` has a difficulty ``a_i ~ N(0, sigma_unit^2)``, shared by every seed. A seed shifts every
unit alike, ``b_s ~ N(0, sigma_seed^2)``, and each (seed, unit) pair adds its own noise ``e_si ~ N(0, 1)``. The run
of seed ``s`` classifies unit ``i`` correctly when ``m + a_i + b_s + e_si > 0``. The test set is ``n_test`` units
drawn without replacement from the population, and every seed is scored on it. The truth is the mean over the
population of ``P(correct) = Phi((m + a_i) / sqrt(1 + sigma_seed^2))`` (the seed and pair noises integrated out).

An interval *covers* when it contains that truth; over many experiments, a 95 % interval should cover about 95 % of
the time. ``tests/bench/test_interval_coverage.py`` asserts 93-97 % for the method in use, and that the per-seed
draw of the earlier code (b84155b), reproduced here as :func:`per_seed_draw`, fails that test.

**The paired test.** Two recipes with the same expected accuracy (a true difference of zero), scored on the same test
set with the same seeds: they share the units' difficulties, their seed shifts are correlated (``rho``), the pair
noises are their own. The one-sided test at level ``alpha`` should reject about ``alpha`` of the time.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from tactile_zoo.bench.intervals import bootstrap_accuracy, records_interval
from tactile_zoo.bench.paired import paired_bootstrap

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
NOTE = RESULTS / "interval_coverage.md"


@dataclass(frozen=True)
class Setting:
    """One simulated design: ``seeds`` runs scored on one test set of ``n_test`` units."""

    seeds: int
    n_test: int
    m: float  # probit location: sets the true accuracy
    sigma_unit: float  # spread of the units' difficulties, shared by all seeds
    sigma_seed: float  # spread of the seeds' shifts: training noise
    population: int = 2000


def simulate(setting: Setting, experiments: int, rng: np.random.Generator, paired_rho: float | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``experiments`` simulated experiments: the truths (E,), the correctness of recipe a (E, seeds, n_test) and,
    with ``paired_rho``, that of a recipe b with the same truth whose seed shifts correlate ``paired_rho`` with a's."""
    s = setting
    a = rng.normal(0.0, s.sigma_unit, (experiments, s.population))
    truth = stats.norm.cdf((s.m + a) / np.sqrt(1.0 + s.sigma_seed ** 2)).mean(axis=1)
    # n_test units without replacement: the first n_test of a random permutation of each population
    test = np.argsort(rng.random((experiments, s.population)), axis=1)[:, :s.n_test]
    difficulty = np.take_along_axis(a, test, axis=1)[:, None, :]  # (E, 1, n)
    shift_a = rng.normal(0.0, s.sigma_seed, (experiments, s.seeds, 1))
    correct_a = s.m + difficulty + shift_a + rng.normal(size=(experiments, s.seeds, s.n_test)) > 0
    if paired_rho is None:
        return truth, correct_a, None
    shift_b = paired_rho * shift_a + np.sqrt(1 - paired_rho ** 2) * rng.normal(0.0, s.sigma_seed, shift_a.shape)
    correct_b = s.m + difficulty + shift_b + rng.normal(size=(experiments, s.seeds, s.n_test)) > 0
    return truth, correct_a, correct_b


def per_seed_draw(correct: np.ndarray, rng: np.random.Generator, resamples: int = 1000,
                  level: float = 0.95) -> tuple[float, float]:
    """The earlier interval (b84155b), on one experiment's (seeds, n) correctness: per resample the seeds with
    replacement, then for *each drawn seed its own* draw of the test units, the percentile interval of the mean."""
    seeds, n = correct.shape
    picked = rng.integers(0, seeds, (resamples, seeds))
    units = rng.integers(0, n, (resamples, seeds, n))
    means = correct[picked[:, :, None], units].mean(axis=(1, 2))
    tail = (1 - level) / 2
    low, high = np.quantile(means, [tail, 1 - tail])
    return float(low), float(high)


def per_seed_draw_p(gain: np.ndarray, rng: np.random.Generator, resamples: int = 1000) -> float:
    """The earlier paired p-value (b84155b): per-seed draws, the shifted tail ``(1 + #{d* - d >= d}) / (R + 1)``."""
    seeds, n = gain.shape
    d = gain.mean()
    picked = rng.integers(0, seeds, (resamples, seeds))
    units = rng.integers(0, n, (resamples, seeds, n))
    diffs = gain[picked[:, :, None], units].mean(axis=(1, 2))
    return (1 + int(np.count_nonzero(diffs - d >= d))) / (resamples + 1)


def _cells(correct: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """One experiment's (seeds, n) correctness as harness cells: targets 0, prediction 0 where correct."""
    targets = np.zeros(correct.shape[1], dtype=np.int64)
    return [(targets, np.where(row, 0, 1)) for row in correct]


def coverage(setting: Setting, experiments: int, seed: int = 0, resamples: int = 500,
             methods: tuple[str, ...] = ("shared", "per_seed")) -> dict[str, float]:
    """Per method, the share of ``experiments`` whose 95 % interval holds the truth, and the mean width."""
    rng = np.random.default_rng(seed)
    truth, correct, _ = simulate(setting, experiments, rng)
    hits = {m: 0 for m in methods}
    widths = {m: 0.0 for m in methods}
    for e in range(experiments):
        for method in methods:
            if method == "shared":
                low, high = bootstrap_accuracy(_cells(correct[e]), resamples=resamples, seed=e)
            else:
                low, high = per_seed_draw(correct[e], rng, resamples)
            hits[method] += low <= truth[e] <= high
            widths[method] += (high - low) / experiments
    out = {f"{m}_coverage": hits[m] / experiments for m in methods}
    out |= {f"{m}_width": widths[m] for m in methods}
    out["truth"] = float(truth.mean())
    out["seed_sd"] = float(correct.mean(axis=2).std(axis=1, ddof=1).mean())
    return out


def false_positive_rate(setting: Setting, experiments: int, rho: float = 0.5, alpha: float = 0.05, seed: int = 0,
                        resamples: int = 500, old: bool = False) -> float:
    """The share of experiments with a true difference of zero where the one-sided paired test says "b better"."""
    rng = np.random.default_rng(seed)
    _, correct_a, correct_b = simulate(setting, experiments, rng, paired_rho=rho)
    assert correct_b is not None
    targets = np.zeros(setting.n_test, dtype=np.int64)
    rejected = 0
    for e in range(experiments):
        if old:
            p = per_seed_draw_p(correct_b[e].astype(float) - correct_a[e], rng, resamples)
        else:
            cells = [(targets, np.where(ra, 0, 1), np.where(rb, 0, 1)) for ra, rb in zip(correct_a[e], correct_b[e])]
            p = paired_bootstrap(cells, resamples=resamples, seed=e).p_value
        rejected += p < alpha
    return rejected / experiments


#: the designs of the note: like Ev-Containers (60 test recordings, accuracy about 0.74) and Ev-Objects (144, about
#: 0.87), 3 and 5 seeds, a seed spread like the committed cells' (sd 0.03-0.05), and a spread twice as large
SETTINGS = {
    "Ev-Containers-like, 3 seeds": Setting(3, 60, 0.9, 1.0, 0.15),
    "Ev-Containers-like, 5 seeds": Setting(5, 60, 0.9, 1.0, 0.15),
    "Ev-Objects-like, 3 seeds": Setting(3, 144, 1.6, 1.0, 0.15),
    "Ev-Objects-like, 5 seeds": Setting(5, 144, 1.6, 1.0, 0.15),
    "large seed spread, 3 seeds": Setting(3, 60, 0.9, 1.0, 0.4),
    "large seed spread, 5 seeds": Setting(5, 60, 0.9, 1.0, 0.4),
    "no shared difficulty, 3 seeds": Setting(3, 60, 0.9, 0.0, 0.15),
}

#: the issue's table (29): committed zoo cells, the interval then, and the shared-draw percentile interval it quoted
ISSUE_ROWS = (("ev_containers", "x_tacformer", "[0.650, 0.767]", "[0.607, 0.810]"),
              ("ev_containers", "sgnet", "[0.473, 0.587]", "[0.410, 0.650]"),
              ("ev_objects", "tacformer", "[0.815, 0.890]", "[0.794, 0.907]"))


def shared_percentile(records: list[dict], resamples: int = 2000, seed: int = 0) -> tuple[float, float]:
    """The issue's intermediate method: seeds with replacement and one shared draw of the test samples per resample,
    the percentile interval (no small-sample quantile, interaction counted twice)."""
    rng = np.random.default_rng(seed)
    correct = np.array([np.equal(r["predictions"]["test"]["targets"], r["predictions"]["test"]["predictions"])
                        for r in records], dtype=float)  # (S, n)
    seeds, n = correct.shape
    weights = rng.multinomial(n, np.full(n, 1.0 / n), size=resamples)
    per_seed = weights @ correct.T / n  # (R, S)
    picked = rng.integers(0, seeds, (resamples, seeds))
    means = np.take_along_axis(per_seed, picked, axis=1).mean(axis=1)
    low, high = np.quantile(means, [0.025, 0.975])
    return float(low), float(high)


def note(experiments: int = 1000) -> str:
    lines = ["# Do the intervals cover?", "",
             "Generated by `python -m tools.interval_coverage --write` (the model and the estimand: its "
             "docstring). Each row: "
             f"{experiments} simulated experiments; coverage of the 95 % interval (share of experiments whose "
             "interval holds the true expected accuracy) and its mean width.", "",
             "| design | seeds | test units | truth | seed sd | per-seed draw (b84155b) | now: shared draw, t per "
             "part |",
             "|---|---|---|---|---|---|---|"]
    for i, (name, setting) in enumerate(SETTINGS.items()):
        res = coverage(setting, experiments, seed=i)
        lines.append(f"| {name} (sigma_unit {setting.sigma_unit}, sigma_seed {setting.sigma_seed}) | {setting.seeds} "
                     f"| {setting.n_test} | {res['truth']:.3f} | {res['seed_sd']:.3f} | "
                     f"{res['per_seed_coverage']:.3f} (width {res['per_seed_width']:.3f}) | "
                     f"{res['shared_coverage']:.3f} (width {res['shared_width']:.3f}) |")
    fpr_rows = []
    for i, name in enumerate(("Ev-Containers-like, 3 seeds", "Ev-Containers-like, 5 seeds",
                              "Ev-Objects-like, 5 seeds")):
        setting = SETTINGS[name]
        fpr_rows.append(f"| {name} | {false_positive_rate(setting, experiments, seed=100 + i, old=True):.3f} | "
                        f"{false_positive_rate(setting, experiments, seed=100 + i):.3f} |")
    lines += ["", "Binomial standard error of a coverage near 0.95 over "
              f"{experiments} experiments: {np.sqrt(0.95 * 0.05 / experiments):.3f}. The seed sd column is the mean "
              "sample std of the seeds' accuracies on their test set, as the tables quote it.", "",
              "## The paired test under a true difference of zero", "",
              f"One-sided, alpha = 0.05, {experiments} experiments; seed shifts of the two recipes correlated 0.5.", "",
              "| design | false-positive rate, per-seed draw (b84155b) | now |", "|---|---|---|", *fpr_rows]
    lines += ["", "## The issue's table, on the committed `zoo` cells", "",
              "| dataset, model | interval at b84155b | shared draw, percentile (the issue) | now |",
              "|---|---|---|---|"]
    from tactile_zoo.study.publish import study_folder
    from tools.fidelity import STUDIES, cells

    zoo = cells(study_folder(STUDIES, "table1-zoo"), recipe="zoo")
    for dataset, model, then, issue in ISSUE_ROWS:
        recs = sorted((r for r in zoo if r["model"] == model and r["dataset"] == dataset), key=lambda r: r["seed"])
        low, high = shared_percentile(recs)
        now = records_interval(recs)
        assert now is not None
        lines.append(f"| {dataset}, {model} ({len(recs)} seeds) | {then} | [{low:.3f}, {high:.3f}] (issue: {issue}) | "
                     f"[{now[0]:.3f}, {now[1]:.3f}] |")
    lines += ["", "## Reading", "",
              "- The per-seed draw treats the one test set as if each seed had a fresh one: the test noise, which "
              "all seeds share, is averaged away, and the intervals undercover.",
              "- Drawing the test units once per resample for all seeds restores that noise. A percentile bootstrap "
              "over 3-5 seeds still undercovers when the seeds' spread matters (the seed part rests on 2-4 degrees "
              "of freedom), and counts the noise that differs between seeds twice; hence the seed part's own t "
              "quantile and the correction (`tactile_zoo/bench/intervals.py`).",
              "- Over these seven designs the interval now covers 93.4-95.7 % (the per-seed draw: 85.5-93.0 %). It "
              "rests on a normal seed spread; a seed spread far from normal (a recipe that collapses on some seeds) "
              "is not covered by any interval from 3 runs.",
              "- The paired test's false-positive rate is near alpha (0.036-0.064; the per-seed draw's shifted tail "
              "was conservative, 0.016-0.040, and lost power).", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.interval_coverage", description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help=f"write {NOTE.relative_to(RESULTS.parents[1])}")
    parser.add_argument("--experiments", type=int, default=1000)
    args = parser.parse_args(argv)
    text = note(args.experiments)
    if args.write:
        NOTE.write_text(text)
        print(f"wrote {NOTE}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
