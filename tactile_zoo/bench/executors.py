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

Under Dask, a cell whose worker dies (killed for memory, a lost node) is rescheduled by the scheduler up to its
``allowed-failures`` times (Dask's default 3; ``--retries N`` sets it for this run); the scheduler's count of lost
workers gives the record's ``attempts``. Dask's per-task ``retries=`` is not used: it re-runs tasks that *raise*, and
a cell never raises for a problem of its own (that is a recorded failure, which a rerun would only repeat).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import importlib
import logging
import multiprocessing
import os
import sys
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..engine.runtime import cpu_count
from ..errors import ConfigError
from .progress import listening
from .worker import CellTask, run_cell, setup_worker

logger = logging.getLogger(__name__)

__all__ = ["Executor", "LocalExecutor", "ProcessExecutor", "DaskExecutor", "make_executor", "DEFAULT_THREADS",
           "pool_size", "check_workers"]

#: torch threads per cell unless --threads says otherwise (see the module docstring)
DEFAULT_THREADS = 1


def pool_size(requested: int | None, cells: int | None, threads: int | None = None) -> int:
    """How many worker processes a local pool (``process``, or ``dask`` without a scheduler) starts: ``--workers``
    (default: the cores, at most 4), never more than the ``cells`` to run, since an idle worker only holds memory.
    Above the cores (counting ``threads`` per worker) it says so in one warning line: the cells then compete for
    them. ``cells=None``: not capped, no warning."""
    n = requested or max(1, min(cpu_count(), 4))
    if cells is None:
        return n
    n = max(1, min(n, cells))
    busy, cores = n * (threads or DEFAULT_THREADS), cpu_count()
    if busy > cores:
        logger.warning("%d worker process(es) x %d thread(s) = %d threads on %d core(s): the cells compete for the "
                       "cores and run slower each; --workers %d (or fewer) is what helps here", n,
                       threads or DEFAULT_THREADS, busy, cores, max(1, cores // (threads or DEFAULT_THREADS)))
    return n


def check_workers(kind: str, workers: int | None, threads: int | None, cells: int, remote: bool = False) -> None:
    """Refuse, before anything runs, a local pool whose processes x threads (workers capped at the grid's ``cells``)
    exceed :data:`~.config.OVERSUBSCRIPTION` times this machine's cores."""
    from .config import OVERSUBSCRIPTION

    if kind == "local" or remote or workers is None:
        return
    n, per = max(1, min(workers, cells)), threads or DEFAULT_THREADS
    cap = OVERSUBSCRIPTION * cpu_count()
    if n * per > cap:
        raise ConfigError(f"--workers {workers}: {n} worker process(es) x {per} thread(s) for {cells} cell(s) is "
                          f"{n * per} threads; at most {cap} ({OVERSUBSCRIPTION} x the {cpu_count()} core(s) of this "
                          f"machine; more only slow every cell down)")


class Executor:
    """Runs cells; ``slots`` is how many may be in flight at once."""

    name = "executor"
    slots = 1
    threads: int | None = None

    def submit(self, task: CellTask) -> Any:
        raise NotImplementedError

    def wait(self, futures: list[Any], timeout: float | None = None) -> list[Any]:
        """Block until at least one of ``futures`` is done, or ``timeout`` seconds; return the done ones."""
        done, _ = cf.wait(futures, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return list(done)

    def result(self, future: Any) -> dict[str, Any]:
        return future.result()

    def attempts(self, future: Any) -> int | None:
        """How many times the cell of a done ``future`` was started (more than 1: its worker died and it was
        rescheduled); ``None`` when unknown."""
        return 1

    def abandon(self) -> None:
        """Stop the cells in flight now (the run was interrupted): once this returns, none of them writes anything
        more, so the runner can mark them as no longer running. Executors that cannot stop a running cell (Dask:
        a worker thread cannot be interrupted) do nothing."""

    def shutdown(self, cancel: bool = False) -> None:
        pass

    def describe(self) -> str:
        return self.name


class LocalExecutor(Executor):
    """One cell at a time in this process. ``listener`` (the runner's display) is called after each epoch, since
    the runner itself is blocked in :meth:`submit` while the cell runs."""

    name = "local"

    def __init__(self, threads: int | None = None, progress: bool = False) -> None:
        import torch

        self.threads, self.progress = threads or DEFAULT_THREADS, progress
        self.listener: Callable[[dict[str, Any]], None] | None = None
        self._caller_threads = torch.get_num_threads()  # restored afterwards: this is the caller's process

    def submit(self, task: CellTask) -> cf.Future:
        future: cf.Future = cf.Future()
        with listening(self.listener):
            future.set_result(run_cell(task, progress=self.progress))  # KeyboardInterrupt propagates from here
        return future

    def shutdown(self, cancel: bool = False) -> None:
        import torch

        if torch.get_num_threads() != self._caller_threads:
            torch.set_num_threads(self._caller_threads)

    def describe(self) -> str:
        return f"local ({self.threads} thread{'s' if self.threads > 1 else ''})"


#: How often a pool worker checks that the run that started it is still alive (seconds).
PARENT_POLL_S = 1.0


def _exit_with_parent(parent: int) -> None:
    """Leave as soon as ``parent`` is no longer this process's parent (it died, and the process was re-parented).

    A killed ``tactile-zoo bench`` (SIGKILL, an out-of-memory kill, a closed session) cannot shut its pool down, and
    its workers would go on training cells whose records nobody will write, holding cores a resumed run needs.
    Polling ``os.getppid()`` from a daemon thread works on every platform, unlike Linux's ``PR_SET_PDEATHSIG``.
    """
    import threading
    import time

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)  # no cleanup to run: the cell's record was never going to be written

    threading.Thread(target=watch, name="tactile-zoo-parent-watch", daemon=True).start()


def _init_process_worker(plugin_modules: tuple[str, ...], threads: int, sys_path: tuple[str, ...],
                         parent: int) -> None:
    os.environ["OMP_NUM_THREADS"] = str(threads)
    _exit_with_parent(parent)
    setup_worker(plugin_modules, threads, sys_path)


class ProcessExecutor(Executor):
    """``workers`` local processes (spawned, so no thread pool state is forked), ``threads`` torch threads each.

    A worker that dies (killed by the OS for memory, a segfault in an extension) fails the cells it held; the pool
    is rebuilt for the remaining cells. A worker whose run died exits within about a second
    (:func:`_exit_with_parent`).
    """

    name = "process"

    def __init__(self, workers: int | None, threads: int | None, plugin_modules: tuple[str, ...],
                 cells: int | None = None) -> None:
        self.workers = pool_size(workers, cells, threads)
        self.threads = threads or DEFAULT_THREADS
        self.slots = self.workers
        self._args = (tuple(plugin_modules), self.threads, tuple(sys.path), os.getpid())
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

    def abandon(self) -> None:
        """Terminate the pool's workers and wait for them. A worker that did not get the Ctrl-C itself (``kill
        -INT`` of the run, or a run outside the terminal's foreground group) would go on training a cell whose
        record nobody writes, rewriting its progress file after the runner removed it, and the run could not exit
        before the cell ended: ``concurrent.futures`` joins its workers when the interpreter exits."""
        terminate = getattr(self._pool, "terminate_workers", None)  # Python 3.14
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        if terminate is not None:
            terminate()
        else:
            for process in processes:
                with contextlib.suppress(OSError, ValueError, AttributeError):
                    process.terminate()
        for process in processes:
            with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
                process.join(timeout=10)
                if process.is_alive():
                    process.kill()
                    process.join(timeout=5)
        self._pool.shutdown(wait=False, cancel_futures=True)

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


def _shipped_file(module_name: str, folder: Path) -> Path | None:
    """The file that carries plugin module ``module_name`` to remote workers: its top-level module's ``.py``, or its
    package zipped; ``None`` for an installed distribution (site-packages), which workers must install themselves."""
    top = module_name.partition(".")[0]
    module = sys.modules.get(top) or importlib.import_module(top)
    source = getattr(module, "__file__", None)
    if not source or any(part in ("site-packages", "dist-packages") for part in Path(source).parts):
        return None
    source_path = Path(source)
    if source_path.name != "__init__.py":
        return source_path if source_path.suffix == ".py" else None
    archive = folder / f"{top}.zip"
    with zipfile.ZipFile(archive, "w") as zf:  # a zip on a worker's sys.path imports like the package folder
        for path in sorted(source_path.parent.rglob("*.py")):
            zf.write(path, Path(top) / path.relative_to(source_path.parent))
    return archive


class DaskExecutor(Executor):
    """Cells as tasks on a Dask distributed cluster: ``scheduler`` (``tcp://HOST:PORT``), or without one a
    ``LocalCluster`` of ``workers`` processes with one thread each (dask-jobqueue's SLURM/PBS clusters expose a
    scheduler address the same way).

    - ``retries``: how often a cell whose worker died is rescheduled (the scheduler's ``allowed-failures``; ``None``
      keeps the scheduler's own setting). It is restored when the run ends.
    - ``device`` ``cuda``/``cuda:N``: each cell asks for the resource ``GPU=1``, so a worker started with
      ``--resources GPU=1`` runs one GPU cell at a time.
    - plugin modules are uploaded to every worker (also ones that join later) and imported there.
    - ``dashboard``: the local cluster's dashboard address (off by default).
    """

    name = "dask"

    def __init__(self, scheduler: str | None, workers: int | None, threads: int | None,
                 plugin_modules: tuple[str, ...], *, retries: int | None = None, device: str = "auto",
                 dashboard: str | None = None, cells: int | None = None) -> None:
        try:
            import distributed
        except ImportError:
            raise ConfigError("--executor dask needs the optional dependency: pip install 'tactile-zoo[dask]'") \
                from None
        self._distributed = distributed
        self._cluster = None
        self.gpu = str(device).startswith("cuda")
        try:
            if scheduler:
                _check_reachable(scheduler)
                self._client = distributed.Client(scheduler, timeout="30s")
            else:
                n = pool_size(workers, cells, threads)
                self._cluster = distributed.LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=dashboard,
                    silence_logs=logging.ERROR, resources={"GPU": 1} if self.gpu else None)
                self._client = distributed.Client(self._cluster)
        except OSError as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect to the Dask scheduler: {exc}") from None
        nthreads = self._client.nthreads()
        self.slots = max(1, sum(nthreads.values()))
        self.threads = threads or DEFAULT_THREADS
        self._plugins = tuple(plugin_modules)
        self.address = self._client.scheduler.address
        self.dashboard = self._client.dashboard_link if dashboard else None
        self._restore_failures: int | None = None
        self.retries = self._set_retries(retries)
        self._ship_plugins()
        if self.gpu:
            self._check_gpu_workers()

    # -------------------------------------------------------------------------------------------- set-up
    def _set_retries(self, retries: int | None) -> int | None:
        """Set (or read) the scheduler's ``allowed_failures``; functions defined here travel by value, so the
        scheduler needs neither tactile-zoo nor torch."""

        def swap(value: int | None, dask_scheduler: Any = None) -> int:
            old = dask_scheduler.allowed_failures
            if value is not None:
                dask_scheduler.allowed_failures = value
            return old

        try:
            old = self._client.run_on_scheduler(swap, retries)
        except Exception as exc:  # noqa: BLE001 - a scheduler refusing pickled functions: keep its setting
            if retries is not None:
                logger.warning("cannot set the Dask scheduler's allowed-failures to %s (%s); it keeps its own",
                               retries, exc)
            return None
        if retries is None:
            return int(old)
        self._restore_failures = int(old)
        return retries

    def _ship_plugins(self) -> None:
        if not self._plugins:
            return
        from distributed.diagnostics.plugin import UploadFile

        with tempfile.TemporaryDirectory(prefix="tactile-zoo-plugins-") as folder:
            for name in dict.fromkeys(m.partition(".")[0] for m in self._plugins):
                path = _shipped_file(name, Path(folder))
                if path is None:
                    logger.debug("plugin module %s is installed; the workers must have it too", name)
                    continue
                try:  # a worker plugin (not client.upload_file): the scheduler never imports torch or the module
                    self._client.register_plugin(UploadFile(str(path), load=True), name=f"tactile-zoo-{name}")
                except Exception as exc:  # noqa: BLE001 - the worker's own import error, reported as bad input
                    raise ConfigError(f"--plugin-module {name}: cannot be imported on the Dask workers: "
                                      f"{type(exc).__name__}: {exc}") from None
                logger.debug("shipped plugin module %s (%s) to the Dask workers", name, path.name)

    def _check_gpu_workers(self) -> None:
        workers = self._client.scheduler_info().get("workers", {})
        if not any((w.get("resources") or {}).get("GPU") for w in workers.values()):
            logger.warning("--device cuda: no Dask worker declares a GPU resource, so GPU cells wait until one "
                           "joins; start workers with `dask worker ... --resources GPU=1` (one per GPU)")

    # -------------------------------------------------------------------------------------------- cells
    def submit(self, task: CellTask) -> Any:
        return self._client.submit(_dask_task, task, key=f"cell-{task.cell_id}-{os.getpid()}", pure=False,
                                   resources={"GPU": 1} if self.gpu else None)

    def wait(self, futures: list[Any], timeout: float | None = None) -> list[Any]:
        try:
            done, _ = self._distributed.wait(futures, timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            return []
        return list(done)

    def result(self, future: Any) -> dict[str, Any]:
        try:
            return future.result()
        finally:
            # the record is here now: release the task at once, or the loss of the worker that still holds the
            # result would make the scheduler recompute the whole cell for nothing
            future.release()

    def attempts(self, future: Any) -> int | None:
        """From the scheduler: the task's count of workers lost while running it (its ``suspicious`` count)."""

        def count(key: Any, dask_scheduler: Any = None) -> tuple[str, int] | None:
            ts = dask_scheduler.tasks.get(key)
            return None if ts is None else (ts.state, ts.suspicious)

        try:
            found = self._client.run_on_scheduler(count, future.key)
        except Exception as exc:  # noqa: BLE001 - unknown is better than a failed run
            logger.debug("cannot read the attempts of %s: %s", future.key, exc)
            return None
        if found is None:
            return None
        state, lost = found
        return max(1, lost) if state == "erred" else lost + 1  # erred after a death: every run was lost

    def shutdown(self, cancel: bool = False) -> None:
        try:
            if self._restore_failures is not None:
                with contextlib.suppress(Exception):
                    self._client.run_on_scheduler(
                        lambda value, dask_scheduler=None: setattr(dask_scheduler, "allowed_failures", value),
                        self._restore_failures)
            self._client.close()
        finally:
            if self._cluster is not None:
                self._cluster.close()

    def describe(self) -> str:
        retries = "" if self.retries is None else f", retries {self.retries}"
        dashboard = f", dashboard {self.dashboard}" if self.dashboard else ""
        return f"dask ({self.address}, {self.slots} worker threads{retries}{dashboard})"


def make_executor(kind: str, *, workers: int | None = None, threads: int | None = None, scheduler: str | None = None,
                  plugin_modules: tuple[str, ...] = (), progress: bool = False, retries: int | None = None,
                  device: str = "auto", dashboard: str | None = None, cells: int | None = None) -> Executor:
    """The executor ``kind``; ``cells`` (the cells to run) caps a local pool's worker processes (:func:`pool_size`)."""
    if kind == "local":
        return LocalExecutor(threads, progress)
    if kind == "process":
        return ProcessExecutor(workers, threads, plugin_modules, cells)
    if kind == "dask":
        return DaskExecutor(scheduler, workers, threads, plugin_modules, retries=retries, device=device,
                            dashboard=dashboard, cells=cells)
    raise ConfigError(f"unknown executor {kind!r}")
