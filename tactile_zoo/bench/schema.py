"""The cell record schema: :func:`check_record` says what is wrong with a record, for every reader and the writer.

Keys every record has: ``cell_id``, ``status`` (ok, failed, skipped), ``model``, ``dataset``, ``fold``, ``seed``,
``config_hash``; an ``ok`` record also has what the tables, the report and a resumed run read: ``metrics`` with a
``test`` or ``val`` split that has an ``accuracy``, ``epochs_run``, ``best_epoch``, ``train_seconds``. Optional keys
are checked when present.

Every number obeys one finite-and-range rule:

- no NaN or infinity anywhere (JSON has neither; Python's ``json`` reads the ``NaN`` and ``Infinity`` literals and
  turns ``1e999`` into infinity, and all three are refused, with the path of the first, e.g. ``curve[3].val_loss``);
- accuracies and other fractions (balanced accuracy, macro-F1, validation accuracy per epoch, prefix fractions,
  earliness) lie in [0, 1]; a score may be ``null`` only for an empty split (its ``n`` is 0);
- fold, seed, epochs and every count (samples, parameters, confusion entries, attempts) are non-negative integers,
  and ``best_epoch`` is at most ``epochs_run``;
- times and memory (``train_seconds``, ``seconds``, ``infer_ms_per_sample``, ``peak_memory_mb``, a curve row's
  ``seconds``) are finite and non-negative.

A record whose ``format`` is above :data:`RECORD_FORMAT` was written by a newer tactile-zoo: it is refused as such
(``InvalidCell.newer``), not read as if it were this version's.

The writing side keeps the rule: :func:`nan_to_null` writes a number that is not one (the score of an empty split, a
validation loss that overflowed) as ``null``, and :meth:`~.rundir.RunDir.write_cell` refuses a record that fails
:func:`check_record` (:class:`InvalidRecordError`), so no process of this code writes a record it would refuse.

The check is written out here rather than with a JSON-Schema library: the package has no such dependency, and the
rules (a number between 0 and 1, lists of equal length, keys required by status) read more plainly as code.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from ..errors import ResultsError

__all__ = ["CELL_STATUSES", "RECORD_FORMAT", "InvalidRecordError", "check_record", "newer_format", "nan_to_null"]

#: the cell record format this code writes (``format``); a record of a higher one was written by a newer tactile-zoo
RECORD_FORMAT = 1
CELL_STATUSES = ("ok", "failed", "skipped")
#: the per-split metrics the tables read; each, when present, is a fraction
_FRACTIONS = ("accuracy", "balanced_accuracy", "macro_f1")


class InvalidRecordError(ResultsError):
    """A record about to be written fails :func:`check_record`; ``problems`` lists what is wrong."""

    def __init__(self, path: Path, problems: list[str]) -> None:
        self.path, self.problems = path, list(problems)
        super().__init__(f"{path}: the record is not valid ({joined(problems)}); not written")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _all_ints(values: list[Any]) -> bool:
    """Whether every item of ``values`` is an int (not a bool). A parsed list of plain ints is settled by the set of
    its items' types, at C speed: the per-sample predictions were most of a record's check, item by item."""
    return set(map(type, values)) <= {int} or all(map(_is_int, values))


def _all_counts(values: list[Any]) -> bool:
    """Whether every item of ``values`` is an int (not a bool), 0 or more."""
    return _all_ints(values) and (not values or min(values) >= 0)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_count(value: Any) -> bool:
    return _is_int(value) and value >= 0


def _is_amount(value: Any) -> bool:
    """A finite number, 0 or more: seconds, milliseconds, megabytes (an int is finite, however large)."""
    return _is_number(value) and value >= 0 and (isinstance(value, int) or math.isfinite(value))


def _is_fraction(value: Any) -> bool:
    return _is_number(value) and 0 <= value <= 1  # False for NaN, whose every comparison is False


def _is_name(value: Any) -> bool:
    return isinstance(value, str) and bool(value.strip())


def _shown(value: Any) -> str:
    text = json.dumps(value, default=str, allow_nan=True)
    return text if len(text) <= 40 else text[:37] + "..."


def joined(problems: list[str]) -> str:
    return "; ".join(problems[:3]) + (f"; and {len(problems) - 3} more" if len(problems) > 3 else "")


Check = tuple[Callable[[Any], bool], str]
_NAME: Check = (_is_name, "a non-empty string")
_COUNT: Check = (_is_count, "a non-negative integer")
_AMOUNT: Check = (_is_amount, "a finite number, 0 or more")
_FRACTION: Check = (_is_fraction, "a number between 0 and 1")
_OBJECT: Check = (lambda v: isinstance(v, dict), "an object")
_LIST: Check = (lambda v: isinstance(v, list), "a list")
_TEXT: Check = (lambda v: isinstance(v, str), "a string")

#: keys every record has
_REQUIRED: dict[str, Check] = {
    "cell_id": _NAME, "status": (lambda v: v in CELL_STATUSES, f"one of {', '.join(CELL_STATUSES)}"),
    "model": _NAME, "dataset": _NAME, "fold": _COUNT, "seed": _COUNT, "config_hash": _NAME,
}
#: keys an ok record has besides (what the tables, the report and a resumed run's cell lines read)
_REQUIRED_OK: dict[str, Check] = {
    "metrics": _OBJECT, "epochs_run": _COUNT, "best_epoch": _COUNT, "train_seconds": _AMOUNT,
}
#: keys checked when present (``None`` allowed for each)
_OPTIONAL: dict[str, Check] = {
    "format": (lambda v: _is_int(v) and v >= 1, "a positive integer"), "hash_format": _COUNT, "config": _OBJECT,
    "error": _TEXT, "protocol": _TEXT, "versions": _OBJECT, "curve": _LIST, "refit_curve": _LIST,
    "class_names": (lambda v: isinstance(v, list) and all(isinstance(n, str) for n in v), "a list of strings"),
    "n_train": _COUNT, "n_val": _COUNT, "n_test": _COUNT, "params": _COUNT, "threads": _COUNT, "attempts": _COUNT,
    "test_reads": _COUNT, "seconds": _AMOUNT, "infer_ms_per_sample": _AMOUNT, "peak_memory_mb": _AMOUNT,
    "peak_gpu_memory_mb": _AMOUNT, "prefix": _OBJECT, "predictions": _OBJECT, "reference": _OBJECT,
    "weights": _OBJECT, "teachers": _LIST,
}
#: the numbers of a curve row (``epoch`` is required), of ``prefix`` and of ``reference``, checked when present
_CURVE_ROW: dict[str, Check] = {"seconds": _AMOUNT, "val_accuracy": _FRACTION}
_PREFIX: dict[str, Check] = {"earliness": _FRACTION}
_REFERENCE: dict[str, Check] = {"epochs": _COUNT, "best_test_epoch": _COUNT, "best_test_epoch_accuracy": _FRACTION,
                                "final_epoch_accuracy": _FRACTION}


def _check_keys(record: Mapping[str, Any], checks: Mapping[str, Check], required: bool, where: str = ""
                ) -> list[str]:
    problems = []
    for key, (ok, expected) in checks.items():
        if key not in record:
            if required:
                problems.append(f"no {where}{key!r}")
            continue
        value = record[key]
        if value is None and not required:
            continue
        if not ok(value):
            problems.append(f"{where}{key} is {_shown(value)}, expected {expected}")
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
        problems += _check_keys(split, {"n": _COUNT}, required=False, where=f"{where}.")
        empty = split.get("n") == 0  # an empty split has no score: null (engine.metrics gives NaN, written null)
        for key in _FRACTIONS:
            if key in split and not (_is_fraction(split[key]) or (empty and split[key] is None)):
                problems.append(f"{where}.{key} is {_shown(split[key])}, expected a number between 0 and 1")
        confusion = split.get("confusion")
        if confusion is not None and not (isinstance(confusion, list) and all(
                isinstance(row, list) and _all_counts(row) for row in confusion)):
            problems.append(f"{where}.confusion is not a matrix of counts")
    return problems


def _check_ok(record: Mapping[str, Any]) -> list[str]:
    """An ok record's required keys, its metrics, and the one rule between two of its keys."""
    problems = _check_keys(record, _REQUIRED_OK, required=True)
    if isinstance(record.get("metrics"), dict):
        problems += _check_metrics(record["metrics"])
    best, run = record.get("best_epoch"), record.get("epochs_run")
    if _is_count(best) and _is_count(run) and best > run:
        problems.append(f"best_epoch is {best}, expected at most epochs_run ({run})")
    return problems


