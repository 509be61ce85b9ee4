"""Cell records: the one place that reads a cell file and decides whether it is a usable record.

A cell file (``cells/<cell id>.json``, or its compact form ``cells/<cell id>.json.gz``: see below) is *valid* when it
parses as a JSON object that passes :func:`~.schema.check_record` (the schema and its finite-and-range rule:
:mod:`.schema`). A second file with the same ``cell_id`` (a copy) is invalid: it would otherwise silently stand in for
the first.

Anything else (unreadable, empty, truncated, ``[]``, ``"accuracy": "high"``, an accuracy of NaN, ``"fold": -5``,
``best_epoch`` above ``epochs_run``, an ``ok`` cell without metrics) is an :class:`InvalidCell`, and never silently
dropped: ``tactile-zoo report`` names each one (file, field and value) and refuses to write tables unless
``--skip-invalid``; ``tactile-zoo bench`` names each one, moves a damaged cell of its grid aside to
``cells/damaged/`` before recomputing it (:func:`move_aside`), and exits non-zero unless ``--skip-invalid``. A cell
written by a newer tactile-zoo (``InvalidCell.newer``) is not damaged: ``bench`` and ``report`` refuse the folder
(:func:`refuse_newer`) before they write anything, rather than move it aside or leave it out.

**Compact cells.** A cell file may be stored compressed: ``<cell id>.json.gz`` holds the gzip of the plain file's
exact bytes (``zcat`` gives the plain file back), a fifth of the size. Every reader here reads both forms alike; a
folder holding both forms of one cell is refused (:class:`CellFormsError`, naming both files). ``bench`` writes new
cells plain and rewrites a compact cell compact (:meth:`.RunDir.write_cell`); ``python -m tactile_zoo.bench.compact
FOLDER`` compacts a finished folder's cells (:func:`compact_cell`), each verified before its plain file goes.
"""

from __future__ import annotations

import gzip
import json
import os
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import registry
from .._files import atomic_path
from ..errors import ConfigError, ResultsError, TactileZooError
from ..recipe import recipe_name_of
from .schema import check_record, joined, newer_format

__all__ = ["CELLS_DIR", "DAMAGED_DIR", "PLAIN_SUFFIX", "COMPACT_SUFFIX", "InvalidCell", "CellScan", "InvalidCellsError",
           "CellFormsError", "read_record", "read_cell_bytes", "cell_file", "scan_cells", "refuse_newer", "move_aside",
           "cell_files", "compact_cell", "compact_folder", "run_records", "revision_gaps", "qualifying_cells"]

#: a bench folder's folder of cell records, one ``<cell id>.json`` each
CELLS_DIR = "cells"
#: where ``bench`` moves a damaged cell file before recomputing the cell (inside ``cells/``)
DAMAGED_DIR = "damaged"
#: a plain cell file's name: ``<cell id>.json``
PLAIN_SUFFIX = ".json"
#: a compact cell file's name: ``<cell id>.json.gz``, the gzip of the plain file's bytes
COMPACT_SUFFIX = ".json.gz"


@dataclass(frozen=True)
class InvalidCell:
    """A file under ``cells/`` that is not a usable cell record, and why."""

    path: Path
    reason: str
    #: written by a newer tactile-zoo (its ``format`` is above :data:`RECORD_FORMAT`): not damaged, not ours to read
    newer: bool = False

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


@dataclass
class CellScan:
    """Every ``*.json`` file of a ``cells/`` folder: the valid records by cell id, and the invalid files."""

    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    invalid: list[InvalidCell] = field(default_factory=list)


class InvalidCellsError(ResultsError):
    """Cell files that are unreadable or fail :func:`~.schema.check_record`; ``str()`` names every one, a line each."""

    def __init__(self, invalid: list[InvalidCell], folder: Path, action: str) -> None:
        self.invalid = list(invalid)
        lines = [f"{len(self.invalid)} damaged cell file(s) in {folder}; {action}"]
        lines += [f"  {item}" for item in self.invalid]
        super().__init__("\n".join(lines))


class CellFormsError(ResultsError):
    """A folder holds both forms of one cell (``<id>.json`` and ``<id>.json.gz``): which is the cell's is not ours to
    guess. ``str()`` names both files of each such cell."""

    def __init__(self, pairs: list[tuple[Path, Path]]) -> None:
        self.pairs = list(pairs)
        lines = [f"{len(self.pairs)} cell(s) stored both plain and compact; keep one file of each (a compaction "
                 f"that was stopped: run `python -m tactile_zoo.bench.compact` on the folder again)"]
        lines += [f"  {plain} and {compact}" for plain, compact in self.pairs]
        super().__init__("\n".join(lines))


