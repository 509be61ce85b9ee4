"""Bench children without an interpreter's start-up, for the tests that SIGKILL a bench at some point of its run.

A ``python -m tactile_zoo.cli bench`` child spends about 6 CPU seconds importing before its first cell ends: torch
and the package, then torch._dynamo (the first Adam optimizer) and sklearn.metrics (the first evaluation). A test
that kills five such children pays that five times. :func:`fork_bench` forks each child instead from a
:mod:`multiprocessing` fork server that has imported those modules once per test process (:data:`PRELOAD`; the
server imports nothing else, runs no torch op and has one thread, so forking it is safe). The child then runs the
command line through ``tactile_zoo.cli.main``, as ``python -m tactile_zoo.cli`` does, with ``env`` set first, so a
plugin module such as tests/reliability/kill_points.py is imported fresh under it. It is a process of its own, with
its own pid, claims and files: SIGKILL ends it where it is (exit status -9), and what it wrote stays written.

A forked child has the signal dispositions of a new interpreter (SIGINT raises ``KeyboardInterrupt``, SIGTERM and
SIGQUIT are the defaults) and, when ``PYTHONFAULTHANDLER`` is set, faulthandler on, so the tests of SIGINT and
SIGTERM use it too (tests/bench/test_process_faults.py). :func:`fork_python` runs a script as ``python -c`` would.
:func:`dask_forkserver` lets the Dask nannies of a ``LocalCluster`` in the test process fork their worker processes
from the same server. The tests of how a bench's own workers *start* keep the processes the product spawns.
"""

from __future__ import annotations

import contextlib
import faulthandler
import multiprocessing
import multiprocessing.forkserver
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

#: what a bench child imports before its first cell is written
PRELOAD = ["tactile_zoo.cli", "tactile_zoo.bench.runner", "tactile_zoo.bench.worker", "tactile_zoo.bench.report",
           "tiny_zoo", "torch._dynamo", "sklearn.metrics"]


