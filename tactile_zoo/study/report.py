"""``study report``: the study's results as markdown (``report.md``) and CSV (``summary.csv``, ``reads.csv``).

What it holds: the question and whether the study was pre-registered (and when it was frozen); per grid and per
model and dataset, the leaderboard's metrics (accuracy with its 95 % interval by the shared-draw method of
:mod:`tactile_zoo.bench.intervals`, balanced accuracy, macro-F1, the early-classification accuracies and
earliness); the external figures beside our intervals; the declared reads (computed once and recorded,
:mod:`.reads`) and each threshold's outcome with the decision it leads to; each rule's outcome (:mod:`.audit`); and
the cost.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

from .._files import atomic_write_text
from ..bench.intervals import records_interval
from ..bench.tables import leaderboard_rows, summary_rows
from .audit import AuditResult, audit, cpu_hours, cpu_types, study_records
from .freeze import read_freeze
from .publish import study_blocks
from .reads import compute_reads
from .schema import Study

__all__ = ["write_report", "summary_table"]


def _f(value: Any, digits: int = 4) -> str:
    return "-" if value is None or isinstance(value, str) else f"{value:.{digits}f}"


def summary_table(records_by_grid: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Per grid, model, recipe and dataset: the bench's summary row (means of the leaderboard's metrics) with the
    95 % interval of the mean accuracy."""
    out = []
    for grid, records in records_by_grid.items():
        board, columns = leaderboard_rows([r for r in records if r.get("status") == "ok"])
        rows, _ = summary_rows(board, columns)
        for row in rows:
            cells = [r for r in records if r.get("status") == "ok" and r["model"] == row["model"]
                     and r["dataset"] == row["dataset"] and (r.get("metrics") or {}).get("test")]
            low_high = None
            if cells and all((r.get("predictions") or {}).get("test") for r in cells):
                low_high = records_interval(cells, "test")
            val = [r["metrics"]["val"]["accuracy"] for r in records if r.get("status") == "ok"
                   and r["model"] == row["model"] and r["dataset"] == row["dataset"]
                   and ((r.get("metrics") or {}).get("val") or {}).get("accuracy") is not None]
            out.append({"grid": grid, **row, "accuracy_low": low_high and low_high[0],
                        "accuracy_high": low_high and low_high[1],
                        "val_accuracy_mean": sum(val) / len(val) if val else None})
    return out


def csv_text(rows: list[dict[str, Any]]) -> str:
    """``rows`` as CSV text, the columns in order of first appearance (the report's and ``compare``'s CSVs)."""
    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    return stream.getvalue()


def _results(summary: list[dict[str, Any]]) -> list[str]:
    if not summary:
        return ["No cell has finished yet.", ""]
    early = sorted({k for row in summary for k in row if k.startswith("accuracy_at_") and k.endswith("_mean")},
                   key=lambda k: float(k[len("accuracy_at_"):-len("_mean")]))
    head = ["grid", "model", "recipe", "dataset", "runs", "accuracy [95 % interval]", "balanced acc.", "macro-F1",
            *(f"acc. at {k[len('accuracy_at_'):-len('_mean')]} %" for k in early), "earliness", "best val."]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in summary:
        interval = "" if row["accuracy_low"] is None else f" [{row['accuracy_low']:.3f}, {row['accuracy_high']:.3f}]"
        cells = [row["grid"], row["model"], str(row["recipe"]), row["dataset"], str(row["n_cells"]),
                 _f(row["accuracy_mean"]) + interval, _f(row["balanced_accuracy_mean"]), _f(row["macro_f1_mean"]),
                 *(_f(row.get(k)) for k in early), _f(row.get("earliness_mean")), _f(row.get("val_accuracy_mean"))]
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def _external(study: Study, summary: list[dict[str, Any]]) -> list[str]:
    lines = []
    for external in study.spec.compares_with:
        lines += [f"**{external.name}** ({external.source})", "", "| model | dataset | theirs | ours [95 %] | theirs "
                  "against our interval |", "|---|---|---|---|---|"]
        for figure in external.figures:
            row = next((r for r in summary if r["model"] == figure.model and r["dataset"] == figure.dataset), None)
            if row is None or row["accuracy_low"] is None:
                ours, where = "not run" if row is None else _f(row["accuracy_mean"]), "-"
            else:
                ours = f"{row['accuracy_mean']:.4f} [{row['accuracy_low']:.3f}, {row['accuracy_high']:.3f}]"
                where = "above" if figure.value > row["accuracy_high"] else \
                    "below" if figure.value < row["accuracy_low"] else "inside"
            lines.append(f"| {figure.model} | {figure.dataset} | {figure.value:.4f} | {ours} | {where} |")
        lines.append("")
    return lines