def _check_details(record: Mapping[str, Any]) -> list[str]:
    """The nested parts the report and the intervals read: curve rows, prefix lists, per-sample predictions."""
    problems = []
    for key in ("curve", "refit_curve"):
        rows = record.get(key) or []
        if any(not isinstance(row, dict) or not _is_count(row.get("epoch")) for row in rows):
            problems.append(f"{key} has a row without a non-negative integer 'epoch'")
            continue
        for i, row in enumerate(rows):
            problems += _check_keys(row, _CURVE_ROW, required=False, where=f"{key}[{i}].")
    prefix = record.get("prefix")
    if isinstance(prefix, dict):
        fractions, accuracy = prefix.get("fractions"), prefix.get("accuracy")
        if not (isinstance(fractions, list) and isinstance(accuracy, list) and len(fractions) == len(accuracy)
                and all(_is_fraction(f) for f in fractions) and all(a is None or _is_fraction(a) for a in accuracy)):
            problems.append("prefix needs lists 'fractions' and 'accuracy' of equal length, of numbers between 0 "
                            "and 1")
        balanced = prefix.get("balanced_accuracy")
        if balanced is not None and not (isinstance(balanced, list)
                                         and all(a is None or _is_fraction(a) for a in balanced)):
            problems.append("prefix.balanced_accuracy is not a list of numbers between 0 and 1")
        steps = prefix.get("steps")
        if steps is not None and not (isinstance(steps, list) and _all_counts(steps)):
            problems.append("prefix.steps is not a list of non-negative integers")
        problems += _check_keys(prefix, _PREFIX, required=False, where="prefix.")
    if isinstance(record.get("reference"), dict):
        problems += _check_keys(record["reference"], _REFERENCE, required=False, where="reference.")
    weights = record.get("weights")
    if isinstance(weights, dict):
        problems += _check_keys(weights, {"bytes": _COUNT}, required=False, where="weights.")
    for split, values in (record.get("predictions") or {}).items():
        where = f"predictions.{split}"
        if not isinstance(values, dict):
            problems.append(f"{where} is {_shown(values)}, expected an object")
            continue
        targets, predicted = values.get("targets"), values.get("predictions")
        if not (isinstance(targets, list) and isinstance(predicted, list) and len(targets) == len(predicted)
                and _all_ints(targets) and _all_ints(predicted)):
            problems.append(f"{where} needs lists 'targets' and 'predictions' of equal length, of class indices")
        groups = values.get("groups")
        if groups is not None and not (isinstance(groups, list) and isinstance(targets, list)
                                       and len(groups) == len(targets)):
            problems.append(f"{where}.groups is not a list as long as its targets")
    return problems


