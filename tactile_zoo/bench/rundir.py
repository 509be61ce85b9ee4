"""The run directory: atomic cell files, per-cell claims and the table lock (the tables: :mod:`.tables`).

Layout of ``--out``::

    run.json                                                          written first: its "format" marks a bench folder
    cells/<model>__<dataset>__f<fold>__s<seed>__<config hash>.json   one per finished cell (ok, failed, skipped)
                                                                      (or .json.gz: compact, see .records)
    cells/damaged/                                                    damaged cell files, moved aside (.records)
    claims/<cell id>.lock                                             held (flock) while a process runs that cell
    progress/<cell id>.json                                           a running cell's last epoch (see .progress)
    run.lock, leaderboard.csv, summary.csv, report.md, plots/*.png

``bench --out`` refuses an existing folder that holds anything and is not a bench folder (:meth:`RunDir.prepare`).

Every file is written to a temporary file in the same folder and renamed over the target (``os.replace``), so a
reader, or a rerun after SIGKILL, sees either the old complete file or the new complete one, never a torn one.

Two processes on one ``--out`` share the work through *claims*: before running a cell a process takes an exclusive,
non-blocking ``fcntl.flock`` on the cell's claim file (and writes its pid and host there); a cell claimed by another
live process is left to it. The kernel drops the lock when its holder exits or is killed, so a claim can never go
stale. Once a process has nothing else to do it waits for the cells others hold (saying which pid holds them) and, if
the holder died without finishing one, runs that cell itself. The tables are rewritten under ``run.lock``. So two
``tactile-zoo bench`` commands on the same folder cooperate: no cell is computed twice and no file is corrupted.
(``flock`` works on local file systems; on NFS Linux maps it to POSIX byte-range locks, which need a lock daemon.)
"""

from __future__ import annotations

import contextlib
import errno
import gzip
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .._files import atomic_write_bytes, atomic_write_text, torn_temporaries
from .._owned import FolderRule, check_folder, make_writable
from ..errors import ConfigError
from .records import COMPACT_SUFFIX, CellScan, InvalidCell, cell_file, read_record, scan_cells
from .schema import InvalidRecordError, check_record

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no claims; one process per --out
    fcntl = None  # type: ignore[assignment]

__all__ = ["atomic_write_json", "RunDir", "Claim", "CellWriteError"]


#: the version of ``run.json``'s ``format`` this code reads and writes (a higher one: a newer tactile-zoo wrote it)
BENCH_VERSION = 1
BENCH_FORMAT_PREFIX = "tactile-zoo-bench/"
#: ``run.json``'s ``format``: the marker of a bench folder, written when ``bench`` creates the folder
BENCH_FORMAT = f"{BENCH_FORMAT_PREFIX}{BENCH_VERSION}"
RUN_JSON = "run.json"
RUN_LOCK = "run.lock"
#: documents a study may commit into its folder before the first cell runs (what it declares, how to read it);
#: bench never writes these names, so a new folder holding only them is not refused as someone else's
PLAN_DOCUMENTS = frozenset({"README.md", "PLAN.md"})
#: the records a study keeps in its results folder (its freeze, reads and report, :mod:`tactile_zoo.study`): a grid
#: whose folder is the results folder itself (``folder: .``) starts its first cell beside them; bench never writes it
STUDY_RECORDS = "study"
#: ``--out`` of bench under the output-folder rule: besides the plan documents, the lock and run.json's temporary
#: file are created before the marker, so a folder holding only them is not someone else's
BENCH_FOLDER = FolderRule("--out", "bench", RUN_JSON, "a bench folder to resume",
                          ignored=PLAN_DOCUMENTS | {RUN_LOCK, STUDY_RECORDS}, ignored_prefixes=(f".{RUN_JSON}.",))


class CellWriteError(OSError):
    """A cell (or table) file could not be written (disk full, permissions)."""


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, set | frozenset | tuple):
        return list(value)
    return str(value)


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    """``obj`` as JSON, one top-level key per line with its value written compactly: a cell's per-sample lists
    (predictions, probabilities, recordings) take a line each instead of a line per number, a fifth of the bytes.
    A NaN or infinity raises ``ValueError`` before anything is written: JSON has neither, and a file holding one is
    refused by every reader (:mod:`.schema`). A ``path`` ending ``.json.gz`` gets the gzip of those bytes (a compact
    cell file, :mod:`.records`)."""
    def dump(value: Any, **kwargs: Any) -> str:
        return json.dumps(value, default=_json_default, allow_nan=False, **kwargs)

    if isinstance(obj, dict) and obj:
        body = ",\n".join(f" {dump(str(k))}: {dump(v, separators=(',', ':'))}" for k, v in obj.items())
        text = "{\n" + body + "\n}\n"
    else:
        text = dump(obj, indent=1) + "\n"
    if str(path).endswith(COMPACT_SUFFIX):
        atomic_write_bytes(path, gzip.compress(text.encode("utf-8"), compresslevel=9, mtime=0))
    else:
        atomic_write_text(path, text)