# ----------------------------------------------------------------------------------------------- reading
def _compact(path: Path) -> bool:
    return path.name.endswith(COMPACT_SUFFIX)


def read_cell_bytes(path: str | os.PathLike) -> bytes:
    """The plain bytes of the cell file ``path``: its contents, or, for a compact file, the decompressed contents
    (the same bytes its plain file held). A damaged compact file raises ``OSError``/``EOFError``/``zlib.error``."""
    path = Path(path)
    data = path.read_bytes()
    return gzip.decompress(data) if _compact(path) and data else data


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
    if _compact(path) and data:
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:  # BadGzipFile is an OSError; a cut file ends early
            return InvalidCell(path, f"not a readable gzip file ({exc or type(exc).__name__}); truncated?")
    if not data.strip():
        return InvalidCell(path, "empty file")
    try:
        record = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        return InvalidCell(path, "not UTF-8 text")
    except json.JSONDecodeError as exc:
        why = exc.msg.removesuffix(" at").lower()
        return InvalidCell(path, f"not valid JSON at line {exc.lineno} column {exc.colno} ({why}); truncated?")
    except (ValueError, RecursionError) as exc:  # an integer of over 4300 digits; arrays nested thousands deep
        return InvalidCell(path, f"cannot be read as a cell record ({str(exc).split(';')[0] or type(exc).__name__})")
    problems = check_record(record)
    if problems:
        return InvalidCell(path, joined(problems), newer=isinstance(record, dict) and bool(newer_format(record)))
    return record


def _listing(folder: Path, refuse_both: bool = True) -> list[Path]:
    """The cell files directly in the cells folder ``folder`` (``*.json`` and ``*.json.gz``), in path order; both
    forms of one cell raise :class:`CellFormsError` (unless ``refuse_both`` is false)."""
    paths = sorted(p for suffix in (PLAIN_SUFFIX, COMPACT_SUFFIX) for p in folder.glob(f"*{suffix}") if p.is_file())
    if refuse_both:
        both = [(p, p.with_name(p.name + ".gz")) for p in paths if not _compact(p)]
        both = [(p, gz) for p, gz in both if gz.is_file()]
        if both:
            raise CellFormsError(both)
    return paths


def cell_file(folder: str | os.PathLike, cell_id: str) -> Path:
    """The file of cell ``cell_id`` in the cells folder ``folder``: its compact file where only that exists, else its
    plain one (which need not exist yet: the path a new cell is written to). Both raise :class:`CellFormsError`."""
    plain = Path(folder) / f"{cell_id}{PLAIN_SUFFIX}"
    compact = plain.with_name(plain.name + ".gz")
    if compact.is_file():
        if plain.is_file():
            raise CellFormsError([(plain, compact)])
        return compact
    return plain


def scan_cells(folder: str | os.PathLike) -> CellScan:
    """Every cell file (``*.json``, ``*.json.gz``) directly in ``folder`` (a run's ``cells/``), read and checked; a
    missing folder is empty. Temporary files (``.<name>.*.tmp``) and ``damaged/`` are not cell files; both forms of
    one cell raise :class:`CellFormsError`."""
    scan = CellScan()
    folder = Path(folder)
    if not folder.is_dir():
        return scan
    for path in _listing(folder):
        try:
            result = read_record(path)
        except FileNotFoundError:  # removed since the listing (moved aside by another bench process)
            continue
        if isinstance(result, InvalidCell):
            scan.invalid.append(result)
        elif result["cell_id"] in scan.records:  # a copy: which of the two is the cell's is not ours to guess
            first = cell_file(folder, result["cell_id"])
            scan.invalid.append(InvalidCell(path, f"repeats cell_id {result['cell_id']!r}"
                                                  + (f" of {first.name}" if first.is_file() else "")))
        else:
            scan.records[result["cell_id"]] = result
    return scan


def refuse_newer(scan: CellScan, where: str) -> None:
    """A cell file written by a newer tactile-zoo is not damaged, and not this version's to read, recompute or move
    aside: raise ConfigError naming the first one (``where``: the folder as the command names it), before the
    caller writes anything."""
    newer = [item for item in scan.invalid if item.newer]
    if newer:
        others = f" (and {len(newer) - 1} more)" if len(newer) > 1 else ""
        raise ConfigError(f"{where}: {newer[0]}{others}; nothing was written")


