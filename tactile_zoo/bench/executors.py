"""Where cells run: in this process, in local worker processes, or on a Dask cluster.

The runner talks to every executor the same way: :meth:`Executor.submit` a :class:`~.cell.CellTask`, get a future;
:meth:`Executor.wait` for at least one to finish; ``future.result()`` is the cell's record. Records travel back to the
runner, which alone writes files, so workers (on other machines, for Dask) never need the output folder; they only
need the package, the plugin modules and the data home (``--root``) at the same path.

Seeding is per cell (model initialisation, dropout and batch order depend only on the cell's seed), and every
executor runs a cell with the same number of torch threads, ``--threads`` (default 1): on CPU the result of a
convolution or matrix product depends on how many threads split it, so a thread count that followed the executor
(all cores in-process, cores / workers in a pool) would make the same cell differ between a local and a distributed
run. With one thread per cell, local, process and dask runs give identical numbers for the same seeds; parallelism
comes from running cells side by side (``--executor process --workers N``, or a Dask cluster).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import sys
from typing import Any

from ..engine.runtime import cpu_count
from ..errors import ConfigError
from .cell import CellTask, run_cell, setup_worker

__all__ = ["Executor", "LocalExecutor", "ProcessExecutor", "DaskExecutor", "make_executor", "DEFAULT_THREADS"]

#: torch threads per cell unless --threads says otherwise (see the module docstring)
DEFAULT_THREADS = 1


class Executor:
    """Runs cells; ``slots`` is how many may be in flight at once."""

    name = "executor"
    slots = 1
    threads: int | None = None

    def submit(self, task: CellTask) -> Any:
        raise NotImplementedError

    def wait(self, futures: list[Any]) -> list[Any]:
        """Block until at least one of ``futures`` is done; return the done ones."""
        done, _ = cf.wait(futures, return_when=cf.FIRST_COMPLETED)
        return list(done)

    def result(self, future: Any) -> dict[str, Any]:
        return future.result()

    def shutdown(self, cancel: bool = False) -> None:
        pass

    def describe(self) -> str:
        return self.name


class LocalExecutor(Executor):
    """One cell at a time in this process (epoch progress bars are shown here only)."""

    name = "local"

    def __init__(self, threads: int | None = None, progress: bool = False) -> None:
        import torch

        self.threads, self.progress = threads or DEFAULT_THREADS, progress
        self._caller_threads = torch.get_num_threads()  # restored afterwards: this is the caller's process

    def submit(self, task: CellTask) -> cf.Future:
        future: cf.Future = cf.Future()
        future.set_result(run_cell(task, progress=self.progress))  # KeyboardInterrupt propagates from here
        return future

    def shutdown(self, cancel: bool = False) -> None:
        import torch

        if torch.get_num_threads() != self._caller_threads:
            torch.set_num_threads(self._caller_threads)

    def describe(self) -> str:
        return f"local ({self.threads} thread{'s' if self.threads > 1 else ''})"


def _init_process_worker(plugin_modules: tuple[str, ...], threads: int, sys_path: tuple[str, ...]) -> None:
    os.environ["OMP_NUM_THREADS"] = str(threads)
    setup_worker(plugin_modules, threads, sys_path)


class ProcessExecutor(Executor):
    """``workers`` local processes (spawned, so no thread pool state is forked), ``threads`` torch threads each.

    A worker that dies (killed by the OS for memory, a segfault in an extension) fails the cells it held; the pool
    is rebuilt for the remaining cells.
    """

    name = "process"

    def __init__(self, workers: int | None, threads: int | None, plugin_modules: tuple[str, ...]) -> None:
        cores = cpu_count()
        self.workers = workers or max(1, min(cores, 4))
        self.threads = threads or DEFAULT_THREADS
        self.slots = self.workers
        self._args = (tuple(plugin_modules), self.threads, tuple(sys.path))
        self._pool = self._new_pool()

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=_init_process_worker, initargs=self._args)

    def submit(self, task: CellTask) -> cf.Future:
        try:
            return self._pool.submit(run_cell, task)
        except cf.process.BrokenProcessPool:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            return self._pool.submit(run_cell, task)

    def result(self, future: cf.Future) -> dict[str, Any]:
        return future.result()

    def shutdown(self, cancel: bool = False) -> None:
        self._pool.shutdown(wait=not cancel, cancel_futures=cancel)

    def describe(self) -> str:
        return f"process ({self.workers} workers x {self.threads} thread{'s' if self.threads > 1 else ''})"


def _check_reachable(address: str) -> None:
    """Fail in a second on a refused ``tcp://HOST:PORT`` instead of waiting out the Dask connect timeout."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme != "tcp" or not parts.hostname or not parts.port:
        return  # other transports (tls, inproc, ucx): let Dask decide
    try:
        socket.create_connection((parts.hostname, parts.port), timeout=10).close()
    except OSError as exc:
        raise ConfigError(f"--scheduler {address}: cannot connect to the Dask scheduler: "
                          f"{exc.strerror or exc}") from None


def _dask_task(task: CellTask) -> dict[str, Any]:
    return run_cell(task)


class DaskExecutor(Executor):
    """Cells as tasks on a Dask distributed cluster: ``scheduler`` (``tcp://HOST:PORT``), or without one a
    ``LocalCluster`` of ``workers`` processes with one thread each (dask-jobqueue's SLURM/PBS clusters expose a
    scheduler address the same way)."""

    name = "dask"

    def __init__(self, scheduler: str | None, workers: int | None, threads: int | None,
                 plugin_modules: tuple[str, ...]) -> None:
        try:
            import distributed
        except ImportError:
            raise ConfigError("--executor dask needs the optional dependency: pip install 'tactile-zoo[dask]'") \
                from None
        self._distributed = distributed
        self._cluster = None
        try:
            if scheduler:
                _check_reachable(scheduler)
                self._client = distributed.Client(scheduler, timeout="30s")
            else:
                import logging

                n = workers or max(1, min(cpu_count(), 4))
                self._cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                         dashboard_address=None, silence_logs=logging.ERROR)
                self._client = distributed.Client(self._cluster)
        except OSError as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect to the Dask scheduler: {exc}") from None
        nthreads = self._client.nthreads()
        self.slots = max(1, sum(nthreads.values()))
        self.threads = threads or DEFAULT_THREADS
        self._plugins = tuple(plugin_modules)
        self.address = self._client.scheduler.address

    def submit(self, task: CellTask) -> Any:
        return self._client.submit(_dask_task, task, key=f"cell-{task.cell_id}-{os.getpid()}", pure=False)

    def wait(self, futures: list[Any]) -> list[Any]:
        done, _ = self._distributed.wait(futures, return_when="FIRST_COMPLETED")
        return list(done)

    def result(self, future: Any) -> dict[str, Any]:
        return future.result()

    def shutdown(self, cancel: bool = False) -> None:
        try:
            self._client.close()
        finally:
            if self._cluster is not None:
                self._cluster.close()

    def describe(self) -> str:
        return f"dask ({self.address}, {self.slots} worker threads)"


def make_executor(kind: str, *, workers: int | None = None, threads: int | None = None, scheduler: str | None = None,
                  plugin_modules: tuple[str, ...] = (), progress: bool = False) -> Executor:
    if kind == "local":
        return LocalExecutor(threads, progress)
    if kind == "process":
        return ProcessExecutor(workers, threads, plugin_modules)
    if kind == "dask":
        return DaskExecutor(scheduler, workers, threads, plugin_modules)
    raise ConfigError(f"unknown executor {kind!r}")