class Claim:
    """An exclusive ``flock`` on one claim file; released by :meth:`release` or when the process ends."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path, self.fd = path, fd

    def release(self, remove: bool = True) -> None:
        if self.fd < 0:
            return
        if remove:  # unlink while still holding the lock, so a waiter notices the file is gone (see RunDir.claim)
            with contextlib.suppress(OSError):
                self.path.unlink()
        with contextlib.suppress(OSError):
            os.close(self.fd)  # closing drops the flock
        self.fd = -1


class RunDir:
    """The ``--out`` folder of a run."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.cells_dir = self.path / "cells"
        self.claims_dir = self.path / "claims"
        self.plots_dir = self.path / "plots"
        self.progress_dir = self.path / "progress"

    # ------------------------------------------------------------------------------------------- set-up
    def _run_info(self) -> Any:
        try:
            return json.loads((self.path / RUN_JSON).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None

    def check_format(self) -> None:
        """Refuse a folder whose ``run.json`` declares a format this code does not know: a higher
        ``tactile-zoo-bench/N`` (a newer tactile-zoo wrote it, and may have put there what this one would drop when
        it rewrites the file) or any other ``format``. Raises ConfigError naming the file and both formats; call it
        before writing anything into the folder. A folder without run.json, or with one of a version before the
        marker (no ``format``), passes."""
        info = self._run_info()
        if not isinstance(info, dict) or "format" not in info or info["format"] == BENCH_FORMAT:
            return
        found = info["format"]
        version = found[len(BENCH_FORMAT_PREFIX):] if isinstance(found, str) \
            and found.startswith(BENCH_FORMAT_PREFIX) else ""
        if version.isdigit() and int(version) < BENCH_VERSION:  # an older format: read as it is (none exists yet)
            return
        newer = version.isdigit() and int(version) > BENCH_VERSION
        raise ConfigError(f"{self.path / RUN_JSON}: format {found!r} is "
                          + (f"newer than the one this tactile-zoo reads and writes ({BENCH_FORMAT!r}): a newer "
                             f"tactile-zoo wrote this folder; upgrade tactile-zoo to use it"
                             if newer else f"not one this tactile-zoo knows (it reads and writes {BENCH_FORMAT!r})")
                          + "; nothing was written")

    def marked(self) -> bool:
        """Whether ``run.json`` carries the bench folder marker (``"format": "tactile-zoo-bench/N"``)."""
        info = self._run_info()
        return isinstance(info, dict) and str(info.get("format", "")).startswith(BENCH_FORMAT_PREFIX)

    def is_bench_folder(self) -> bool:
        """Whether the folder was written by tactile-zoo bench: the marker, or a folder of a version before it (a
        ``run.json`` with the ``command`` and ``grid`` only bench writes, or a ``cells/`` folder with a valid cell
        record, as the committed benchmarks/results folders that have no run.json)."""
        info = self._run_info()
        if isinstance(info, dict) and (str(info.get("format", "")).startswith(BENCH_FORMAT_PREFIX)
                                       or {"command", "grid"} <= set(info)):
            return True
        return bool(self.scan().records)

    def prepare(self) -> RunDir:
        """Check that ``--out`` is new, empty or a bench folder, mark it as one (``run.json``), create its folders
        and prove the location is writable: the output-folder rule every command shares (:mod:`tactile_zoo._owned`).
        A folder holding anything else is refused before a byte is written, so a bench run never overwrites files
        it did not write; that, a ``run.json`` of a format this code does not know (:meth:`check_format`) and an
        unwritable ``--out`` are ConfigErrors."""
        self.check_format()
        check_folder(self.path, BENCH_FOLDER, self.is_bench_folder)
        make_writable(self.path, BENCH_FOLDER)
        try:
            # the marker comes first, under the lock: a second bench starting on the same new folder sees either
            # an empty folder (bar the lock and run.json's temporary) or the marker, never a half-made folder
            with self.table_lock():
                if not (self.path / RUN_JSON).exists():
                    atomic_write_json(self.path / RUN_JSON, {"format": BENCH_FORMAT, "status": "created"})
            for folder in (self.cells_dir, self.claims_dir, self.progress_dir):
                folder.mkdir(parents=True, exist_ok=True)
            make_writable(self.cells_dir, BENCH_FOLDER)
        except OSError as exc:
            raise ConfigError(f"--out {self.path}: cannot write there ({exc.strerror or exc}); choose a writable "
                              f"folder") from None
        return self

    # ------------------------------------------------------------------------------------------- cells
    def cell_path(self, cell_id: str) -> Path:
        """The cell's file: ``cells/<id>.json``, or ``cells/<id>.json.gz`` where the cell is stored compact (both
        forms of one cell raise :class:`~.records.CellFormsError`)."""
        return cell_file(self.cells_dir, cell_id)

    def read_cell(self, cell_id: str) -> dict[str, Any] | None:
        """The cell's valid record; ``None`` when it has no file or a damaged one (see :meth:`read_cell_file`)."""
        result = self.read_cell_file(cell_id)
        return None if isinstance(result, InvalidCell) else result

    def read_cell_file(self, cell_id: str) -> dict[str, Any] | InvalidCell | None:
        """The cell's valid record, an :class:`~.records.InvalidCell` for a damaged file, ``None`` for no file."""
        try:
            return read_record(self.cell_path(cell_id))
        except FileNotFoundError:
            return None

    def scan(self) -> CellScan:
        """Every cell file in the folder, checked (:func:`.records.scan_cells`): valid records and damaged files."""
        return scan_cells(self.cells_dir)

    def cells(self) -> dict[str, dict[str, Any]]:
        """Every valid cell record in the folder, by cell id (damaged files: :meth:`scan`)."""
        return self.scan().records

    def write_cell(self, record: dict[str, Any]) -> Path:
        """Write ``record`` as its cell's file, plain (``<id>.json``) unless the cell is stored compact, which stays
        compact (one file per cell, replaced atomically: no moment holds both forms). A record that fails the schema
        (:func:`~.schema.check_record`: a NaN score, a negative fold) raises :class:`~.schema.InvalidRecordError` and
        nothing is written, so no reader is ever handed a record it would refuse; a file that cannot be written
        raises :class:`CellWriteError`."""
        path = self.cell_path(record["cell_id"])
        problems = check_record(record)
        if problems:
            raise InvalidRecordError(path, problems)
        try:
            atomic_write_json(path, record)
        except OSError as exc:
            raise CellWriteError(exc.errno, f"cannot write cell file {path}: {exc.strerror or exc}") from None
        return path

    # ------------------------------------------------------------------------------------------- claims
    def _claim_path(self, cell_id: str) -> Path:
        return self.claims_dir / f"{cell_id}.lock"

    def claim(self, cell_id: str, blocking: bool = False) -> Claim | None:
        """Take the cell's claim; ``None`` if another process holds it (non-blocking mode)."""
        if fcntl is None:
            return Claim(self._claim_path(cell_id), -1)
        path = self._claim_path(cell_id)
        while True:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
            except BlockingIOError:
                os.close(fd)
                return None
            except BaseException:
                os.close(fd)
                raise
            # the holder we waited for may have unlinked the file before releasing: our lock is then on an orphan
            # inode that a third process cannot see; start over on the current file
            try:
                same = os.fstat(fd).st_ino == os.stat(path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
                    os.write(fd, f"{os.getpid()} {socket.gethostname()} {time.strftime('%H:%M:%S')}\n".encode())
                return Claim(path, fd)
            os.close(fd)

    def remove_torn(self, folder: Path, name: str) -> int:
        """Delete temporary files a killed writer of ``folder/name`` left behind. Only call this while holding what
        serialises those writes (the cell's claim, or the table lock), so no live writer's file is touched."""
        removed = 0
        for tmp in torn_temporaries(folder, name):
            with contextlib.suppress(OSError):
                tmp.unlink()
                removed += 1
        return removed

    def claim_holder(self, cell_id: str) -> str:
        """``"pid P on HOST since T"`` of the process holding a claim (best effort)."""
        try:
            text = self._claim_path(cell_id).read_text().split()
        except OSError:
            return "another process"
        return f"pid {text[0]} on {text[1]} since {text[2]}" if len(text) >= 3 else "another process"

    @contextlib.contextmanager
    def table_lock(self) -> Iterator[None]:
        """Serialise rewriting the tables and run.json between processes sharing the folder."""
        if fcntl is None:
            yield
            return
        fd: int | None
        try:
            fd = os.open(self.path / RUN_LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            if exc.errno not in (errno.EACCES, errno.EPERM, errno.EROFS):
                raise
            # a read-only folder: an existing lock file can still be locked (flock needs no write access); with
            # none, no process can write here, so there is nothing to serialise. Writing fails later, naming
            # the file, for a caller that tries.
            try:
                fd = os.open(self.path / RUN_LOCK, os.O_RDONLY)
            except OSError:
                fd = None
        if fd is None:
            yield
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)
