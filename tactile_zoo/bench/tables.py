"""The tables of a run, built from its cell records: leaderboard (one row per cell), summary (per model and dataset,
with ranks) and their CSV text.

pandas does the table work: ordering the leaderboard, grouping ok cells by model and dataset, ranking the models of
each dataset and averaging each model's ranks. The per-group means and standard deviations are reduced in plain
Python, left to right, as they always were: pandas' own ``mean``/``std`` sum pairwise or with Kahan/Welford updates,
which can change the last bit, and the CSV writes every float exactly (``repr``), so a rebuilt table must reproduce
the committed one byte for byte.

Rows are plain dicts of Python values (``None`` where a value is missing), so callers and ``rows_to_csv`` never see
numpy scalars (``repr(np.float64(x))`` is not ``repr(x)``) or NaN placeholders.

The test metrics are the registered ones (:func:`tactile_zoo.engine.metrics.register_metric`), computed from the
targets, predictions and class probabilities each record stores of its test split, so a metric registered today
has a value for every finished cell. ``accuracy``, ``balanced_accuracy`` and ``macro_f1`` keep their fixed
columns; every other metric gets a column after ``error`` (``<name>_mean`` in the summary). Where a record stores
no input the metric needs (the probabilities of a test split over ``MAX_PROBABILITY_ROWS`` samples, or predictions
in an older record), the cell shows :data:`UNAVAILABLE`, and so does a summary mean over it; a metric the record
also stores as a number (the three above) falls back to that number. A row without a test split (a failed cell, a
tuning trial) has no test metrics: its cells stay empty, as before.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from ..engine.metrics import MetricError, MetricInputMissing, metric_value, registered_metrics
from ..recipe import recipe_name_of

if TYPE_CHECKING:  # pandas is imported on first use: it adds most of a second to every worker's start-up
    import pandas as pd

__all__ = ["LEADERBOARD_COLUMNS", "SUMMARY_COLUMNS", "TIMING_COLUMNS", "UNAVAILABLE", "leaderboard_rows",
           "summary_rows", "rows_to_csv", "prefix_label", "reference_rows", "metric_columns", "record_metrics"]

#: The leaderboard's fixed columns (the issue's list, in its order); extra columns follow ``error``:
#: ``accuracy_<split>`` for each extra test split, ``accuracy_at_<p>`` per prefix percentage, ``earliness``.
LEADERBOARD_COLUMNS = (
    "model", "recipe", "dataset", "protocol", "fold", "seed", "status", "accuracy", "balanced_accuracy", "macro_f1",
    "n_train", "n_val", "n_test", "epochs_run", "best_epoch", "train_seconds", "infer_ms_per_sample", "params",
    "peak_memory_mb", "device", "config_hash", "tactile_zoo_version", "torch_version", "error",
)
SUMMARY_COLUMNS = (
    "model", "recipe", "dataset", "n_cells", "accuracy_mean", "accuracy_std", "balanced_accuracy_mean", "macro_f1_mean",
    "train_seconds_mean", "rank", "mean_rank",
)
#: Columns that depend on the machine (left out when comparing two runs' numbers).
TIMING_COLUMNS = ("train_seconds", "infer_ms_per_sample", "peak_memory_mb", "train_seconds_mean")

_SORT_KEYS = ("model", "dataset", "fold", "seed", "config_hash")
#: what a metric's cell shows where the record stores no input the metric needs (report.md says which, below its
#: summary table); never left blank, which would read as "not run"
UNAVAILABLE = "n/a"
#: the registered metrics that have fixed leaderboard columns
_FIXED_METRICS = ("accuracy", "balanced_accuracy", "macro_f1")
#: names a registered metric cannot take: they are other columns of the tables
_TAKEN = (set(LEADERBOARD_COLUMNS) - set(_FIXED_METRICS)) | {"earliness", "evaluation", "val_accuracy",
                                                              "best_test_epoch_accuracy", "recipe"}


def _pd() -> Any:
    import pandas

    return pandas


def prefix_label(fraction: float) -> str:
    """0.25 -> ``"25"`` (percent, as in ``accuracy_at_25``)."""
    return f"{fraction * 100:g}"


def _num(value: Any) -> Any:
    if isinstance(value, float) and (math.isnan(value) or math.isinf(value)):
        return None
    return value


def metric_columns() -> list[str]:
    """The registered metrics without a fixed leaderboard column, in registration order: the extra metric columns.

    Raises:
        MetricError: a registered metric whose name is another column of the tables.
    """
    names = [m.name for m in registered_metrics() if m.name not in _FIXED_METRICS]
    taken = [n for n in names if n in _TAKEN]
    if taken:
        raise MetricError(f"metric {taken[0]!r} has the name of another table column; register it under another name")
    return names


def record_metrics(rec: dict[str, Any]) -> dict[str, Any]:
    """Every registered metric of the record's ``test`` split, from its stored predictions or probabilities: a number,
    ``None`` (an empty split), or :data:`UNAVAILABLE` where the record stores no input the metric needs and no value
    of it either. ``{}`` for a record without test metrics (a failed cell, a tuning trial).

    Raises:
        MetricError: a metric raised or returned no number; the message names the metric and the cell.
    """
    test = (rec.get("metrics") or {}).get("test") or {}
    if not test:
        return {}
    split = (rec.get("predictions") or {}).get("test") or {}
    where = f"cell {rec.get('cell_id', '?')} ({rec.get('model')} on {rec.get('dataset')})"
    out: dict[str, Any] = {}
    for metric in registered_metrics():
        try:
            out[metric.name] = metric_value(metric, split, where)
        except MetricInputMissing:
            # the record's own number where it stores one (the three fixed metrics), else say it is missing
            out[metric.name] = test[metric.name] if metric.name in test else UNAVAILABLE
    return out


def _cell_row(rec: dict[str, Any], extra_splits: set[str], prefixes: set[float], extra_metrics: list[str]
              ) -> dict[str, Any]:
    """A cell record flattened to one leaderboard row; adds the extra test splits and prefix fractions it has to
    ``extra_splits`` and ``prefixes`` (the table's extra columns)."""
    metrics = rec.get("metrics") or {}
    test = record_metrics(rec)
    versions = rec.get("versions") or {}
    row: dict[str, Any] = {
        "model": rec["model"], "recipe": recipe_name_of(rec.get("config") or {}), "dataset": rec["dataset"],
        "protocol": rec.get("protocol", ""),
        "fold": rec.get("fold"), "seed": rec.get("seed"), "status": rec["status"],
        "accuracy": test.get("accuracy"), "balanced_accuracy": test.get("balanced_accuracy"),
        "macro_f1": test.get("macro_f1"), "n_train": rec.get("n_train"), "n_val": rec.get("n_val"),
        "n_test": rec.get("n_test"), "epochs_run": rec.get("epochs_run"), "best_epoch": rec.get("best_epoch"),
        "train_seconds": rec.get("train_seconds"), "infer_ms_per_sample": rec.get("infer_ms_per_sample"),
        "params": rec.get("params"), "peak_memory_mb": rec.get("peak_memory_mb"), "device": rec.get("device"),
        "config_hash": rec.get("config_hash"), "tactile_zoo_version": versions.get("tactile_zoo"),
        "torch_version": versions.get("torch"), "error": rec.get("error"),
    }
    row.update({name: test.get(name) for name in extra_metrics})
    for split, split_metrics in metrics.items():
        if split not in ("test", "val") and split_metrics:
            extra_splits.add(split)
            row[f"accuracy_{split}"] = split_metrics.get("accuracy")
    prefix = rec.get("prefix") or {}
    for frac, acc in zip(prefix.get("fractions", ()), prefix.get("accuracy", ())):
        prefixes.add(float(frac))
        row[f"accuracy_at_{prefix_label(frac)}"] = acc
    if prefix:
        row["earliness"] = prefix.get("earliness")
    row["evaluation"] = (rec.get("config") or {}).get("evaluation", "validation")
    row["best_test_epoch_accuracy"] = (rec.get("reference") or {}).get("best_test_epoch_accuracy")
    row["val_accuracy"] = (metrics.get("val") or {}).get("accuracy")
    return {k: _num(v) for k, v in row.items()}


def _skipped_row(skip: dict[str, Any]) -> dict[str, Any]:
    reason = skip.get("reason", "")
    obtain = str(skip.get("obtain") or "").strip()
    if obtain and obtain not in reason:
        reason = f"{reason.rstrip('.')}. To obtain it: {obtain}"
    return {"model": skip["model"], "dataset": skip["dataset"], "status": skip.get("status", "skipped"),
            "error": reason}


def _sorted(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows by model, dataset, fold, seed, config hash (a missing fold or seed first, as -1); a stable sort, so
    rows equal on every key keep their input order."""
    pd = _pd()
    keys = pd.DataFrame({
        "model": [str(r["model"]) for r in rows], "dataset": [str(r["dataset"]) for r in rows],
        "fold": [r.get("fold") if r.get("fold") is not None else -1 for r in rows],
        "seed": [r.get("seed") if r.get("seed") is not None else -1 for r in rows],
        "config_hash": [str(r.get("config_hash") or "") for r in rows],
    }, columns=list(_SORT_KEYS), dtype=object)
    order = keys.sort_values(list(_SORT_KEYS), kind="stable").index
    return [rows[i] for i in order]


def leaderboard_rows(records: Iterable[dict[str, Any]], skipped: Iterable[dict[str, Any]] = ()
                     ) -> tuple[list[dict[str, Any]], list[str]]:
    """One row per cell (and per skipped model x dataset pair); returns ``(rows, columns)``."""
    extra_splits: set[str] = set()
    prefixes: set[float] = set()
    extra_metrics = metric_columns()
    rows = [_cell_row(rec, extra_splits, prefixes, extra_metrics) for rec in records] + \
        [_skipped_row(skip) for skip in skipped]
    columns = list(LEADERBOARD_COLUMNS) + extra_metrics + [f"accuracy_{s}" for s in sorted(extra_splits)] + \
        [f"accuracy_at_{prefix_label(p)}" for p in sorted(prefixes)] + (["earliness"] if prefixes else [])
    if any(row.get("evaluation") == "reference" for row in rows):
        # --evaluation reference: ``accuracy`` is the final epoch's (nothing selected); the best test epoch's
        # accuracy, chosen on the test set, is the sources' optimistic figure and gets a column of its own
        columns += ["evaluation", "best_test_epoch_accuracy"]
    if any(row.get("evaluation") == "tuning" for row in rows):
        # --evaluation tuning: no test figure exists (``accuracy`` is empty); the selected epoch's validation accuracy
        # is what a trial is judged by
        columns += [c for c in ("evaluation", "val_accuracy") if c not in columns]
    return (_sorted(rows) if rows else []), columns


def _mean(values: list[Any]) -> float | str | None:
    if UNAVAILABLE in values:
        return UNAVAILABLE  # a mean over the cells that have the metric would pass for a mean over all of them
    values = [v for v in values if v is not None]
    return sum(values) / len(values) if values else None


def _std(values: list[Any]) -> float | str | None:
    if UNAVAILABLE in values:
        return UNAVAILABLE
    values = [v for v in values if v is not None]
    if len(values) < 2:
        return None  # one cell has no spread to report
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


def _ranks(summary: pd.DataFrame) -> tuple[list[int | None], list[float | None]]:
    """Per summary row: its rank among the rows of its dataset (1 = best mean accuracy, ties share the best rank,
    no accuracy = no rank) and its model's (model and recipe's) mean rank over the datasets where it has one."""
    pd = _pd()
    accuracy = summary["accuracy_mean"].astype("float64")  # None -> NaN: no rank, and not counted in others'
    rank = accuracy.groupby(summary["dataset"], sort=False, dropna=False).rank(method="min", ascending=False,
                                                                             na_option="keep")
    # ranks are small integers, so any summation order gives the same exact mean
    mean_rank = rank.groupby(summary["model"], sort=False, dropna=False).transform("mean")
    return ([None if pd.isna(v) else int(v) for v in rank], [None if pd.isna(v) else float(v) for v in mean_rank])


def summary_rows(leaderboard: list[dict[str, Any]], columns: list[str]) -> tuple[list[dict[str, Any]], list[str]]:
    """Per (model, recipe, dataset) over ok cells: means, sample std of accuracy, rank per dataset (1 = best mean
    accuracy, ties share the best rank) and each model-and-recipe's mean rank over the datasets it ran on. Two
    recipes of one model are two rows, never one average."""
    pd = _pd()
    named = {m.name for m in registered_metrics()} - set(_FIXED_METRICS)
    extra = [c for c in columns if c in named] + \
        [c for c in columns if c.startswith("accuracy_") and c not in ("accuracy_mean",)] + \
        (["earliness"] if "earliness" in columns else [])
    averaged = ["accuracy", "balanced_accuracy", "macro_f1", "train_seconds", *extra]
    ok = [row for row in leaderboard if row.get("status") == "ok"]
    summary_columns = list(SUMMARY_COLUMNS) + [f"{c}_mean" for c in extra]
    if not ok:
        return [], summary_columns
    # object columns keep each value as the Python object it was (int, float, None): no NaN, no float64 upcast
    cells = pd.DataFrame({c: [row.get(c) for row in ok] for c in ("model", "recipe", "dataset", *averaged)},
                         dtype=object)
    out: list[dict[str, Any]] = []
    cells["recipe"] = [str(r) for r in cells["recipe"]]  # a record without one (None) groups as "None", not dropped
    for (model, recipe, dataset), group in cells.groupby(["model", "recipe", "dataset"], sort=True, dropna=False):
        entry: dict[str, Any] = {"model": model, "recipe": recipe, "dataset": dataset, "n_cells": len(group),
                                 "accuracy_mean": _mean(group["accuracy"].tolist()),
                                 "accuracy_std": _std(group["accuracy"].tolist()),
                                 "balanced_accuracy_mean": _mean(group["balanced_accuracy"].tolist()),
                                 "macro_f1_mean": _mean(group["macro_f1"].tolist()),
                                 "train_seconds_mean": _mean(group["train_seconds"].tolist())}
        for col in extra:
            entry[f"{col}_mean"] = _mean(group[col].tolist())
        out.append(entry)
    # a model's recipes rank as separate entries ("x_tacformer zoo" beside "x_tacformer source")
    frame = pd.DataFrame({"model": [f"{e['model']} {e['recipe']}" for e in out], "dataset": [e["dataset"] for e in out],
                          "accuracy_mean": [None if e["accuracy_mean"] == UNAVAILABLE else e["accuracy_mean"]
                                            for e in out]}, dtype=object)
    for entry, rank, mean_rank in zip(out, *_ranks(frame)):
        entry["rank"], entry["mean_rank"] = rank, mean_rank
    return out, summary_columns


def reference_rows(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (model, dataset) over ok ``--evaluation reference`` cells: the final epoch's test accuracy (honest: nothing
    was selected) with its 95 % interval (:mod:`.intervals`: seeds and shared test draws), and the best test epoch's
    accuracy (chosen on the test set: the sources' optimistic figure, without an interval)."""
    from .intervals import records_interval

    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rec in records:
        if rec.get("status") == "ok" and (rec.get("config") or {}).get("evaluation") == "reference":
            groups.setdefault((rec["model"], rec["dataset"]), []).append(rec)
    rows = []
    for (model, dataset), recs in sorted(groups.items()):
        final = [r["metrics"]["test"]["accuracy"] for r in recs]
        best = [r["reference"]["best_test_epoch_accuracy"] for r in recs]
        rows.append({"model": model, "dataset": dataset, "seeds": sorted(r["seed"] for r in recs),
                     "final_mean": _mean(final), "final_std": _std(final), "final_interval": records_interval(recs),
                     "best_test_epoch_mean": _mean(best), "best_test_epoch_std": _std(best),
                     "best_test_epochs": [r["reference"]["best_test_epoch"] for r in recs]})
    return rows


def rows_to_csv(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """CSV text (header + rows, ``\\n`` line ends); ``None`` is an empty field, floats are written exactly."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({c: ("" if row.get(c) is None else _fmt(row.get(c))) for c in columns})
    return buf.getvalue()


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return repr(value)  # shortest exact representation: tables compare equal iff the numbers do
    if isinstance(value, str):
        return value.replace("\n", " ")
    return value
