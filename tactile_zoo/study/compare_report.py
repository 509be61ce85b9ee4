"""The report of ``tactile-zoo study compare``: ``report.md`` and ``means.csv``, ``paired.csv``, ``curves.csv``.

Per dataset, beside the published cells of the same protocol, split and dataset revision, on the (fold, seed) keys
the user's cells ran (a baseline's published cells at other seeds are left out, so both sides average alike):

- *means*: each model's mean test accuracy over its cells and the 95 % interval of the expected accuracy (the
  shared-draw method, :func:`~tactile_zoo.bench.intervals.records_interval`);
- *paired differences*: each of the user's models minus each baseline, over the cells paired by (fold, seed) and
  scored on the same test samples: the mean difference, its interval and the one-sided p-value of "yours is not
  better" (:func:`~tactile_zoo.bench.paired.records_paired`, one bootstrap draw of the test recordings shared by both
  sides), with Holm's adjustment over the baselines; a baseline scored on the same recordings cut into other samples
  is listed as not paired, with why;
- *early classification*: the mean accuracy on each prefix of the test sequences (``accuracy_at_<p>``) and the
  earliness;
- *tuning*: what each side had: the baselines' trials as the set records them, the user's from their tuning study,
  and "not tuned" where none was given.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from .._files import atomic_write_text
from ..bench.intervals import records_interval
from ..bench.paired import holm, records_paired
from ..bench.tables import prefix_label
from ..errors import ConfigError, ResultsError, TactileZooError
from .audit import study_records
from .compare import Comparison, check_finished, load_comparison, plan_comparison, seed_list
from .report import csv_text
from .run import run_study

__all__ = ["write_comparison", "user_tuning", "comparison_tables", "run_comparison"]


def _f(value: Any, digits: int = 4) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def user_tuning(comparison: Comparison) -> dict[tuple[str, str], str]:
    """Per (model, dataset) of the user's, the tuning their tuning study records, in words."""
    path = comparison.against.tuning
    out: dict[tuple[str, str], str] = {}
    if path is None:
        return {(p.model, p.dataset): "not tuned: no tuning study was given (against.tuning)"
                for p in comparison.pairings}
    file = Path(path).expanduser()
    file = file if file.is_absolute() else comparison.study.path.parent / file
    if not file.is_file():
        raise ConfigError(f"{comparison.study.where}: against.tuning: {path!r} is not a file")
    try:
        tuning, _ = load_comparison(file)
    except TactileZooError as exc:
        raise ConfigError(f"{comparison.study.where}: against.tuning: {exc}") from None
    records = [r for recs in study_records(tuning)[0].values() for r in recs if r.get("status") == "ok"]
    for pairing in comparison.pairings:
        cells = [r for r in records if r["model"] == pairing.model and r["dataset"] == pairing.dataset]
        if not cells:
            out[pairing.model, pairing.dataset] = (f"not tuned on this dataset: the tuning study {tuning.name} "
                                                   f"({file.name}) has no finished cell of it")
            continue
        hashes = {r["config_hash"] for r in cells}
        tested = [r for r in cells if (r.get("config") or {}).get("evaluation") != "tuning"]
        text = f"{len(hashes)} configuration(s) in {len(cells)} cell(s) of the tuning study {tuning.name}"
        if tested:
            text += (f"; {len(tested)} of them read a test split (evaluation "
                     f"{', '.join(sorted({str(r['config'].get('evaluation')) for r in tested}))}): not tuning alone")
        out[pairing.model, pairing.dataset] = text
    return out


def _published_tuning(comparison: Comparison, model: str, dataset: str) -> str:
    found = comparison.set.tuning(model, dataset)
    if not found:
        return "no tuning trial recorded in the set"
    folders = ", ".join(f"{name} ({f['configurations']}/{f['cells']})" for name, f in found["folders"].items())
    return f"{found['configurations']} configuration(s) in {found['cells']} cell(s): {folders}"


