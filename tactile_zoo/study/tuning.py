"""Validation reads: what a tuning study decides by, read from its cells' validation scores (a test split is never
read; a tuning cell cannot load one).

A read takes one model's ``ok`` cells of a grid on a dataset (its runs: every fold, the declared seeds or the grid's)
and one score per run:

- ``best``: the validation accuracy of the epoch the cell selected (``metrics.val.accuracy``);
- ``final``: the validation accuracy at the recipe's last epoch, ``max_epochs`` (the cell's curve): what a recipe
  that reads its last epoch gets;
- ``epoch``: the epoch the cell selected (``best_epoch``), e.g. for a rule that declares an epoch count.

Its value: ``mean`` and ``median`` over the runs; with ``against`` (another arm: a grid, a model, seeds) also that
arm's, their ``difference`` (mean minus the other arm's mean) and ``improved``, how many runs, paired by fold and
seed, score above their partner (of ``pairs``).
"""

from __future__ import annotations

import statistics
from typing import Any

from .checks import plans
from .schema import Arm, Study, ValidationRead

__all__ = ["cell_score", "arm_runs", "validation_value"]


def cell_score(record: dict[str, Any], score: str) -> float | str:
    """The ``score`` of one cell record, or a line saying why it has none."""
    if score == "epoch":
        return float(record["best_epoch"]) if record.get("best_epoch") is not None else \
            f"{record['cell_id']}: no selected epoch recorded"
    if score == "best":
        value = ((record.get("metrics") or {}).get("val") or {}).get("accuracy")
        return float(value) if value is not None else f"{record['cell_id']}: no validation accuracy recorded"
    epochs = ((record.get("config") or {}).get("recipe") or {}).get("max_epochs")
    entry = next((e for e in record.get("curve") or [] if e.get("epoch") == epochs), None)
    if entry is None or entry.get("val_accuracy") is None:
        return f"{record['cell_id']}: no validation accuracy at epoch {epochs} (its max_epochs) in its curve"
    return float(entry["val_accuracy"])


def arm_runs(study: Study, read: ValidationRead, arm: Arm, records: dict[str, dict[str, Any]]
             ) -> tuple[dict[tuple[int, int], dict[str, Any]], list[str]]:
    """The arm's ok records keyed by (fold, seed), and a line per declared seed without any (an arm's grid and
    model default to the read's, its seeds to its grid's)."""
    grid = arm.grid or read.grid or study.grids()[0].name
    model = arm.model or read.model
    plan = plans(study)[grid]
    wanted = plan.hashes[model, read.dataset]
    seeds = arm.seeds if arm.seeds is not None else plan.config.seeds
    runs = {(r["fold"], r["seed"]): r for r in records.values()
            if r.get("status") == "ok" and r["model"] == model and r["dataset"] == read.dataset
            and r["config_hash"] == wanted and r["seed"] in seeds}
    missing = [f"grid {grid}: {model} on {read.dataset}, seed {s}" for s in seeds
               if not any(seed == s for _, seed in runs)]
    return runs, missing


def _values(runs: dict[tuple[int, int], dict[str, Any]], score: str) -> dict[tuple[int, int], float] | str:
    out = {}
    for key, record in sorted(runs.items()):
        value = cell_score(record, score)
        if isinstance(value, str):
            return value
        out[key] = value
    return out


def validation_value(study: Study, read: ValidationRead, records: dict[str, dict[str, Any]]
                     ) -> tuple[dict[str, Any] | None, list[str], list[str]]:
    """(value or None, input cell ids, what is missing) of ``read`` over ``records`` (cell id -> record)."""
    runs, missing = arm_runs(study, read, Arm(seeds=read.seeds), records)
    other, other_missing = ({}, []) if read.against is None else arm_runs(study, read, read.against, records)
    ids = [r["cell_id"] for r in [*runs.values(), *other.values()]]
    if missing or other_missing:
        return None, ids, missing + other_missing
    values = _values(runs, read.score)
    against = _values(other, read.score) if read.against is not None else {}
    for found in (values, against):
        if isinstance(found, str):
            return {"unreadable": found}, ids, []
    assert isinstance(values, dict) and isinstance(against, dict)
    value: dict[str, Any] = {"score": read.score, "mean": statistics.fmean(values.values()),
                             "median": statistics.median(values.values()), "runs": len(values),
                             "values": {f"f{f}s{s}": v for (f, s), v in values.items()}}
    if read.against is not None:
        pairs = sorted(set(values) & set(against))
        value.update({"against_mean": statistics.fmean(against.values()),
                      "against_median": statistics.median(against.values()),
                      "against_values": {f"f{f}s{s}": v for (f, s), v in against.items()},
                      "difference": statistics.fmean(values.values()) - statistics.fmean(against.values()),
                      "improved": sum(values[k] > against[k] for k in pairs), "pairs": len(pairs)})
    return value, ids, []
