"""Everything a run directory shows, rebuilt from its cell files: leaderboard.csv, summary.csv, report.md, plots.

``tactile-zoo report DIR`` calls :func:`write_outputs`; so does every bench run when it ends. Which cells belong to
the run comes from ``run.json``'s grid when it is there (cells of other configurations left in the same folder are
listed as ignored), otherwise every cell file counts. ``tactile-zoo report DIR --all-cells`` takes every cell file in
the folder, for a table built by several bench commands into one folder (each command's ``run.json`` names only its
own grid); report.md then warns about any model and dataset whose cells come from more than one configuration.
report.md also warns about cells computed by an older revision of their model's or dataset's code (registry metadata
``revision``, recorded in each cell's config) than the one registered now: their numbers are stale.
Plots (matplotlib, Agg backend, PNG):

* ``plots/heatmap.png``: mean test accuracy, model x dataset;
* ``plots/bars_<dataset>.png``: mean accuracy per model with the sample standard deviation over cells as error bars
  and the chance level;
* ``plots/confusion/<dataset>__<model>.png``: the confusion matrix of the model's best cell on that dataset (highest
  validation accuracy, then lowest fold and seed: never chosen by test accuracy), class names on the axes, rows
  normalised;
* ``plots/curves_<dataset>.png``: training loss, validation loss (both on a log scale when positive) and validation
  accuracy per epoch of each model's best cell;
* ``plots/early_<dataset>.png``: accuracy versus the fraction of the sequence seen (early classification), one line
  per model (mean over cells; dashed = non-causal model given the prefix as its whole input).
"""

from __future__ import annotations

import errno
import json
import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .._files import atomic_write_text
from ..engine.metrics import registered_metrics
from ..errors import ResultsError
from ..recipe import recipe_name_of
from .plots import write_plots
from .records import CellScan, InvalidCell, InvalidCellsError, refuse_newer, revision_gaps
from .rundir import RunDir
from .tables import (
    UNAVAILABLE,
    leaderboard_rows,
    metric_columns,
    prefix_label,
    reference_rows,
    rows_to_csv,
    summary_rows,
)

__all__ = ["write_outputs", "load_run"]


def load_run(path: str | os.PathLike, all_cells: bool = False, scan: CellScan | None = None
             ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, Any], int]:
    """``(records of the run's cells, skipped rows, run.json, number of ignored cell files)``; with ``all_cells``
    every cell file of the folder, whatever grid ``run.json`` names. Damaged cell files are left out (``scan``,
    when given, is the folder's already read :class:`~.records.CellScan`)."""
    run = RunDir(path)
    records = (scan or run.scan()).records
    info: dict[str, Any] = {}
    try:
        info = json.loads((run.path / "run.json").read_text())
    except (OSError, ValueError):
        pass
    if not isinstance(info, dict):  # a damaged run.json: the cells alone still make the tables
        info = {}
    grid = info.get("grid") or {}
    wanted = None if all_cells else grid.get("cells")
    if wanted is not None:
        selected = [records[c] for c in wanted if c in records]
        ignored = len(records) - len(selected)
    else:
        selected, ignored = sorted(records.values(), key=lambda r: r["cell_id"]), 0
    skipped = [] if all_cells else list(grid.get("skipped") or [])  # skips belong to one command's grid
    return selected, skipped, info, ignored


