"""The declared reads: computed once, when every input cell is in, and recorded; a recorded read is never computed
again (a later change in how it would be computed cannot move it).

- a *mean*: one model's seeds on a dataset, the mean accuracy on the split and its 95 % interval (the shared-draw
  method of :mod:`tactile_zoo.bench.intervals`);
- an *ensemble*: its declared member cells combined (:func:`seed_ensemble`: the mean of their stored probabilities,
  or a majority vote of their predictions), one run: its accuracy and an interval over the test units;
- a *comparison*: ``b`` against ``a`` over their paired cells (:func:`~tactile_zoo.bench.paired.records_paired`):
  the mean difference, its interval and the one-sided p-value of "b is not better"; a side given as arms may span
  grids (a previous revision's seeds in two folders), and its inputs are then recorded as ``grid/cell id``;
- a *validation* read (:mod:`.tuning`): a tuning study's validation score of one model's runs, against another arm;
- a *threshold*: a statistic of one of those against its declared bound, and the decision its outcome leads to
  (``at_least`` and ``below`` compare with a tolerance of 1e-9, so that a mean difference of exactly two
  validation recordings is not lost to rounding);
- a *decision*: several thresholds that must all be met.

``RESULTS/study/reads.json`` holds each recorded read: its value, its input cells (id and the sha256 of the file
it was computed from) and when. The audit checks that those inputs are the declared ones and unchanged.
"""

from __future__ import annotations

import hashlib
import json
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..bench import records
from ..bench.intervals import bootstrap_accuracy, records_interval
from ..bench.paired import records_paired
from ..bench.rundir import STUDY_RECORDS, RunDir, atomic_write_json
from ..errors import ResultsError
from .checks import comparison_arms, plans, read_members
from .schema import READ_KINDS, AllOf, ComparisonRead, EnsembleRead, MeanRead, Study, Threshold, ValidationRead
from .tuning import validation_value

__all__ = ["seed_ensemble", "reads_path", "recorded_reads", "compute_reads", "threshold_outcome", "cell_digest",
           "decision_outcome", "comparison_inputs", "input_path", "TOLERANCE"]

#: grid name -> its cell records (:func:`~.audit.study_records`)
ByGrid = dict[str, list[dict[str, Any]]]

#: how close to a threshold's bound a statistic counts as on it (means of fractions carry rounding)
TOLERANCE = 1e-9


def seed_ensemble(records: list[dict[str, Any]], split: str = "test", combine: str = "mean_probabilities"
                  ) -> tuple[float, float, float] | None:
    """The ensemble of ``records`` on ``split``: per test sample the class of highest mean stored probability
    (``mean_probabilities``) or the most frequent prediction (``majority_vote``, ties to the lowest class), its
    accuracy and a 95 % interval over the test units (recordings where the records list them). ``None`` when a
    record stores no probabilities (or predictions) for ``split``; members scored on different test sets raise
    :class:`ResultsError`."""
    stored = [(r.get("predictions") or {}).get(split) or {} for r in records]
    need = "probabilities" if combine == "mean_probabilities" else "predictions"
    if not records or any(need not in pred for pred in stored):
        return None
    targets = np.asarray(stored[0]["targets"])
    for rec, pred in zip(records[1:], stored[1:], strict=True):
        if not np.array_equal(np.asarray(pred["targets"]), targets):
            raise ResultsError(f"{rec['cell_id']}: another {split} set than {records[0]['cell_id']}")
    if combine == "mean_probabilities":
        predictions = np.mean([np.asarray(pred["probabilities"]) for pred in stored], axis=0).argmax(1)
    else:
        votes = np.stack([np.asarray(pred["predictions"]) for pred in stored])  # (members, samples)
        classes = int(max(votes.max(), targets.max())) + 1
        predictions = np.apply_along_axis(lambda v: np.bincount(v, minlength=classes).argmax(), 0, votes)
    groups = stored[0].get("groups")
    low_high = bootstrap_accuracy([(targets, predictions)], groups=None if groups is None else [groups])
    assert low_high is not None
    return float((predictions == targets).mean()), *low_high