def _read_rows(reads: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for name, entry in reads.items():
        value = entry.get("value") or {}
        outcome = entry.get("outcome") or {}
        rows.append({"name": name, "kind": entry["kind"],
                     "statistic": outcome.get("statistic") or next((k for k in ("accuracy", "difference", "mean")
                                                                     if k in value), ""),
                     "value": outcome.get("value", value.get("accuracy", value.get("difference", value.get("mean")))),
                     "low": value.get("low"), "high": value.get("high"), "p_value": value.get("p_value"),
                     "bound": outcome.get("bound"), "met": outcome.get("met"), "decision": outcome.get("decision"),
                     "recorded": entry.get("time"),
                     "waiting_for": len(entry.get("missing") or []) or None,
                     "note": value.get("unreadable"), **_validation_columns(entry)})
    return rows


def _validation_columns(entry: dict[str, Any]) -> dict[str, Any]:
    """A validation read's own columns (its score, both arms' means, the runs that improved); a decision's
    thresholds."""
    value = entry.get("value") or {}
    if entry["kind"] == "decision":
        return {"all_of": " ".join(entry.get("all_of") or [])}
    if entry["kind"] != "validation" or "mean" not in value:
        return {}
    return {"score": value["score"], "mean": value["mean"], "against_mean": value.get("against_mean"),
            "improved": value.get("improved"), "pairs": value.get("pairs"), "runs": value.get("runs")}


def _validation_text(row: dict[str, Any]) -> str:
    text = f"{row['score']} {row['mean']:.4f} over {row['runs']} run(s)"
    if row.get("against_mean") is not None:
        text += (f" against {row['against_mean']:.4f}: difference {row['value']:+.4f}, {row['improved']} of "
                 f"{row['pairs']} paired run(s) above")
    return text


def _reads(rows: list[dict[str, Any]]) -> list[str]:
    if not rows:
        return ["No read was declared.", ""]
    lines = ["| read | kind | value [95 % interval] | outcome | recorded |", "|---|---|---|---|---|"]
    for row in rows:
        if row["waiting_for"]:
            value, outcome = f"waiting for {row['waiting_for']} cell(s)", "-"
        elif row["kind"] == "decision":
            value = f"all of: {row['all_of']}"
            outcome = "not decided yet" if row["met"] is None else \
                f"{'met' if row['met'] else 'missed'}: {row['decision']}"
        elif row["kind"] == "validation" and row.get("score") and not row["note"]:
            value, outcome = _validation_text(row), "-"
        elif row["kind"] == "threshold":
            digits = ".0f" if row["statistic"] in ("improved", "epoch") else ".4f"
            value = "-" if row["value"] is None else \
                f"{row['statistic']} {row['value']:{digits}} (bound {row['bound']})"
            outcome = "not decided yet" if row["met"] is None else \
                f"{'met' if row['met'] else 'missed'}: {row['decision']}"
        else:
            value = row["note"] or (f"{row['statistic']} {_f(row['value'])}" + (
                f" [{row['low']:.3f}, {row['high']:.3f}]" if row["low"] is not None else "")
                + (f", p = {row['p_value']:.3g}" if row["p_value"] is not None else ""))
            outcome = "-"
        lines.append(f"| {row['name']} | {row['kind']} | {value} | {outcome} | {row['recorded'] or '-'} |")
    return [*lines, ""]


def _rules(result: AuditResult) -> list[str]:
    lines = [f"- {rule}: {'held' if held else 'BROKEN'}" for rule, held in result.rules.items()]
    lines += [f"  - {failure}" for failure in result.failures]
    return [*lines, ""]


def write_report(study: Study, out: str | Path | None = None) -> dict[str, Path]:
    """Write ``report.md``, ``summary.csv`` and ``reads.csv`` into ``out`` (default ``RESULTS/study``), recording
    every declared read whose cells are in; returns the paths written."""
    folder = Path(out) if out is not None else study.results / "study"
    folder.mkdir(parents=True, exist_ok=True)
    read = study_records(study)  # once: the reads, the audit and the summary all take these records
    records_by_grid = read[0]
    records = {r["cell_id"]: r for recs in records_by_grid.values() for r in recs}
    folders = {g.name: study.folder(g) for g in study.grids()}
    reads = compute_reads(study, records, folders, by_grid=records_by_grid)
    result = audit(study, records=read)
    summary = summary_table(records_by_grid)
    state = read_freeze(study)
    rules = study.rules()
    everything = list(records.values())
    frozen = study.spec.freeze.time if study.spec.freeze else (state or {}).get("time")
    lines = [f"# Study `{study.name}`", "", f"**Question.** {study.spec.question}", "",
             ("Pre-registered: frozen " + (frozen or "never (not run yet)")) if study.spec.pre_registered else
             "**Not pre-registered**: its cells ran before any plan; read its figures as exploratory.", ""]
    if study.spec.notes.strip():
        lines += [study.spec.notes.strip(), ""]
    superseded = [g for g in study.grids() if g.superseded]
    lines += [f"Superseded: grid {g.name} ({study.folder(g)}): {g.superseded}" for g in superseded]
    lines += [f"Reused: grid {g.name} ({study.folder(g)}): {g.reused}" for g in study.grids() if g.reused]
    lines += ["## Results", "", *_results(summary), *_external(study, summary)]
    read_rows = _read_rows(reads)
    lines += ["## Declared reads", "", *_reads(read_rows), "## Rules", "", *_rules(result)]
    if study.spec.publishes:
        lines += ["## Published", ""] + [f"- {p.where}" + (f", block `{p.block}`" if p.block else "")
                                         + (f": {', '.join(p.reads)}" if p.reads else "")
                                         for p in study.spec.publishes] + [""]
        for page, block, text in study_blocks(study):  # the generated tables it feeds (:mod:`.publish`)
            lines += [f"### {page}, block `{block}`", "", text, ""]
    reused = {g.name for g in study.grids() if g.reused}
    own = [r for name, recs in records_by_grid.items() if name not in reused for r in recs]
    hours = cpu_hours(own)
    lines += ["## Cost", "", f"{hours:.3f} CPU-hours over {len(own)} cell(s) (the cells' own `seconds`, one "
              f"torch thread each)" + (f", of a budget of {rules.budget_cpu_hours:g}" if rules.budget_cpu_hours
                                       else "") + (f" ({len(everything) - len(own)} reused cell(s) not counted)"
                                                   if len(own) < len(everything) else "")
              + f"; CPU: {'; '.join(cpu_types(everything)) or 'none yet'}.", ""]
    paths = {"report": folder / "report.md", "summary": folder / "summary.csv", "reads": folder / "reads.csv"}
    atomic_write_text(paths["report"], "\n".join(lines))
    atomic_write_text(paths["summary"], csv_text(summary))
    atomic_write_text(paths["reads"], csv_text(read_rows))
    return paths
