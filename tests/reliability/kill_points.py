"""Stop points for the SIGKILL tests, imported by a bench subprocess through ``--plugin-module kill_points``.

A test cannot kill a process "in the middle of writing summary.csv" by timing: the window is microseconds wide and
the machine is shared. Instead the test sets ``TZ_RELIABILITY_STOP=<point>:<n>`` and ``TZ_RELIABILITY_SIGNAL=<file>``;
when the bench reaches that point this module writes the signal file and then blocks, so the test's SIGKILL lands
exactly there. With ``TZ_RELIABILITY_GO=<file>`` the process resumes when that file appears instead (the
two-processes test). Points:

    cell:N       the N-th cell of this process has been computed; its record is not written yet (claim held)
    claim:N      before taking the N-th cell claim of this process (between cells)
    cellwrite:N  half of the N-th cell file of this process is in its temporary file (a torn write)
    table:NAME   half of report table NAME (leaderboard.csv, summary.csv, report.md) is in its temporary file

Without ``TZ_RELIABILITY_STOP`` importing this module changes nothing.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

from tactile_zoo.bench import executors, report
from tactile_zoo.bench import rundir as results

STOP = os.environ.get("TZ_RELIABILITY_STOP", "")
SIGNAL = os.environ.get("TZ_RELIABILITY_SIGNAL", "")
GO = os.environ.get("TZ_RELIABILITY_GO", "")
_counts: dict[str, int] = {}


def _stop_here() -> None:
    """Announce the point, then wait to be killed (or for the GO file)."""
    Path(SIGNAL).write_text(f"{os.getpid()}\n")
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if GO and Path(GO).exists():
            return
        time.sleep(0.02)
    raise SystemExit(f"kill_points: nobody killed pid {os.getpid()} at {STOP}")


def _nth(point: str) -> bool:
    _counts[point] = _counts.get(point, 0) + 1
    kind, _, arg = STOP.partition(":")
    return kind == point and arg.isdigit() and _counts[point] == int(arg)


def _torn_write(path: Path, text: str) -> None:
    """What a SIGKILL in the middle of ``atomic_write_text`` leaves: a half-written temporary file."""
    fd, _ = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        fh.write(text[: len(text) // 2])
        fh.flush()


def _install() -> None:
    kind = STOP.partition(":")[0]
    if kind == "cell":
        real_cell = executors.run_cell

        def run_cell(task: Any, progress: bool = False) -> dict:
            record = real_cell(task, progress)
            if _nth("cell"):
                _stop_here()
            return record

        executors.run_cell = run_cell
    elif kind == "claim":
        real_claim = results.RunDir.claim

        def claim(self: results.RunDir, cell_id: str, blocking: bool = False) -> Any:
            if _nth("claim"):
                _stop_here()
            return real_claim(self, cell_id, blocking)

        results.RunDir.claim = claim
    elif kind == "cellwrite":
        real_text = results.atomic_write_text

        def cell_text(path: Any, text: str) -> None:
            path = Path(path)
            if path.parent.name == "cells" and _nth("cellwrite"):
                _torn_write(path, text)
                _stop_here()
            real_text(path, text)

        results.atomic_write_text = cell_text
    elif kind == "table":
        real_table = report.atomic_write_text

        def table_text(path: Any, text: str) -> None:
            path = Path(path)
            if f"table:{path.name}" == STOP:
                _torn_write(path, text)
                _stop_here()
            real_table(path, text)

        report.atomic_write_text = table_text
    elif STOP:
        raise SystemExit(f"kill_points: unknown stop point {STOP!r}")


_install()