def reads_path(study: Study) -> Path:
    return study.results / STUDY_RECORDS / "reads.json"


def recorded_reads(study: Study) -> dict[str, dict[str, Any]]:
    path = reads_path(study)
    if not path.is_file():
        return {}
    try:
        return dict(json.loads(path.read_text(encoding="utf-8"))["reads"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ResultsError(f"{path}: cannot be read as the study's recorded reads ({exc})") from None


def cell_digest(path: Path) -> str:
    """sha256 of the cell's plain bytes: the same for a cell stored plain or compact (compaction keeps the bytes)."""
    return hashlib.sha256(records.read_cell_bytes(path)).hexdigest()


def _cells(study: Study, grid: str | None, ids: list[str], records: dict[str, dict[str, Any]],
           by_grid: ByGrid | None = None) -> tuple[list[dict[str, Any]], list[str]]:
    """The ok records of ``ids`` and the ids not (yet) there: from the records of ``grid`` (default: the study's
    first) where ``by_grid`` gives them (a cell id may be in two grids' folders), else from ``records``."""
    if by_grid is not None:
        records = {r["cell_id"]: r for r in by_grid.get(grid or study.grids()[0].name, [])}
    found = [records[i] for i in ids if (records.get(i) or {}).get("status") == "ok"]
    return found, [i for i in ids if (records.get(i) or {}).get("status") != "ok"]


def _listed_cells(folder: Path) -> set[str]:
    """The cell ids the bench listed for the grid when it last ran (``run.json``; its folds come from the data)."""
    try:
        return set(json.loads((folder / "run.json").read_text(encoding="utf-8"))["grid"]["cells"])
    except (OSError, ValueError, KeyError, TypeError):
        return set()


def _selection(study: Study, grid: str | None, dataset: str, model: str, seeds: list[int] | None) -> list[str]:
    """One model's cells in a grid (default: the study's first): each seed's folds as the bench listed them (fold 0
    before any run)."""
    plan = plans(study)[grid or study.grids()[0].name]
    listed = _listed_cells(plan.folder)
    out = []
    for seed in seeds if seeds is not None else plan.config.seeds:
        fold = 0
        out.append(plan.cell_id_of(model, dataset, fold, seed))
        while (next_id := plan.cell_id_of(model, dataset, fold + 1, seed)) in listed:
            out.append(next_id)
            fold += 1
    return out


def comparison_inputs(study: Study, read: ComparisonRead) -> dict[str, list[str]]:
    """The input cells of a comparison given as arms, per side, each named ``grid/cell id``: one cell id may be in
    two grids' folders (a rerun of the same configuration), so an arm's cells are read from its own grid."""
    return {side: [f"{arm.grid}/{cell}" for arm in comparison_arms(study, read, side)
                   for cell in _selection(study, arm.grid, read.dataset, arm.model, arm.seeds)] for side in "ab"}


def _arm_cells(inputs: list[str], records: dict[str, dict[str, Any]], by_grid: ByGrid | None
               ) -> tuple[list[dict[str, Any]], list[str]]:
    """The ok records of ``inputs`` (``grid/cell id``) and the inputs not (yet) there: each from its grid's records
    where ``by_grid`` gives them, else from ``records`` by cell id."""
    grids = {grid: {r["cell_id"]: r for r in recs} for grid, recs in (by_grid or {}).items()}
    found, missing = [], []
    for name in inputs:
        grid, cell = name.split("/", 1)
        record = (records if by_grid is None else grids.get(grid, {})).get(cell) or {}
        if record.get("status") == "ok":
            found.append(record)
        else:
            missing.append(name)
    return found, missing


def _comparison(study: Study, read: ComparisonRead, records: dict[str, dict[str, Any]],
                by_grid: ByGrid | None) -> tuple[dict[str, Any] | None, list[str], list[str]]:
    """A comparison given as arms: (value or None, its inputs as ``grid/cell id``, the inputs missing)."""
    inputs = comparison_inputs(study, read)
    ids = inputs["a"] + inputs["b"]
    (found_a, missing_a), (found_b, missing_b) = (_arm_cells(inputs[side], records, by_grid) for side in "ab")
    if missing_a or missing_b:
        return None, ids, missing_a + missing_b
    try:
        paired = records_paired(found_a, found_b, read.split, level=read.level)
    except ValueError as exc:  # two cells of one side with one fold and seed, another test set, no pair
        raise ResultsError(f"{study.where}: reads.comparisons.{read.name}: {exc}") from None
    return {"difference": paired.difference, "low": paired.low, "high": paired.high, "p_value": paired.p_value,
            "pairs": paired.n_cells}, ids, []


def _value(study: Study, read: Any, records: dict[str, dict[str, Any]], by_grid: ByGrid | None = None
           ) -> tuple[dict[str, Any] | None, list[str], list[str]]:
    """(value or None, input cell ids, the ids missing)."""
    if isinstance(read, ComparisonRead) and read.arms:
        return _comparison(study, read, records, by_grid)
    if isinstance(read, ValidationRead):
        return validation_value(study, read, records)
    if isinstance(read, EnsembleRead):
        ids = [m[-1] for m in read_members(study, read)]
        found, missing = _cells(study, read.grid, ids, records, by_grid)
        if missing:
            return None, ids, missing
        result = seed_ensemble(found, read.split, read.combine)
        members_mean = statistics.fmean(r["metrics"][read.split]["accuracy"] for r in found)
        if result is None:
            return {"unreadable": f"a member stores no {read.combine.split('_')[-1]} for {read.split!r}",
                    "members_mean": members_mean}, ids, []
        accuracy, low, high = result
        return {"accuracy": accuracy, "low": low, "high": high, "members_mean": members_mean}, ids, []
    if isinstance(read, MeanRead):
        ids = _selection(study, read.grid, read.dataset, read.model, read.seeds)
        found, missing = _cells(study, read.grid, ids, records, by_grid)
        if missing:
            return None, ids, missing
        low_high = records_interval(found, read.split)
        return {"accuracy": statistics.fmean(r["metrics"][read.split]["accuracy"] for r in found),
                "low": None if low_high is None else low_high[0], "high": None if low_high is None else low_high[1],
                "runs": len(found)}, ids, []
    ids_a, ids_b = (_selection(study, read.grid, read.dataset, model, None) for model in (read.a, read.b))
    found_a, missing_a = _cells(study, read.grid, ids_a, records, by_grid)
    found_b, missing_b = _cells(study, read.grid, ids_b, records, by_grid)
    if missing_a or missing_b:
        return None, ids_a + ids_b, missing_a + missing_b
    paired = records_paired(found_a, found_b, read.split, level=read.level)
    return {"difference": paired.difference, "low": paired.low, "high": paired.high, "p_value": paired.p_value,
            "pairs": paired.n_cells}, ids_a + ids_b, []


def threshold_outcome(threshold: Threshold, value: dict[str, Any] | None | dict[str, dict[str, Any] | None]
                      ) -> dict[str, Any] | None:
    """``{"statistic", "value", "met", "decision"}`` of ``threshold`` on its read's value; ``None`` while the read
    is not in. A threshold over several reads takes ``{read name: value}`` and judges the best of them (``"of"``
    names it); ``None`` while any of them is not in, a read without the statistic (unreadable) left out."""
    best = None
    if isinstance(threshold.read, list):
        values = value or {}
        if any(name not in values or values[name] is None for name in threshold.read):
            return None
        found = {name: float(v[threshold.statistic]) for name, v in values.items()
                 if name in threshold.read and v.get(threshold.statistic) is not None}
        if not found:
            return None
        best = max(found, key=found.__getitem__)
        value = {threshold.statistic: found[best]}
    if value is None or threshold.statistic not in value or value[threshold.statistic] is None:
        return None
    got = float(value[threshold.statistic])
    met = got >= threshold.at_least - TOLERANCE if threshold.at_least is not None else \
        got < float(threshold.below) - TOLERANCE
    bound = f">= {threshold.at_least:g}" if threshold.at_least is not None else f"< {threshold.below:g}"
    return {"statistic": threshold.statistic, "value": got, "bound": bound, "met": met,
            **({"of": best} if best else {}), "decision": threshold.decision.met if met else threshold.decision.missed}


def decision_outcome(decision: AllOf, outcomes: dict[str, dict[str, Any] | None]) -> dict[str, Any] | None:
    """``{"met", "decision", "thresholds"}`` of ``decision`` from its thresholds' outcomes; ``None`` while one of them
    is not decided."""
    found = [outcomes.get(name) for name in decision.all_of]
    if any(outcome is None for outcome in found):
        return None
    met = all(outcome["met"] for outcome in found if outcome is not None)
    return {"met": met, "decision": decision.decision.met if met else decision.decision.missed,
            "thresholds": {name: bool(outcome["met"]) for name, outcome in zip(decision.all_of, found, strict=True)
                           if outcome is not None}}


def input_path(folders: dict[str, Path], cell: str, grid: str | None = None) -> Path:
    """The cell's file: an input named ``grid/cell id`` (a comparison given as arms) in that grid's folder, one of a
    read of one grid (``grid``) in its folder, else in whichever grid folder holds it (a validation read spans
    grids)."""
    if "/" in cell:  # neither a grid's name nor a cell id holds one
        grid, cell = cell.split("/", 1)
    if grid is not None:
        return RunDir(folders[grid]).cell_path(cell)
    paths = [RunDir(folder).cell_path(cell) for folder in dict.fromkeys(folders.values())]
    return next((path for path in paths if path.is_file()), paths[0])


def compute_reads(study: Study, records: dict[str, dict[str, Any]], folders: dict[str, Path], record: bool = True,
                  by_grid: ByGrid | None = None) -> dict[str, dict[str, Any]]:
    """Every declared read: the recorded value where there is one, else computed from ``records`` (cell id ->
    record) when all its inputs are in, and then recorded (with ``record``). A read still waiting for cells is
    ``{"kind", "missing": [...]}``. ``folders``: grid name -> its bench folder (for the inputs' digests);
    ``by_grid``: grid name -> its records (:func:`~.audit.study_records`), which a read of one grid, and each arm of
    a comparison, takes its cells from (one cell id may be in two grids' folders; default: ``records``)."""
    recorded = recorded_reads(study)
    reads = study.reads()
    out: dict[str, dict[str, Any]] = {}
    new = False
    for kind in READ_KINDS:
        for read in getattr(reads, kind):
            if read.name in recorded:
                out[read.name] = recorded[read.name]
                continue
            value, ids, missing = _value(study, read, records, by_grid)
            entry: dict[str, Any] = {"kind": kind.rstrip("s"), "value": value, "inputs": ids}
            if missing:
                entry["missing"] = missing
            elif value is not None:
                grid = None if isinstance(read, ValidationRead) else read.grid or study.grids()[0].name
                entry["digests"] = {i: cell_digest(input_path(folders, i, grid)) for i in ids}
                entry["time"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
                recorded[read.name] = entry
                new = True
            out[read.name] = entry
    for threshold in reads.thresholds:
        if threshold.name in recorded:
            out[threshold.name] = recorded[threshold.name]
            continue
        if isinstance(threshold.read, list):
            outcome = threshold_outcome(threshold, {n: (out.get(n) or {}).get("value") for n in threshold.read})
        else:
            outcome = threshold_outcome(threshold, (out.get(threshold.read) or {}).get("value"))
        entry = {"kind": "threshold", "read": threshold.read, "outcome": outcome}
        if outcome is not None:
            entry["time"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
            recorded[threshold.name] = entry
            new = True
        out[threshold.name] = entry
    for decision in reads.decisions:
        if decision.name in recorded:
            out[decision.name] = recorded[decision.name]
            continue
        outcome = decision_outcome(decision, {name: (out.get(name) or {}).get("outcome") for name in decision.all_of})
        entry = {"kind": "decision", "all_of": decision.all_of, "outcome": outcome}
        if outcome is not None:
            entry["time"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
            recorded[decision.name] = entry
            new = True
        out[decision.name] = entry
    if record and new:
        reads_path(study).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(reads_path(study), {"study": study.name, "reads": recorded})
    return out
