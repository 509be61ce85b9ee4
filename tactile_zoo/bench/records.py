"""Cell records: the one place that reads a cell file and decides whether it is a usable record.

A cell file (``cells/<cell id>.json``) is *valid* when it parses as a JSON object that passes :func:`check_record`:
the keys every record has (``cell_id``, ``status``, ``model``, ``dataset``, ``fold``, ``seed``, ``config_hash``),
with the right types, and for an ``ok`` record the metrics the tables, the report and a resumed run read
(``metrics`` with a ``test`` or ``val`` split whose ``accuracy`` is a number between 0 and 1, ``epochs_run``,
``best_epoch``, ``train_seconds``). Optional keys are checked when present. A second file with the same ``cell_id``
(a copy) is invalid: it would otherwise silently stand in for the first.

Anything else (unreadable, empty, truncated, ``[]``, ``"accuracy": "high"``, an ``ok`` cell without metrics) is an
:class:`InvalidCell`, and never silently dropped: ``tactile-zoo report`` names each one and refuses to write tables
unless ``--skip-invalid``; ``tactile-zoo bench`` names each one, moves a damaged cell of its grid aside to
``cells/damaged/`` before recomputing it (:func:`move_aside`), and exits non-zero unless ``--skip-invalid``.

The check is written out here rather than with a JSON-Schema library: the package has no such dependency, and the
rules (a number between 0 and 1 or NaN, lists of equal length, keys required by status) read more plainly as code.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import registry
from ..errors import ResultsError, TactileZooError
from ..recipe import recipe_name_of

__all__ = ["CELL_STATUSES", "CELLS_DIR", "DAMAGED_DIR", "InvalidCell", "CellScan", "InvalidCellsError", "check_record",
           "read_record", "scan_cells", "move_aside", "cell_files", "run_records", "revision_gaps", "qualifying_cells",
           "recipe_name_of"]

CELL_STATUSES = ("ok", "failed", "skipped")
#: a bench folder's folder of cell records, one ``<cell id>.json`` each
CELLS_DIR = "cells"
#: where ``bench`` moves a damaged cell file before recomputing the cell (inside ``cells/``)
DAMAGED_DIR = "damaged"
#: the per-split metrics the tables read; each, when present, is a fraction
_FRACTIONS = ("accuracy", "balanced_accuracy", "macro_f1")


@dataclass(frozen=True)
class InvalidCell:
    """A file under ``cells/`` that is not a usable cell record, and why."""

    path: Path
    reason: str

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


@dataclass
class CellScan:
    """Every ``*.json`` file of a ``cells/`` folder: the valid records by cell id, and the invalid files."""

    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    invalid: list[InvalidCell] = field(default_factory=list)


class InvalidCellsError(ResultsError):
    """Cell files that are unreadable or fail :func:`check_record`; ``str()`` names every one, a line each."""

    def __init__(self, invalid: list[InvalidCell], folder: Path, action: str) -> None:
        self.invalid = list(invalid)
        lines = [f"{len(self.invalid)} damaged cell file(s) in {folder}; {action}"]
        lines += [f"  {item}" for item in self.invalid]
        super().__init__("\n".join(lines))


# ----------------------------------------------------------------------------------------------- the schema
def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_fraction(value: Any) -> bool:
    # NaN is how a metric of an empty split is written (allow_nan); the tables show it as blank
    return _is_number(value) and (math.isnan(value) or 0 <= value <= 1)


def _is_name(value: Any) -> bool:
    return isinstance(value, str) and bool(value.strip())


def _shown(value: Any) -> str:
    text = json.dumps(value, default=str, allow_nan=True)
    return text if len(text) <= 40 else text[:37] + "..."


Check = tuple[Callable[[Any], bool], str]
_NAME: Check = (_is_name, "a non-empty string")
_INT: Check = (_is_int, "an integer")
_NUMBER: Check = (_is_number, "a number")
_OBJECT: Check = (lambda v: isinstance(v, dict), "an object")
_LIST: Check = (lambda v: isinstance(v, list), "a list")

#: keys every record has
_REQUIRED: dict[str, Check] = {
    "cell_id": _NAME, "status": (lambda v: v in CELL_STATUSES, f"one of {', '.join(CELL_STATUSES)}"),
    "model": _NAME, "dataset": _NAME, "fold": _INT, "seed": _INT, "config_hash": _NAME,
}
#: keys an ok record has besides (what the tables, the report and a resumed run's cell lines read)
_REQUIRED_OK: dict[str, Check] = {
    "metrics": _OBJECT, "epochs_run": _INT, "best_epoch": _INT, "train_seconds": _NUMBER,
}
#: keys checked when present (``None`` allowed for each)
_OPTIONAL: dict[str, Check] = {
    "format": _INT, "config": _OBJECT, "error": (lambda v: isinstance(v, str), "a string"),
    "protocol": (lambda v: isinstance(v, str), "a string"), "versions": _OBJECT, "curve": _LIST,
    "refit_curve": _LIST, "class_names": (lambda v: isinstance(v, list) and all(isinstance(n, str) for n in v),
                                          "a list of strings"),
    "n_train": _INT, "n_val": _INT, "n_test": _INT, "params": _INT, "infer_ms_per_sample": _NUMBER,
    "peak_memory_mb": _NUMBER, "prefix": _OBJECT, "predictions": _OBJECT, "reference": _OBJECT, "weights": _OBJECT,
}


def _check_keys(record: Mapping[str, Any], checks: Mapping[str, Check], required: bool) -> list[str]:
    problems = []
    for key, (ok, expected) in checks.items():
        if key not in record:
            if required:
                problems.append(f"no {key!r}")
            continue
        value = record[key]
        if value is None and not required:
            continue
        if not ok(value):
            problems.append(f"{key} is {_shown(value)}, expected {expected}")
    return problems


def _check_metrics(metrics: Mapping[str, Any]) -> list[str]:
    problems = []
    splits = {name: m for name, m in metrics.items() if m is not None}
    if not any(name in splits for name in ("test", "val")):
        problems.append("metrics has neither a 'test' nor a 'val' split")
    for name, split in splits.items():
        where = f"metrics.{name}"
        if not isinstance(split, dict):
            problems.append(f"{where} is {_shown(split)}, expected an object")
            continue
        if "accuracy" not in split:
            problems.append(f"{where} has no 'accuracy'")
        for key in _FRACTIONS:
            if key in split and not _is_fraction(split[key]):
                problems.append(f"{where}.{key} is {_shown(split[key])}, expected a number between 0 and 1")
        confusion = split.get("confusion")
        if confusion is not None and not (isinstance(confusion, list) and all(
                isinstance(row, list) and all(_is_int(v) for v in row) for row in confusion)):
            problems.append(f"{where}.confusion is not a matrix of counts")
    return problems


def _check_details(record: Mapping[str, Any]) -> list[str]:
    """The nested parts the report and the intervals read: curve rows, prefix lists, per-sample predictions."""
    problems = []
    for key in ("curve", "refit_curve"):
        rows = record.get(key) or []
        if any(not isinstance(row, dict) or not _is_int(row.get("epoch")) for row in rows):
            problems.append(f"{key} has a row without an integer 'epoch'")
    prefix = record.get("prefix")
    if isinstance(prefix, dict):
        fractions, accuracy = prefix.get("fractions"), prefix.get("accuracy")
        if not (isinstance(fractions, list) and isinstance(accuracy, list) and len(fractions) == len(accuracy)
                and all(_is_number(f) for f in fractions) and all(a is None or _is_fraction(a) for a in accuracy)):
            problems.append("prefix needs lists 'fractions' and 'accuracy' of equal length, of numbers")
    for split, values in (record.get("predictions") or {}).items():
        where = f"predictions.{split}"
        if not isinstance(values, dict):
            problems.append(f"{where} is {_shown(values)}, expected an object")
            continue
        targets, predicted = values.get("targets"), values.get("predictions")
        if not (isinstance(targets, list) and isinstance(predicted, list) and len(targets) == len(predicted)
                and all(_is_int(v) for v in targets) and all(_is_int(v) for v in predicted)):
            problems.append(f"{where} needs lists 'targets' and 'predictions' of equal length, of class indices")
        groups = values.get("groups")
        if groups is not None and not (isinstance(groups, list) and isinstance(targets, list)
                                       and len(groups) == len(targets)):
            problems.append(f"{where}.groups is not a list as long as its targets")
    return problems


def check_record(record: Any) -> list[str]:
    """What is wrong with ``record`` as a cell record (module docstring); an empty list when it is valid."""
    if not isinstance(record, dict):
        kind = "an array" if isinstance(record, list) else type(record).__name__
        return [f"holds {kind}, expected a cell record (a JSON object)"]
    problems = _check_keys(record, _REQUIRED, required=True)
    problems += _check_keys(record, _OPTIONAL, required=False)
    if record.get("status") == "ok":
        problems += _check_keys(record, _REQUIRED_OK, required=True)
        if isinstance(record.get("metrics"), dict):
            problems += _check_metrics(record["metrics"])
    if not problems:
        problems = _check_details(record)
    return problems


# ----------------------------------------------------------------------------------------------- reading
def read_record(path: str | os.PathLike) -> dict[str, Any] | InvalidCell:
    """The valid record in ``path``, or an :class:`InvalidCell` saying why not. A missing file, or something that
    is not a file (a folder named like one), raises ``FileNotFoundError``: absent is not damaged, the cell has
    simply not run (and writing it will say what is in the way)."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise FileNotFoundError(f"{path} is not a file")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as exc:
        return InvalidCell(path, f"cannot be read ({exc.strerror or exc})")
    if not data.strip():
        return InvalidCell(path, "empty file")
    try:
        record = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        return InvalidCell(path, "not UTF-8 text")
    except json.JSONDecodeError as exc:
        why = exc.msg.removesuffix(" at").lower()
        return InvalidCell(path, f"not valid JSON at line {exc.lineno} column {exc.colno} ({why}); truncated?")
    problems = check_record(record)
    if problems:
        shown = "; ".join(problems[:3]) + (f"; and {len(problems) - 3} more" if len(problems) > 3 else "")
        return InvalidCell(path, shown)
    return record