def write_outputs(path: str | os.PathLike, plots: bool = True, all_cells: bool = False, skip_invalid: bool = False,
                  on_invalid: Callable[[InvalidCell], None] | None = None) -> dict[str, Path]:
    """Write leaderboard.csv, summary.csv, report.md (and the plots) of the run directory ``path``, holding the
    folder's table lock (another bench process on the same folder waits; it never sees half a table). With
    ``all_cells`` every cell file of the folder counts (see the module docstring).

    A ``run.json`` of a format this code does not know raises ConfigError (:meth:`~.rundir.RunDir.check_format`).
    A damaged cell file (:mod:`.records`) raises :class:`~.records.InvalidCellsError` naming every one before
    anything is written; with ``skip_invalid`` the tables are built without them, ``on_invalid`` is called with
    each, and report.md lists them. A folder where the tables cannot be written raises
    :class:`~tactile_zoo.errors.ResultsError` naming it."""
    from ..errors import ConfigError

    run = RunDir(path)
    if not run.path.is_dir():
        raise ConfigError(f"{run.path} is not a folder (expected a bench output folder with cells/)")
    if not run.cells_dir.is_dir():
        raise ConfigError(f"{run.path} has no cells/ folder: not a tactile-zoo bench output")
    run.check_format()  # a run.json of a newer format: its grid may not mean what this code reads into it
    scan = run.scan()
    refuse_newer(scan, str(run.path))  # a newer tactile-zoo's cell is not damaged: --skip-invalid does not skip it
    if scan.invalid and not skip_invalid:
        raise InvalidCellsError(scan.invalid, run.cells_dir, "nothing written. `tactile-zoo bench` with the same "
                                "arguments moves them to cells/damaged/ and recomputes them; --skip-invalid builds "
                                "the tables without them")
    for item in scan.invalid:
        if on_invalid is not None:
            on_invalid(item)
    try:
        with run.table_lock():
            for name in ("leaderboard.csv", "summary.csv", "report.md"):
                run.remove_torn(run.path, name)
            for torn in run.plots_dir.rglob(".*.tmp") if run.plots_dir.is_dir() else ():
                torn.unlink(missing_ok=True)
            return _write_outputs(run, plots, all_cells, scan)
    except OSError as exc:
        if exc.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
            raise
        # a read-only folder (a colleague's results, a mounted archive): say where, not a traceback
        raise ResultsError(f"cannot write the tables into {run.path} ({exc.strerror or exc}: "
                           f"{exc.filename or run.path}); copy the folder somewhere writable and run `tactile-zoo "
                           f"report` on the copy") from None


def _mixed_configs(records: list[dict[str, Any]]) -> list[str]:
    """``model (recipe) on dataset`` for every summary row whose cells carry more than one config hash."""
    hashes: dict[tuple[str, str, str], set[str]] = {}
    for rec in records:
        key = (rec["model"], recipe_name_of(rec.get("config") or {}), rec["dataset"])
        hashes.setdefault(key, set()).add(str(rec.get("config_hash")))
    return [f"{m} ({r}) on {d}" for (m, r, d), h in sorted(hashes.items()) if len(h) > 1]


def _outdated_cells(records: list[dict[str, Any]]) -> list[str]:
    """One line per model, dataset and reason where cells were computed by an older revision of the model's or the
    dataset's code than the one registered now (:func:`~tactile_zoo.bench.records.revision_gaps`); a name no longer
    registered has nothing to compare with and is not flagged."""
    stale: dict[tuple[str, str, str], list[str]] = {}
    for rec in records:
        gaps = revision_gaps(rec)
        if gaps:
            where = f"fold {_f(rec.get('fold'))} seed {_f(rec.get('seed'))}"
            stale.setdefault((rec["model"], rec["dataset"], "; ".join(gaps)), []).append(where)
    return [f"- {m} on {d}, {len(cells)} cell(s) ({', '.join(cells)}): {why}"
            for (m, d, why), cells in sorted(stale.items())]


def _write_outputs(run: RunDir, plots: bool, all_cells: bool = False, scan: CellScan | None = None
                   ) -> dict[str, Path]:
    scan = scan or run.scan()
    records, skipped, info, ignored = load_run(run.path, all_cells, scan)
    board, board_cols = leaderboard_rows(records, skipped)
    summary, summary_cols = summary_rows(board, board_cols)
    written = {"leaderboard": run.path / "leaderboard.csv", "summary": run.path / "summary.csv",
               "report": run.path / "report.md"}
    atomic_write_text(written["leaderboard"], rows_to_csv(board, board_cols))
    atomic_write_text(written["summary"], rows_to_csv(summary, summary_cols))
    figures: dict[str, Any] = {}
    if plots and records:
        figures = write_plots(run, records, summary)
    notes = []
    if scan.invalid:  # --skip-invalid: the tables are short of these, and whoever reads them must know
        notes.append(f"Warning: {len(scan.invalid)} damaged cell file(s) left out (`--skip-invalid`): "
                     + "; ".join(f"`{item.path.name}` ({item.reason})" for item in scan.invalid) + ".")
    if all_cells:
        notes.append("Built with `--all-cells`: every cell file of the folder, from any bench command that wrote here; "
                     "`Command` above is only the last one.")
        mixed = _mixed_configs(records)
        if mixed:
            notes.append(f"Warning: cells of more than one configuration are averaged together for {', '.join(mixed)}; "
                         "compare their `config_hash` in leaderboard.csv.")
    atomic_write_text(written["report"], _markdown(run, records, board, summary, figures, info, ignored, notes,
                                                   _outdated_cells(records)))
    manifest = _weights_manifest(run, records)
    if manifest is not None:
        written["weights_manifest"] = manifest
    return written


