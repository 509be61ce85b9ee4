"""SIGTERM handled like Ctrl-C: the commands that clean up after an interruption (``bench``, ``export``) do the same
after ``kill``, a batch system's time limit or a container's stop.

Python turns SIGINT into :class:`KeyboardInterrupt`, which every cleanup path of the package already handles
(``except KeyboardInterrupt``, ``except BaseException``, ``finally``); SIGTERM's default action ends the process on
the spot, leaving progress files, staging folders and the pool's semaphores behind. Inside
:func:`terminate_as_interrupt` SIGTERM raises :class:`Terminated`, a ``KeyboardInterrupt``, so the same paths run;
a command then exits 143 (128 + SIGTERM, what a shell reports for a process SIGTERM ended) instead of Ctrl-C's 130.

This module sits at the bottom of the import layers (beside :mod:`tactile_zoo._files`) so every layer can use it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

__all__ = ["Terminated", "terminate_as_interrupt", "TERMINATED_EXIT"]

#: The exit status of a command SIGTERM stopped (128 + 15).
TERMINATED_EXIT = 128 + 15


class Terminated(KeyboardInterrupt):  # noqa: N818 - a signal, as KeyboardInterrupt is
    """SIGTERM arrived: raised in the main thread, where Ctrl-C raises ``KeyboardInterrupt``."""

    exit_code = TERMINATED_EXIT


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (once: a second SIGTERM while the
    first one's cleanup runs is ignored; SIGKILL still ends the process).

    Nothing changes outside the main thread (only it may set handlers) or where SIGTERM already has a handler of the
    caller's, or is ignored: a host that set its own keeps it. The previous handler is restored when the block ends.
    """
    sigterm = getattr(signal, "SIGTERM", None)
    if sigterm is None or threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(sigterm) is not signal.SIG_DFL:
        yield
        return
    raised = False

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal raised
        if raised:
            return
        raised = True
        raise Terminated("terminated (SIGTERM)")

    signal.signal(sigterm, handler)
    try:
        yield
    finally:
        signal.signal(sigterm, signal.SIG_DFL)