def scan_cells(folder: str | os.PathLike) -> CellScan:
    """Every ``*.json`` file directly in ``folder`` (a run's ``cells/``), read and checked; a missing folder is
    empty. Temporary files (``.<name>.*.tmp``) and ``damaged/`` are not cell files."""
    scan = CellScan()
    folder = Path(folder)
    if not folder.is_dir():
        return scan
    for path in sorted(folder.glob("*.json")):
        try:
            result = read_record(path)
        except FileNotFoundError:  # removed since the listing (moved aside by another bench process)
            continue
        if isinstance(result, InvalidCell):
            scan.invalid.append(result)
        elif result["cell_id"] in scan.records:  # a copy: which of the two is the cell's is not ours to guess
            first = folder / f"{result['cell_id']}.json"
            scan.invalid.append(InvalidCell(path, f"repeats cell_id {result['cell_id']!r}"
                                                  + (f" of {first.name}" if first.is_file() else "")))
        else:
            scan.records[result["cell_id"]] = result
    return scan


def move_aside(path: str | os.PathLike) -> Path:
    """Move the damaged cell file ``path`` into ``damaged/`` beside it, under a name no earlier one has; returns
    the new path. Call it only while holding the cell's claim, so no other process is writing that cell."""
    path = Path(path)
    folder = path.parent / DAMAGED_DIR
    folder.mkdir(exist_ok=True)
    target = folder / path.name
    n = 1
    while target.exists():  # a cell damaged twice keeps both copies
        target = folder / f"{path.stem}.{n}{path.suffix}"
        n += 1
    os.replace(path, target)
    return target