class ForkedBench:
    """A forked bench child, with the part of :class:`subprocess.Popen`'s interface the tests use; its stdout and
    stderr are in ``<log>.out`` and ``<log>.err``."""

    def __init__(self, process: multiprocessing.process.BaseProcess, log: Path) -> None:
        self.process, self.log, self.pid = process, log, process.pid

    @property
    def returncode(self) -> int | None:
        return self.process.exitcode

    def poll(self) -> int | None:
        return self.process.exitcode

    def kill(self) -> None:
        if self.process.exitcode is None:
            self.process.kill()

    def send_signal(self, sig: int) -> None:
        os.kill(self.pid, sig)

    def wait(self, timeout: float | None = None) -> int:
        self.process.join(timeout)
        if self.process.exitcode is None:
            raise subprocess.TimeoutExpired(f"bench child {self.pid}", timeout or 0.0)
        return self.process.exitcode

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Wait for the child (as Popen does: :class:`subprocess.TimeoutExpired` if it runs on), then what it
        printed."""
        self.wait(timeout)
        return self.log.with_suffix(".out").read_text(), self.log.with_suffix(".err").read_text()


def _child_setup(log: str, env: dict[str, str]) -> None:
    """In the forked child: SIGINT, SIGTERM and SIGQUIT as a fresh interpreter has them, ``env``, stdout and stderr
    to the log files, faulthandler as ``PYTHONFAULTHANDLER`` asks, and a resource tracker of its own."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)
    os.environ.update(env)
    for fd, suffix in ((1, ".out"), (2, ".err")):
        target = os.open(Path(log).with_suffix(suffix), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(target, fd)
        os.close(target)
    sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115 - the process ends below
    sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
    # a resource tracker of its own, started on first use, as a new interpreter has: the semaphores of a child that
    # is killed are then reported (and removed) by its tracker, into its own stderr, not by the test process's at exit
    from multiprocessing import resource_tracker

    tracker = resource_tracker._resource_tracker
    if tracker._fd is not None:
        os.close(tracker._fd)
    tracker._fd = tracker._pid = None
    if os.environ.get("PYTHONFAULTHANDLER"):  # SIGABRT then prints every thread's stack (conftest.hung_stacks)
        faulthandler.enable()


def _bench_child(argv: list[str], log: str, env: dict[str, str]) -> None:
    """In the forked child: :func:`_child_setup`, then ``tactile-zoo ARGV``; the process ends with its exit code.

    It ends as an interpreter does (``SystemExit``: :mod:`multiprocessing` runs its exit functions, so the
    semaphores of a pool that was shut down are released, not reported leaked by the resource tracker)."""
    _child_setup(log, env)
    from tactile_zoo.cli import main

    sys.exit(main(argv))


def _python_child(source: str, argv: list[str], log: str, env: dict[str, str]) -> None:
    """In the forked child: :func:`_child_setup`, then ``source`` as ``python -c SOURCE ARGV`` runs it."""
    _child_setup(log, env)
    sys.argv = ["-c", *argv]
    exec(compile(source, "<string>", "exec"), {"__name__": "__main__"})  # noqa: S102 - the test's own script


def _server() -> multiprocessing.context.BaseContext:
    """The fork server, started on first use with one BLAS/OpenMP thread (so it has no thread to fork past)."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    saved = os.environ.get("OMP_NUM_THREADS")
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        if saved is None:
            del os.environ["OMP_NUM_THREADS"]
        else:
            os.environ["OMP_NUM_THREADS"] = saved
    return context


def fork_bench(argv: list[str], log: Path, **env: str) -> ForkedBench:
    """``tactile-zoo ARGV`` (e.g. ``["bench", "--plugin-module", "tiny_zoo", ...]``) in a child forked from the warm
    server, with ``env`` added to its environment (and ``OMP_NUM_THREADS=1``, as the suite's children have)."""
    process = _server().Process(target=_bench_child, args=(list(argv), str(log), {"OMP_NUM_THREADS": "1", **env}),
                                name=f"bench-{Path(log).name}")
    process.start()
    return ForkedBench(process, Path(log))


def fork_python(source: str, argv: list[str], log: Path, **env: str) -> ForkedBench:
    """``python -c SOURCE ARGV`` in a child forked from the warm server (the package already imported), with ``env``
    added to its environment; its stdout and stderr are in ``<log>.out`` and ``<log>.err``."""
    process = _server().Process(target=_python_child, args=(source, list(argv), str(log),
                                                            {"OMP_NUM_THREADS": "1", **env}),
                                name=f"python-{Path(log).name}")
    process.start()
    return ForkedBench(process, Path(log))


def finish_python(source: str, argv: list[str], log: Path, timeout: float = 300, **env: str) -> tuple[int, str, str]:
    """:func:`fork_python` run to its end: its exit status, stdout and stderr; a child still running after
    ``timeout`` seconds is killed (:class:`subprocess.TimeoutExpired`)."""
    child = fork_python(source, argv, log, **env)
    try:
        status = child.wait(timeout=timeout)
    finally:
        child.kill()
    return (status, *child.communicate())


def run_python(source: str, argv: list[str], log: Path, timeout: float = 300, **env: str) -> tuple[str, str]:
    """:func:`finish_python` of a child that must exit 0 (its stderr is the failure message): its stdout and
    stderr."""
    status, out, err = finish_python(source, argv, log, timeout, **env)
    assert status == 0, err
    return out, err



def package_from(root: Path) -> str:
    """The first lines of a :func:`fork_python` source that runs in ``root`` with ``root``'s own ``tactile_zoo`` (a
    copy of the project, another commit's tree) in place of the checkout's, which the server imported: the child
    forgets that package, ``tools`` and the modules importing them, then imports ``root``'s, as a new interpreter
    with ``PYTHONPATH=root`` would (torch and the other libraries stay imported)."""
    return f"""
import os, sys
os.chdir({str(root)!r})
for name in [m for m in sys.modules if m.split(".")[0] in ("tactile_zoo", "tools", "tiny_zoo", "conftest")]:
    del sys.modules[name]
sys.path.insert(0, {str(root)!r})
import tactile_zoo
assert tactile_zoo.__file__.startswith({str(root) + os.sep!r}), f"not {str(root)}: {{tactile_zoo.__file__}}"
"""

@contextlib.contextmanager
def dask_forkserver() -> Iterator[None]:
    """Within the block, the Dask nannies this process starts (``LocalCluster(processes=True)``, also the one
    ``--executor dask`` starts) fork their worker processes from the warm server (Dask's ``forkserver`` method)
    instead of spawning new interpreters that import torch and the package on their first cell. The server is
    started first, so Dask's own preload list (set on its first use of the method) never replaces :data:`PRELOAD`."""
    import dask

    _server()
    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        yield
