"""The run directory: atomic cell files, per-cell claims and the table lock (the tables: :mod:`.tables`).

Layout of ``--out``::

    cells/<model>__<dataset>__f<fold>__s<seed>__<config hash>.json   one per finished cell (ok, failed, skipped)
    claims/<cell id>.lock                                             held (flock) while a process runs that cell
    progress/<cell id>.json                                           a running cell's last epoch (see .progress)
    run.json, leaderboard.csv, summary.csv, report.md, plots/*.png

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
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .._files import atomic_write_text, open_temporary, torn_temporaries
from ..errors import ConfigError

# The table maths lives in .tables; its names stay importable from here for code written against the old layout.
from .tables import (
    LEADERBOARD_COLUMNS,
    SUMMARY_COLUMNS,
    TIMING_COLUMNS,
    leaderboard_rows,
    prefix_label,
    rows_to_csv,
    summary_rows,
)

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no claims; one process per --out
    fcntl = None  # type: ignore[assignment]

__all__ = ["atomic_write_text", "atomic_write_json", "RunDir", "Claim", "CellWriteError", "LEADERBOARD_COLUMNS",
           "SUMMARY_COLUMNS", "TIMING_COLUMNS", "leaderboard_rows", "summary_rows", "rows_to_csv", "prefix_label"]


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
    (predictions, probabilities, recordings) take a line each instead of a line per number, a fifth of the bytes."""
    def dump(value: Any, **kwargs: Any) -> str:
        return json.dumps(value, default=_json_default, allow_nan=True, **kwargs)

    if isinstance(obj, dict) and obj:
        body = ",\n".join(f" {dump(str(k))}: {dump(v, separators=(',', ':'))}" for k, v in obj.items())
        atomic_write_text(path, "{\n" + body + "\n}\n")
    else:
        atomic_write_text(path, dump(obj, indent=1) + "\n")


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
    def prepare(self) -> RunDir:
        """Create the folders and prove the location is writable; an unwritable ``--out`` is a ConfigError."""
        try:
            for folder in (self.path, self.cells_dir, self.claims_dir, self.progress_dir):
                folder.mkdir(parents=True, exist_ok=True)
            fd, probe = open_temporary(self.cells_dir / "probe")
            os.close(fd)
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f"--out {self.path}: cannot write there ({exc.strerror or exc}); choose a writable "
                              f"folder") from None
        return self

    # ------------------------------------------------------------------------------------------- cells
    def cell_path(self, cell_id: str) -> Path:
        return self.cells_dir / f"{cell_id}.json"

    def read_cell(self, cell_id: str) -> dict[str, Any] | None:
        return self._read(self.cell_path(cell_id))

    @staticmethod
    def _read(path: Path) -> dict[str, Any] | None:
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None  # absent, or not ours: it will be recomputed and replaced
        return record if isinstance(record, dict) and "cell_id" in record and "status" in record else None

    def cells(self) -> dict[str, dict[str, Any]]:
        """Every readable cell record in the folder, by cell id."""
        out = {}
        if self.cells_dir.is_dir():
            for path in sorted(self.cells_dir.glob("*.json")):
                record = self._read(path)
                if record is not None:
                    out[record["cell_id"]] = record
        return out

    def write_cell(self, record: dict[str, Any]) -> Path:
        path = self.cell_path(record["cell_id"])
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
        fd = os.open(self.path / "run.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)