# ----------------------------------------------------------------------------------------------- results folders
def cell_files(folder: str | os.PathLike, recursive: bool = False) -> list[Path]:
    """The cell files of the bench folder ``folder`` (``cells/*.json``; with ``recursive``, those of every bench
    folder under it), in path order; ``cells/damaged/`` holds none. The one place the layout is spelt out."""
    folder = Path(folder)
    found = folder.rglob(f"{CELLS_DIR}/*.json") if recursive else (folder / CELLS_DIR).glob("*.json")
    return sorted(p for p in found if p.is_file())


def run_records(folder: str | os.PathLike, recursive: bool = False) -> list[dict[str, Any]]:
    """The valid cell records of the bench folder ``folder`` (its ``cells/``; with ``recursive``, of every ``cells/``
    under it), in path order. A damaged cell file raises :class:`InvalidCellsError` naming each one: a table built from
    committed results never silently leaves a cell out."""
    records: list[dict[str, Any]] = []
    invalid: list[InvalidCell] = []
    for path in cell_files(folder, recursive):
        result = read_record(path)
        (invalid if isinstance(result, InvalidCell) else records).append(result)
    if invalid:
        raise InvalidCellsError(invalid, Path(folder), "no table is built from a folder with damaged cells")
    return records


def revision_gaps(record: Mapping[str, Any]) -> list[str] | None:
    """How the code that computed ``record`` is older than the code registered now: one line per model or dataset
    whose revision has moved on (``[]``: current), or ``None`` when one of them is no longer registered, so there is
    nothing to compare with. A record without revisions predates them: revision 1."""
    config = record.get("config") or {}
    gaps = []
    for kind, lookup in (("model", registry.get_model_entry), ("dataset", registry.get_dataset_entry)):
        try:
            now = registry.revision_of(lookup(str(record[kind])))
        except TactileZooError:  # an unknown name, or a plugin that no longer loads
            return None
        then = config.get(f"{kind}_revision")
        then = registry.DEFAULT_REVISION if then is None else then
        if isinstance(then, int) and then < now:
            gaps.append(f"{kind} revision {then}, now {now}")
    return gaps


def qualifying_cells(folder: str | os.PathLike, recipe: str = "source", evaluation: str = "validation"
                     ) -> list[dict[str, Any]]:
    """The cells of ``folder`` a results table counts: ``ok``, computed by the current code, trained with the named
    ``recipe`` under ``evaluation``."""
    return [rec for rec in run_records(folder) if rec.get("status") == "ok" and revision_gaps(rec) == []
            and recipe_name_of(rec.get("config") or {}) == recipe
            and (rec.get("config") or {}).get("evaluation", "validation") == evaluation]

