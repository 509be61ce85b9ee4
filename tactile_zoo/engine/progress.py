"""Progress of a long task: a live bar on a terminal, log lines when stderr is not one, nothing when turned off.

One rule for every command that can run for more than a few seconds (``train``, ``evaluate``, ``export``,
``stream``, ``bench``) and for the Python API (``tz.fit``, ``tz.evaluate``, ``export_model``, ``replay``):

- stderr is a terminal (or the code runs in a Jupyter notebook): a tqdm bar, cleared when the task ends;
- stderr is not a terminal (piped, redirected to a file, a CI log): INFO records on the ``tactile_zoo.progress``
  logger instead of a bar, which would fill a log with carriage returns: one per epoch or file, and for fine units
  (batches, frames) at most one every :data:`LOG_SECONDS` plus the last. The command line prints them on stderr; in
  a Python program they appear once the program configures logging (``logging.basicConfig(level="INFO")``), as a
  library's INFO records do;
- ``progress=False`` (the command line's ``-q``): nothing.

The Python API defaults to ``progress=True``, so an interactive session (a terminal, a notebook) sees a bar and a
script whose stderr goes to a file gets no control characters in it.

This module sits in the engine so that the engine's loops can report without importing the harness; the harness's
display of running cells (:mod:`tactile_zoo.bench.progress`) builds its bars with :func:`make_bar` too.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from typing import Any, TextIO

__all__ = ["Progress", "make_bar", "interactive", "format_seconds", "LOG_SECONDS"]

logger = logging.getLogger("tactile_zoo.progress")

#: the shortest interval between two log lines of a task counted in fine units (batches, frames)
LOG_SECONDS = 5.0


def format_seconds(seconds: float | None) -> str:
    """``4s``, ``1m15s``, ``1h02m``; ``?`` for ``None``."""
    if seconds is None:
        return "?"
    seconds = max(0, int(round(seconds)))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


def _in_notebook() -> bool:
    shell = sys.modules.get("IPython")
    try:
        ip = shell.get_ipython() if shell is not None else None  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001 - an IPython that cannot say: not a notebook
        return False
    return ip is not None and "IPKernelApp" in getattr(ip, "config", {})


def interactive(stream: TextIO | None = None) -> bool:
    """Whether a person watches ``stream`` (default ``sys.stderr``) live: a terminal, or a notebook's cell."""
    stream = sys.stderr if stream is None else stream
    try:
        if stream.isatty():
            return True
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False
    return stream in (sys.__stderr__, sys.stderr) and _in_notebook()


def make_bar(total: int | None, desc: str, unit: str, stream: TextIO | None = None, **kwargs: Any) -> Any:
    """A tqdm bar on ``stream`` (default ``sys.stderr``), cleared when closed (``leave=False`` unless given).

    A terminal that reports a size of 0 x 0 (``script``, ``docker exec -t``, some CI pseudo-terminals) made tqdm
    hide every bar: it treats the bar as below the last row. Such a size is replaced by 80 x 24.
    """
    from tqdm.auto import tqdm

    stream = sys.stderr if stream is None else stream
    try:
        columns, rows = os.get_terminal_size(stream.fileno())
    except (AttributeError, ValueError, OSError):
        columns, rows = 80, 24
    if not rows or not columns:
        kwargs.setdefault("nrows", rows or 24)
        kwargs.setdefault("ncols", columns or 80)
    else:
        kwargs.setdefault("dynamic_ncols", True)
    kwargs.setdefault("leave", False)
    return tqdm(total=total, desc=desc, unit=unit, file=stream, **kwargs)


class Progress:
    """One task's progress (module docstring): ``update()`` after each unit, ``close()`` at the end (or ``with``).

    Args:
        total: the number of units, or ``None`` when unknown.
        desc: what runs, e.g. ``"train sgnet on sim_evtouch"``; the bar's label and each log line's start.
        unit: the unit's plural name, e.g. ``"epochs"``, ``"batches"``, ``"files"``.
        enabled: ``False``: nothing at all.
        log_every: seconds between two log lines (0: a line per unit); the last unit always gets its line.
        stream: where a bar goes (default ``sys.stderr`` when the task starts).
    """

    def __init__(self, total: int | None, desc: str, unit: str, *, enabled: bool = True, log_every: float = 0.0,
                 stream: TextIO | None = None) -> None:
        self.total, self.desc, self.unit, self.log_every = total, desc, unit, log_every
        self.n = 0
        self.started = self.logged = time.perf_counter()
        self.mode = "off" if not enabled else "bar" if interactive(stream) else "log"
        self.bar = make_bar(total, desc, unit, stream) if self.mode == "bar" else None

    def update(self, n: int = 1, note: str = "") -> None:
        """``n`` more units are done; ``note`` (e.g. ``"loss 0.41 val_acc 0.62"``) goes next to the count."""
        self.n += n
        if self.bar is not None:
            if note:
                self.bar.set_postfix_str(note, refresh=not n)  # update(0) draws nothing by itself
            self.bar.update(n)
            return
        if self.mode != "log":
            return
        now = time.perf_counter()
        last = self.total is not None and self.n >= self.total
        if last or now - self.logged >= self.log_every:
            self.logged = now
            count = f"{self.n}/{self.total}" if self.total is not None else str(self.n)
            logger.info("%s: %s %s%s (%s)", self.desc, count, self.unit, f", {note}" if note else "",
                        format_seconds(now - self.started))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