def _curve(records: list[dict[str, Any]]) -> dict[str, Any]:
    rows: dict[str, list[float]] = {}
    earliness = []
    for rec in records:
        prefix = rec.get("prefix") or {}
        for frac, acc in zip(prefix.get("fractions") or [], prefix.get("accuracy") or [], strict=True):
            rows.setdefault(f"accuracy_at_{prefix_label(frac)}", []).append(acc)
        if prefix.get("earliness") is not None:
            earliness.append(prefix["earliness"])
    out: dict[str, Any] = {k: statistics.fmean(v) for k, v in rows.items() if len(v) == len(records)}
    out["earliness"] = statistics.fmean(earliness) if len(earliness) == len(records) else None
    return out


def comparison_tables(comparison: Comparison, mine: dict[tuple[str, str, str], list[dict[str, Any]]]
                      ) -> dict[str, list[dict[str, Any]]]:
    """The rows of ``means.csv``, ``paired.csv`` and ``curves.csv``."""
    level = comparison.against.level
    tuned = user_tuning(comparison)
    means: list[dict[str, Any]] = []
    paired: list[dict[str, Any]] = []
    curves: list[dict[str, Any]] = []
    shown: set[tuple[str, str, tuple[Any, ...]]] = set()

    def add(dataset: str, model: str, side: str, records: list[dict[str, Any]], tuning: str) -> None:
        keys = tuple(sorted((r["fold"], r["seed"]) for r in records))
        if (dataset, model, keys) in shown:
            return
        shown.add((dataset, model, keys))
        low_high = records_interval(records, "test", level=level)
        means.append({"dataset": dataset, "model": model, "side": side, "runs": len(records),
                      "seeds": seed_list({r["seed"] for r in records}),
                      "folds": seed_list({r["fold"] for r in records}),
                      "accuracy": statistics.fmean(r["metrics"]["test"]["accuracy"] for r in records),
                      "low": low_high and low_high[0], "high": low_high and low_high[1], "tuning": tuning})
        curves.append({"dataset": dataset, "model": model, "side": side, **_curve(records)})

    for pairing in comparison.pairings:
        own = mine[pairing.grid, pairing.model, pairing.dataset]
        add(pairing.dataset, pairing.model, "yours", own, tuned[pairing.model, pairing.dataset])
        family: dict[str, float] = {}
        rows = []
        for baseline, cells in pairing.baselines.items():
            theirs = [comparison.set.record(c) for c in cells]
            add(pairing.dataset, baseline, f"published {comparison.recipe}", theirs,
                _published_tuning(comparison, baseline, pairing.dataset))
            row: dict[str, Any] = {"dataset": pairing.dataset, "model": pairing.model, "baseline": baseline,
                                   "pairs": len(own), "paired": pairing.paired[baseline]}
            if pairing.paired[baseline]:
                result = records_paired(theirs, own, "test", level=level)
                row.update(difference=result.difference, low=result.low, high=result.high,
                           p_value=result.p_value, why="")
                family[baseline] = result.p_value
            else:
                n_theirs = len(theirs[0]["predictions"]["test"]["targets"])
                n_mine = len(own[0]["predictions"]["test"]["targets"])
                row.update(difference=None, low=None, high=None, p_value=None,
                           why=f"not paired: the same test recordings cut into {n_theirs} samples (theirs) and "
                               f"{n_mine} (yours); compare the means")
            rows.append(row)
        adjusted = holm(family) if family else {}
        for row in rows:
            row["p_holm"] = adjusted.get(row["baseline"])
            paired.append(row)
    return {"means": means, "paired": paired, "curves": curves}