def move_aside(path: str | os.PathLike) -> Path:
    """Move the damaged cell file ``path`` into ``damaged/`` beside it, under a name no earlier one has; returns
    the new path. Call it only while holding the cell's claim, so no other process is writing that cell."""
    path = Path(path)
    folder = path.parent / DAMAGED_DIR
    folder.mkdir(exist_ok=True)
    target = folder / path.name
    n = 1
    stem, suffix = (path.name.removesuffix(COMPACT_SUFFIX), COMPACT_SUFFIX) if _compact(path) else (path.stem,
                                                                                                   path.suffix)
    while target.exists():  # a cell damaged twice keeps both copies
        target = folder / f"{stem}.{n}{suffix}"
        n += 1
    os.replace(path, target)
    return target


# ----------------------------------------------------------------------------------------------- results folders
def cell_files(folder: str | os.PathLike, recursive: bool = False) -> list[Path]:
    """The cell files of the bench folder ``folder`` (``cells/*.json`` and ``cells/*.json.gz``; with ``recursive``,
    those of every bench folder under it), in path order; ``cells/damaged/`` holds none. The one place the layout is
    spelt out. Both forms of one cell raise :class:`CellFormsError`."""
    folder = Path(folder)
    found = [p for p in folder.rglob(CELLS_DIR) if p.is_dir()] if recursive else [folder / CELLS_DIR]
    return sorted(p for cells in found if cells.is_dir() for p in _listing(cells))


def compact_cell(path: str | os.PathLike) -> Path:
    """Store the valid plain cell file ``path`` compact (``<id>.json.gz``, the gzip of its bytes) and remove the plain
    file; returns the compact path. The compact file is written to a temporary file, read back and compared with the
    plain file (bytes and record) before it takes its name and before the plain file goes, so a stop at any moment
    loses nothing: at worst both forms remain, and compacting again finishes the job (a compact file that is not the
    plain file's copy is refused, naming both). A damaged plain file raises :class:`InvalidCellsError`."""
    path = Path(path)
    target = path.with_name(path.name + ".gz")
    record = read_record(path)
    if isinstance(record, InvalidCell):
        raise InvalidCellsError([record], path.parent, "nothing compacted")
    data = path.read_bytes()

    def same(candidate: Path) -> bool:  # the gzip of the plain bytes (the temporary file's name ends .tmp)
        try:
            plain = gzip.decompress(candidate.read_bytes())
            return plain == data and json.loads(plain.decode("utf-8")) == record
        except (OSError, EOFError, zlib.error, ValueError):
            return False

    if target.exists():  # an earlier compaction stopped after the compact file took its name
        if not same(target):
            raise CellFormsError([(path, target)])
    else:
        with atomic_path(target) as tmp:
            tmp.write_bytes(gzip.compress(data, compresslevel=9, mtime=0))  # no time stamp: the same bytes each time
            if not same(tmp):
                raise ResultsError(f"{path}: its compressed copy does not read back equal; nothing compacted")
    path.unlink()
    return target


def compact_folder(folder: str | os.PathLike, recursive: bool = True) -> tuple[list[Path], int]:
    """Compact every plain cell file of the bench folder ``folder`` (with ``recursive``, of every bench folder under
    it) with :func:`compact_cell`; returns the compact files written and how many cells were compact already. Every
    plain file is read first: a damaged one raises :class:`InvalidCellsError` naming each, and nothing is compacted."""
    folder = Path(folder)
    dirs = [p for p in folder.rglob(CELLS_DIR) if p.is_dir()] if recursive else [folder / CELLS_DIR]
    paths = [p for cells in sorted(dirs) if cells.is_dir() for p in _listing(cells, refuse_both=False)]
    plain = [p for p in paths if not _compact(p)]
    invalid = [r for r in map(read_record, plain) if isinstance(r, InvalidCell)]
    if invalid:
        raise InvalidCellsError(invalid, folder, "nothing compacted")
    done = [compact_cell(p) for p in plain]
    return done, sum(1 for p in paths if _compact(p) and p.with_name(p.name.removesuffix(".gz")) not in plain)


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
    nothing to compare with. A record without revisions predates them: revision 1.

    An older model revision the model still builds (:func:`tactile_zoo.registry.model_revisions`) is no gap: its
    cells rerun as they ran (the revision is part of their hash, so they never pool with another revision's)."""
    config = record.get("config") or {}
    gaps = []
    for kind, lookup in (("model", registry.get_model_entry), ("dataset", registry.get_dataset_entry)):
        try:
            entry = lookup(str(record[kind]))
        except TactileZooError:  # an unknown name, or a plugin that no longer loads
            return None
        now = registry.revision_of(entry)
        then = config.get(f"{kind}_revision")
        then = registry.DEFAULT_REVISION if then is None else then
        if kind == "model" and then in registry.model_revisions(entry):
            continue
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