def _weights_manifest(run: RunDir, records: list[dict[str, Any]]) -> Path | None:
    """``weights/manifest.json`` for the cells whose weights ``--save-weights`` wrote, so ``tactile-zoo predict
    --weights OUT/weights/<cell id>.safetensors`` finds its description next to the file."""
    saved = [r for r in _ok(records) if r.get("weights") and (run.path / r["weights"]["file"]).is_file()]
    if not saved:
        return None
    from ..weights.manifest import entry_from_record, write_manifest

    path = run.path / "weights" / "manifest.json"
    write_manifest([entry_from_record(r, run.path) for r in saved], path,
                   description=f"weights saved by tactile-zoo bench --save-weights in {run.path}")
    return path


# ----------------------------------------------------------------------------------------------- markdown
def _f(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _threads(records: list[dict[str, Any]]) -> str:
    """The torch threads the cells ran with, as they recorded them: the bench process's own count (run.json) is not
    what its cells used (``--threads``, default 1, is set in each cell's process)."""
    counts = sorted({r["threads"] for r in records if isinstance(r.get("threads"), int)})
    if not counts:
        return "torch threads per cell not recorded"
    return f"{', '.join(map(str, counts))} torch thread(s) per cell"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _ok(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in records if r.get("status") == "ok"]


def _markdown(run: RunDir, records: list[dict[str, Any]], board: list[dict[str, Any]], summary: list[dict[str, Any]],
              figures: dict[str, Any], info: dict[str, Any], ignored: int, notes: list[str] | None = None,
              outdated: list[str] | None = None) -> str:
    env = info.get("environment") or {}
    versions = env.get("versions") or {}
    status_counts: dict[str, int] = {}
    for rec in records:
        status_counts[rec["status"]] = status_counts.get(rec["status"], 0) + 1
    devices = sorted({str(r.get("device")) for r in _ok(records) if r.get("device")})
    out = ["# tactile-zoo benchmark report", ""]
    out.append(f"Generated {time.strftime('%Y-%m-%d %H:%M')} from {len(records)} cell file(s) in `{run.path}` "
               f"({', '.join(f'{v} {k}' for k, v in sorted(status_counts.items())) or 'none'}).")
    if info.get("command"):
        out.append(f"Command: `{' '.join(info['command'])}`.")
    if versions:
        out.append(f"tactile-zoo {versions.get('tactile_zoo', '?')}, torch {versions.get('torch', '?')}, "
                   f"Python {env.get('python', '?')}; {env.get('cpu_model', '?')} ({env.get('cpu_cores', '?')} cores, "
                   f"{_threads(records)}); GPU: "
                   f"{(env.get('gpu') or {}).get('name', 'none')}; device(s) used: {', '.join(devices) or '–'}; "
                   f"git {env.get('git_commit') or '–'}.")
    if ignored:
        out.append(f"{ignored} cell file(s) in the folder belong to another configuration and are not included.")
    out += notes or []
    out += ["", "Accuracy, balanced accuracy and macro-F1 are on each dataset's test split, for the epoch selected on "
                "its validation split; mean ± sample standard deviation over folds and seeds. Rank is per dataset "
                "(1 = best mean accuracy); mean rank is over the datasets a model ran on. Timings (train seconds, "
                "inference ms per sample at batch 1) depend on the machine." + _other_metrics(), ""]
    if outdated:  # before the tables, so nobody quotes their numbers without seeing it
        out += ["## Warning: cells computed by older code", "",
                "These cells were computed by an older revision of their model's or dataset's code than the one "
                "registered now, so their numbers may differ from what the current code computes, and the tables "
                "below include them. Rerun them: the same `tactile-zoo bench` command with `--force`, or with a "
                "fresh `--out`.", "", *outdated, ""]
    out += ["## Summary", "",
            "The 95 % interval is a confidence interval for the expected accuracy of this training procedure on "
            "this task (over training seeds or folds, on the population the test set was drawn from): one draw of "
            "the test units (samples, or recordings where a dataset cuts recordings into windows) per resample, "
            "shared by the runs scored on that test set, plus the runs' spread with its small-sample t quantile "
            "(`tactile_zoo.bench.intervals`). In simulated experiments it covered the truth 93-96 % of the time "
            "(`tools/interval_coverage.py`). Models whose intervals overlap widely are not told apart by these "
            "cells.", ""]
    intervals = _intervals(records)
    extra = metric_columns()
    labels = {m.name: m.label for m in registered_metrics()}
    rows = [[s["model"], s["recipe"], s["dataset"], str(s["n_cells"]),
             f"{_f(s['accuracy_mean'])} ± {_f(s['accuracy_std'])}",
             _interval(intervals.get((s["model"], s["dataset"]))),
             _f(s["balanced_accuracy_mean"]), _f(s["macro_f1_mean"]), *[_f(s[f"{m}_mean"]) for m in extra],
             _f(s["train_seconds_mean"], 1), _f(s["rank"]), _f(s["mean_rank"], 2)]
            for s in sorted(summary, key=lambda s: (s["dataset"], s["rank"] or 1e9, s["model"]))]
    out.append(_table(["model", "recipe", "dataset", "cells", "accuracy", "95 % interval", "balanced acc.",
                       "macro-F1", *[labels[m] for m in extra], "train s", "rank", "mean rank"], rows)
               if rows else "No finished cell yet.")
    out.append("")
    out += _unavailable_legend(board)
    out += _reference_section(records)
    out += _tuning_section(records)
    if "heatmap" in figures:
        out += ["## Accuracy by model and dataset", "", f"![heat map]({figures['heatmap']})", ""]
    datasets = sorted({r["dataset"] for r in _ok(records)})
    for dataset in datasets:
        out += [f"## {dataset}", ""]
        for key, title in (("bars", "Accuracy per model"), ("curves", "Training curves (best cell per model)"),
                           ("early", "Early classification: accuracy versus the part of the sequence seen")):
            if dataset in figures.get(key, {}):
                out += [f"### {title}", "", f"![{key} {dataset}]({figures[key][dataset]})", ""]
        early = _early_table(_ok(records), dataset)
        if early:
            out += [early, ""]
        confusions = figures.get("confusion", {}).get(dataset, {})
        if confusions:
            out += ["### Confusion matrices (best cell per model)", ""]
            out += [f"![confusion {model}]({p})" for model, p in sorted(confusions.items())]
            out.append("")
    skipped = [r for r in board if r.get("status") == "skipped"]
    if skipped:
        out += ["## Skipped", ""]
        seen = set()
        for row in skipped:
            who = row["dataset"] if row.get("fold") is None else f"{row['model']} x {row['dataset']}"
            if (who, row.get("error")) in seen:
                continue
            seen.add((who, row.get("error")))
            out.append(f"- {who}: {row.get('error')}")
        out.append("")
    failed = [r for r in board if r.get("status") == "failed"]
    if failed:
        out += ["## Failed", ""]
        out += [f"- {r['model']} x {r['dataset']} fold {_f(r.get('fold'))} seed {_f(r.get('seed'))}: "
                f"`{r.get('error')}`" for r in failed]
        out.append("")
    out += ["Per-cell numbers: `leaderboard.csv`; per model and dataset: `summary.csv`; everything else (predictions, "
            "probabilities, curves, configs) is in `cells/*.json`.", ""]
    return "\n".join(out)


def _other_metrics() -> str:
    """The sentence that introduces the registered metrics beyond the three fixed ones (none: nothing)."""
    extra = [m for m in registered_metrics() if m.name in metric_columns()]
    if not extra:
        return ""
    return (" Also on the test split, computed from what each cell file stores of it: "
            + ", ".join(f"{m.label} (`{m.name}`, from the {m.needs})" for m in extra) + ".")


def _unavailable_legend(board: list[dict[str, Any]]) -> list[str]:
    """The legend of :data:`~.tables.UNAVAILABLE`: per metric, the cells that store no input it needs."""
    why = {"probabilities": "a test split too large to keep them, or a record older than stored probabilities",
           "predictions": "a record older than stored predictions"}
    lines = []
    for metric in registered_metrics():
        cells = [row for row in board if row.get(metric.name) == UNAVAILABLE]
        if cells:
            where = ", ".join(sorted({f"{row['model']} on {row['dataset']}" for row in cells}))
            lines.append(f"- `{UNAVAILABLE}` ({metric.label}): {len(cells)} cell file(s) store no test "
                         f"{metric.needs}, which `{metric.name}` needs ({why[metric.needs]}): {where}. A mean over "
                         f"such a cell is `{UNAVAILABLE}` too.")
    return lines + [""] if lines else []


def _intervals(records: list[dict[str, Any]]) -> dict[tuple[str, str], tuple[float, float] | None]:
    """(model, dataset) -> the 95 % interval of the mean test accuracy of its ok honest cells (selected on validation,
    or ``final``: nothing selected, the test split read once)."""
    from .intervals import records_interval

    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rec in _ok(records):
        if (rec.get("config") or {}).get("evaluation", "validation") in ("validation", "final") \
                and rec.get("predictions"):
            groups.setdefault((rec["model"], rec["dataset"]), []).append(rec)
    return {key: records_interval(recs) for key, recs in groups.items()}


def _interval(low_high: tuple[float, float] | None) -> str:
    return "-" if low_high is None else f"[{_f(low_high[0])}, {_f(low_high[1])}]"


def _early_table(records: list[dict[str, Any]], dataset: str) -> str:
    per_model: dict[str, list[dict[str, Any]]] = {}
    for rec in records:
        if rec["dataset"] == dataset and rec.get("prefix"):
            per_model.setdefault(rec["model"], []).append(rec["prefix"])
    if not per_model:
        return ""
    fractions = sorted({f for ps in per_model.values() for p in ps for f in p["fractions"]})
    rows = []
    for model, prefixes in sorted(per_model.items()):
        accs = []
        for frac in fractions:
            vals = [p["accuracy"][p["fractions"].index(frac)] for p in prefixes if frac in p["fractions"]]
            accs.append(_f(sum(vals) / len(vals)) if vals else "–")
        earl = [p["earliness"] for p in prefixes if p.get("earliness") is not None]
        causal = "yes" if prefixes[0].get("causal") else f"no ({prefixes[0].get('input', 'truncated')})"
        rows.append([model, causal, *accs, _f(sum(earl) / len(earl), 2) if earl else "–"])
    return _table(["model", "causal", *[f"{prefix_label(f)} %" for f in fractions], "earliness"], rows)


def _settings(config: dict[str, Any]) -> str:
    """What a tuning trial set: its hyper-parameters and dataset arguments, and the recipe's name."""
    parts = [f"{k}={v}" for k, v in sorted((config.get("hparams") or {}).items())]
    parts += [f"{k}={v}" for k, v in sorted((config.get("dataset_kwargs") or {}).items())]
    return f"{recipe_name_of(config)}" + (f": {', '.join(parts)}" if parts else "")


def _tuning_section(records: list[dict[str, Any]]) -> list[str]:
    trials: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for rec in _ok(records):
        if (rec.get("config") or {}).get("evaluation") == "tuning":
            trials.setdefault((rec["model"], rec["dataset"], rec["config_hash"]), []).append(rec)
    if not trials:
        return []
    rows = []
    for (model, dataset, digest), recs in sorted(trials.items()):
        val = [r["metrics"]["val"]["accuracy"] for r in recs]
        std = f" ± {_f(statistics.stdev(val))}" if len(val) > 1 else ""
        rows.append([model, dataset, f"`{digest}`", _settings(recs[0]["config"]), str(len(recs)),
                     f"{_f(statistics.fmean(val))}{std}", ",".join(str(r["best_epoch"]) for r in recs)])
    return ["## Tuning trials (--evaluation tuning)", "",
            "Validation accuracy of the selected epoch, mean over the trial's cells (folds, seeds). The test split "
            "was never read: in tuning mode loading it raises. Each cell's full configuration is in its file.", "",
            _table(["model", "dataset", "config", "settings", "cells", "val accuracy", "best epochs"], rows), ""]


# ----------------------------------------------------------------------------------------------- plots
def _reference_section(records: list[dict[str, Any]]) -> list[str]:
    rows = reference_rows(records)
    if not rows:
        return []
    table = [[r["model"], r["dataset"], ",".join(map(str, r["seeds"])),
              f"{_f(r['final_mean'])} ± {_f(r['final_std'])}",
              _interval(r["final_interval"]),
              f"{_f(r['best_test_epoch_mean'])} ± {_f(r['best_test_epoch_std'])}",
              ",".join(map(str, r["best_test_epochs"]))] for r in rows]
    return ["## Reference protocol (--evaluation reference)", "",
            "Trained on every training recording for the recipe's fixed epochs; the test split was evaluated after "
            "every epoch. **Final epoch** selects nothing: an honest figure (its 95 % interval as in the summary: "
            "seeds and test samples). **Best test epoch** is chosen on the test set itself, the optimistic protocol "
            "under which some sources publish: comparable with those sources only, never with the summary above.", "",
            _table(["model", "dataset", "seeds", "final epoch (honest)", "95 % interval",
                    "best test epoch (optimistic)", "best epochs"], table), ""]