def _finite(value: Any) -> bool:
    """Whether ``value`` (a parsed JSON document) holds no NaN or infinity; a list of plain numbers is checked at C
    speed (``math.isfinite`` over it), which keeps a record of 100 000 stored probabilities at a few milliseconds."""
    kind = type(value)
    if kind is float:
        return math.isfinite(value)
    if kind is list or kind is dict:
        items = value if kind is list else value.values()
        try:
            return all(map(math.isfinite, items))
        except (TypeError, OverflowError):  # not all plain numbers (or an int too large for a float): one by one
            return all(map(_finite, items))
    return True


def _non_finite(value: Any, where: str = "") -> Iterator[tuple[str, float]]:
    """``(path, value)`` of every NaN or infinity in ``value`` (paths as ``metrics.test.accuracy``, ``curve[3].x``)."""
    if isinstance(value, float):
        if not math.isfinite(value):
            yield where, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _non_finite(item, f"{where}.{key}" if where else str(key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _non_finite(item, f"{where}[{i}]")


def newer_format(record: Mapping[str, Any]) -> str | None:
    """Why ``record`` is not this version's to read (its ``format`` is newer), or ``None``."""
    version = record.get("format")
    if _is_int(version) and version > RECORD_FORMAT:
        return (f"format is {version}, newer than the cell record format this tactile-zoo reads ({RECORD_FORMAT}): a "
                f"newer tactile-zoo wrote it; upgrade tactile-zoo to read it")
    return None


def check_record(record: Any) -> list[str]:
    """What is wrong with ``record`` as a cell record (module docstring); an empty list when it is valid."""
    if not isinstance(record, dict):
        kind = "an array" if isinstance(record, list) else type(record).__name__
        return [f"holds {kind}, expected a cell record (a JSON object)"]
    newer = newer_format(record)
    if newer:
        return [newer]
    problems = _check_keys(record, _REQUIRED, required=True)
    problems += _check_keys(record, _OPTIONAL, required=False)
    if record.get("status") == "ok":
        problems += _check_ok(record)
    if not problems:
        problems = _check_details(record)
    if not problems and not _finite(record):  # anywhere else: a curve's loss, a stored probability, the config
        problems = [f"{path} is {_shown(value)}, expected a finite number (a record holds no NaN or infinity)"
                    for path, value in _non_finite(record)]
    return problems


def nan_to_null(value: Any) -> Any:
    """``value`` with every NaN and infinity replaced by ``None``: how a record writes a number that is not one (the
    score of an empty split, a validation loss that overflowed), since JSON has no NaN. :func:`check_record` then
    decides where ``null`` may stand; a NaN accuracy of a split with samples does not become a valid record."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: nan_to_null(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [nan_to_null(item) for item in value]
    return value