def _markdown(comparison: Comparison, tables: dict[str, list[dict[str, Any]]]) -> str:
    pset, study = comparison.set, comparison.study
    level = f"{comparison.against.level * 100:g} %"
    lines = [f"# {study.name}: compared with the published set {pset.set_id}", "",
             f"Question: {study.spec.question}", "",
             f"Published set: **{pset.set_id}** (sha256 {pset.sha256[:16]}, {len(pset.cells)} cells; {pset.where}), "
             f"recipe `{comparison.recipe}`. No baseline was retrained: their figures are the set's cells on the "
             f"(fold, seed) keys your cells ran.", ""]
    if pset.data.get("about"):
        lines += [pset.data["about"], ""]
    for dataset in dict.fromkeys(p.dataset for p in comparison.pairings):
        pairing = next(p for p in comparison.pairings if p.dataset == dataset)
        some = next(iter(pairing.baselines.values()))[0]
        sets = "; ".join(f"fold {f}: {t.describe()}" for f, t in sorted(pairing.test_sets.items()))
        lines += [f"## {dataset}", "",
                  f"Protocol `{some['protocol']}`, evaluation `{some['evaluation']}`, dataset revision "
                  f"{some['dataset_revision']}; your test split: {sets}.", "",
                  f"### Mean test accuracy ({level} interval)", "",
                  "| model | side | runs | seeds | accuracy | interval | tuning |", "|---|---|---|---|---|---|---|"]
        for row in (r for r in tables["means"] if r["dataset"] == dataset):
            lines.append(f"| {row['model']} | {row['side']} | {row['runs']} | {row['seeds']} | {_f(row['accuracy'])} "
                         f"| [{_f(row['low'])}, {_f(row['high'])}] | {row['tuning']} |")
        lines += ["", f"### Paired differences per test recording (yours minus baseline, {level} interval)", "",
                  "| yours | baseline | pairs | difference | interval | p (yours not better) | Holm p |",
                  "|---|---|---|---|---|---|---|"]
        for row in (r for r in tables["paired"] if r["dataset"] == dataset):
            if row["paired"]:
                lines.append(f"| {row['model']} | {row['baseline']} | {row['pairs']} | {_f(row['difference'], 4)} "
                             f"| [{_f(row['low'])}, {_f(row['high'])}] | {_f(row['p_value'], 4)} "
                             f"| {_f(row['p_holm'], 4)} |")
            else:
                lines.append(f"| {row['model']} | {row['baseline']} | - | {row['why']} | - | - | - |")
        rows = [r for r in tables["curves"] if r["dataset"] == dataset]
        columns = sorted({k for r in rows for k in r if k.startswith("accuracy_at_")},
                         key=lambda k: float(k[len("accuracy_at_"):]))
        lines += ["", "### Early classification (mean accuracy on the first part of each test sequence)", "",
                  "| model | side | " + " | ".join(f"{k[len('accuracy_at_'):]} %" for k in columns)
                  + " | earliness |", "|---|---|" + "---|" * (len(columns) + 1)]
        for row in rows:
            lines.append(f"| {row['model']} | {row['side']} | " + " | ".join(_f(row.get(k)) for k in columns)
                         + f" | {_f(row.get('earliness'), 3)} |")
        lines.append("")
    lines += ["## Tuning", "",
              "Yours: " + ("; ".join(sorted({f"{m} on {d}: {t}" for (m, d), t in user_tuning(comparison).items()}))),
              "", "Published baselines: the tuning column above, as the set records it (configurations/cells per "
              "tuning folder). " + (pset.data.get("tuning_note") or ""), ""]
    return "\n".join(lines)


def write_comparison(comparison: Comparison, mine: dict[tuple[str, str, str], list[dict[str, Any]]],
                     out: str | Path | None = None) -> dict[str, Path]:
    """Write ``report.md``, ``means.csv``, ``paired.csv`` and ``curves.csv`` into ``out`` (default
    ``RESULTS/compare``); returns their paths."""
    folder = Path(out) if out is not None else comparison.study.results / "compare"
    folder.mkdir(parents=True, exist_ok=True)
    tables = comparison_tables(comparison, mine)
    paths = {"report": folder / "report.md", **{name: folder / f"{name}.csv" for name in tables}}
    atomic_write_text(paths["report"], _markdown(comparison, tables))
    for name, rows in tables.items():
        atomic_write_text(paths[name], csv_text(rows))
    return paths


def run_comparison(path: str | Path, *, out: str | Path | None = None, quiet: bool = False) -> dict[str, Path]:
    """``study compare``: check the file and refuse what cannot be compared (:func:`~.compare.plan_comparison`),
    train the grids (:func:`~.run.run_study`: frozen, resumable), check the finished cells and write the report."""
    study, against = load_comparison(path)
    if against is None:
        raise ConfigError(f"{study.where}: against is required by study compare: name the published set to compare "
                          f"with, e.g. `against: {{set: published, recipe: full}}`")
    comparison = plan_comparison(study, against)
    user_tuning(comparison)  # a tuning study that cannot be read fails before any cell trains
    run_study(study, quiet=quiet)
    records, damaged = study_records(study)
    if damaged:
        raise ResultsError("; ".join(damaged))
    return write_comparison(comparison, check_finished(comparison, records), out)
