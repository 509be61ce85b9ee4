"""The bench run: resolve the grid, reuse finished cells, run the rest on an executor, write every output.

Resuming: a cell whose file exists with status ``ok`` or ``skipped`` is finished and never recomputed (``force``
recomputes); a ``failed`` cell is retried on the next run. A cell is written the moment it finishes, atomically, so a
run killed at any point (SIGKILL included) loses at most the cells that were running.

Exit codes: 0 every cell ok (or skipped), 1 a cell or a dataset failed or a file could not be written, 130
interrupted (Ctrl-C: running cells are abandoned, finished ones kept, the tables written for them), 143 the same
after SIGTERM.

Progress: every running cell writes its epochs to ``--out/progress/<cell id>.json`` (:mod:`.progress`); the runner
polls those files (every :data:`POLL_SECONDS`, and after each epoch of a cell it runs itself) and shows a live bar per
running cell on a terminal, else one ``logging`` line per epoch, with an ETA weighted by each cell's expected cost.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from .. import registry
from .._signals import Terminated, terminate_as_interrupt
from ..errors import ResultsError, TactileZooError
from .config import BenchConfig
from .environment import environment
from .executors import Executor, LocalExecutor, check_workers, make_executor
from .grid import Cell, Grid, build_grid, default_out_dir
from .progress import CostModel, ProgressDisplay, RunConsole, remove_progress
from .records import InvalidCell, move_aside, refuse_newer
from .rundir import BENCH_FORMAT, CellWriteError, Claim, RunDir, atomic_write_json
from .schema import RECORD_FORMAT, InvalidRecordError
from .teachers import check_teachers
from .worker import CellTask

logger = logging.getLogger(__name__)

__all__ = ["run_bench", "BenchOutcome", "FINISHED"]

FINISHED = ("ok", "skipped")  # statuses a rerun keeps; "failed" cells are retried
#: how often the runner reads the progress files of cells running in other processes
POLL_SECONDS = 1.0


@dataclass
class BenchOutcome:
    out: Path | None
    exit_code: int
    grid: Grid
    counts: dict[str, int] = field(default_factory=dict)
    ran: list[str] = field(default_factory=list)  # cell ids computed by this process
    reused: list[str] = field(default_factory=list)  # finished before (or by another process)


def _score(value: Any) -> str:
    return "–" if value is None else f"{value:.3f}"  # None: an empty split has no score (.schema)


def _cell_line(record: dict[str, Any], index: int, total: int) -> str:
    head = f"[{index}/{total}] {record['status']:<7} {record['model']} x {record['dataset']} fold {record['fold']} " \
           f"seed {record['seed']}"
    if record["status"] == "ok":
        tail = f"  {record['epochs_run']} ep (best {record['best_epoch']})  {record['train_seconds']:.1f}s"
        test = record["metrics"].get("test")
        if test is None:  # a tuning cell: the validation score is all there is
            return f"{head}: val acc {_score(record['metrics']['val']['accuracy'])} (test not read){tail}"
        return (f"{head}: acc {_score(test['accuracy'])} bal {_score(test.get('balanced_accuracy'))} "
                f"f1 {_score(test.get('macro_f1'))}{tail}")
    return f"{head}: {record.get('error')}"


def _task(cell: Cell, config: BenchConfig, executor: Executor, progress_dir: Path | None = None,
          weights_dir: Path | None = None, run_dir: Path | None = None) -> CellTask:
    tracker_dir = Path(config.tracker_dir) if config.tracker_dir else run_dir
    return CellTask(model=cell.model, dataset=cell.dataset, fold=cell.fold, seed=cell.seed,
                    config_hash=cell.config_hash, cell_id=cell.cell_id, config=cell.config, protocol=cell.protocol,
                    extra_splits=cell.extra_splits, root=config.root, download=config.download, device=config.device,
                    threads=executor.threads if executor.threads is not None else config.threads,
                    plugin_modules=tuple(config.plugin_modules), sys_path=tuple(sys.path),
                    progress_dir=str(progress_dir.resolve()) if progress_dir is not None else None,
                    commit=environment()["git_commit"],
                    weights_dir=str(weights_dir.resolve()) if weights_dir is not None else None,
                    tracker=config.tracker,
                    tracker_dir=str(tracker_dir.resolve()) if config.tracker and tracker_dir is not None else None,
                    teacher_dir=str(Path(config.teachers["folder"]).resolve()) if config.teachers else None)


def _run_json(run: RunDir, config: BenchConfig, grid: Grid, status: str, extra: dict[str, Any]) -> None:
    argv0 = os.path.basename(sys.argv[0]) if sys.argv else ""
    command = ["tactile-zoo", *sys.argv[1:]] if argv0 in ("tactile-zoo", "cli.py", "__main__.py") else list(sys.argv)
    payload = {"format": BENCH_FORMAT, "status": status, "command": command, "config": grid.settings,
               "out": str(run.path), "environment": environment(),
               "grid": {"models": grid.models, "datasets": [d.name for d in grid.datasets],
                        "cells": [c.cell_id for c in grid.cells], "skipped": [s.to_dict() for s in grid.skipped],
                        "dataset_notes": grid.dataset_notes}, **extra}
    with run.table_lock():
        run.remove_torn(run.path, "run.json")
        atomic_write_json(run.path / "run.json", payload)


def run_bench(config: BenchConfig, *, dry_run: bool = False, quiet: bool = False, out: TextIO | None = None,
              err: TextIO | None = None, report: bool = True, plots: bool = True, skip_invalid: bool = False
              ) -> BenchOutcome:
    """Run (or with ``dry_run`` only list) the grid ``config`` describes. Raises ConfigError for bad input.

    Damaged cell files in the folder (:mod:`.records`) are named on ``err``; those of the grid are moved to
    ``cells/damaged/`` and recomputed. Either way the exit code is 1 unless ``skip_invalid``. SIGTERM stops the run
    as Ctrl-C does (:mod:`tactile_zoo._signals`), with exit code 143."""
    with terminate_as_interrupt():
        return _run_bench(config, dry_run=dry_run, quiet=quiet, out=out, err=err, report=report, plots=plots,
                          skip_invalid=skip_invalid)


def _run_bench(config: BenchConfig, *, dry_run: bool, quiet: bool, out: TextIO | None, err: TextIO | None,
               report: bool, plots: bool, skip_invalid: bool) -> BenchOutcome:
    out, err = out or sys.stdout, err or sys.stderr
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())  # --plugin-module my_model finds ./my_model.py, as `python -m` would
    registry.import_plugin_modules(config.plugin_modules)
    grid = build_grid(config)
    check_workers(config.executor, config.workers, config.threads, len(grid.cells), config.remote)
    out_dir = Path(config.out) if config.out else default_out_dir(config, grid)
    if dry_run:
        for line in grid.describe():
            print(line, file=out)
        for cell in grid.cells:
            print(f"  cell {cell.cell_id}", file=out)
        print(f"output folder: {out_dir}", file=out)
        return BenchOutcome(out_dir, 0, grid)

    run = RunDir(out_dir)
    run.check_format()  # before anything is read or written (prepare checks again, for its other callers)
    scan = run.scan()
    refuse_newer(scan, f"--out {out_dir}")
    existing = scan.records  # prepare() writes no cell: the scan above still holds
    todo = [c for c in grid.cells if config.force or (existing.get(c.cell_id) or {}).get("status") not in FINISHED]
    if config.teachers:  # every teacher of every cell to run, before anything is written or trained
        check_teachers(config.teachers["folder"], todo)
    run.prepare()
    started = time.time()
    started_text = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    # a local pool starts no more workers than there are cells to run (and warns above the cores)
    executor = make_executor(config.executor, workers=config.workers, threads=config.threads,
                             scheduler=config.scheduler, plugin_modules=tuple(config.plugin_modules),
                             progress=False, retries=config.retries, device=config.device,
                             dashboard=config.dashboard, cells=len(todo))  # epochs are shown by the ProgressDisplay
    outcome = BenchOutcome(out_dir, 0, grid)
    status = "running"
    try:
        _run_json(run, config, grid, "running", {"started": started_text, "executor": executor.describe()})
        _name_damaged(scan.invalid, {c.cell_id for c in grid.cells}, skip_invalid, out_dir, console_error=err)
        running = {c.cell_id for c in todo}  # a set: a list here made 10,000 cells take minutes to start
        outcome.reused = [c.cell_id for c in grid.cells if c.cell_id not in running]
        console = RunConsole(len(todo), quiet, out, err)
        display = ProgressDisplay(run.path, err, enabled=not quiet, live=console.bar is not None)
        console.line(f"tactile-zoo bench: {len(grid.cells)} cells, {len(outcome.reused)} already finished, "
                     f"{len(todo)} to run on {executor.describe()} -> {out_dir}")
        broken = {s.dataset for s in grid.skipped if s.status == "failed"}
        for name, note in grid.dataset_notes.items():
            if name in broken:  # present but unreadable: an error, not a skip
                console.error(f"tactile-zoo: error: dataset {name} failed to load: {note}")
            else:
                console.line(f"skipped dataset {name}: {note}", always=True)
        status, stop_code = "finished", 130
        try:
            write_error = _Loop(todo, run, config, executor, console, outcome, started, display, existing).run()
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (Terminated)
            status, stop_code = "interrupted", getattr(exc, "exit_code", 130)
            write_error = None
            why = exc if isinstance(exc, Terminated) else "interrupted"
            console.error(f"tactile-zoo: {why}; {len(outcome.ran)} cell(s) finished in this run are saved in "
                          f"{out_dir}; rerun the same command to resume")
        finally:
            display.close()
            console.close()
        records = run.cells()
        counts = {"ok": 0, "failed": 0, "skipped": 0, "pending": 0}
        for cell in grid.cells:
            counts[(records.get(cell.cell_id) or {}).get("status", "pending")] += 1
        counts["datasets_failed"] = len({s.dataset for s in grid.skipped if s.status == "failed"})
        counts["datasets_skipped"] = len(grid.dataset_notes) - counts["datasets_failed"]
        outcome.counts = counts
        try:
            if report:
                from .report import write_outputs

                # damaged files were named above; the ones of the grid have been recomputed
                write_outputs(run.path, plots=plots and status == "finished", skip_invalid=True)
        except TactileZooError as exc:  # already names the folder or the cell
            write_error = write_error or str(exc)
        except OSError as exc:
            write_error = write_error or f"cannot write the tables in {out_dir}: {exc.strerror or exc}"
        try:  # whatever became of the tables: run.json never stays "running" after the run
            _run_json(run, config, grid, status, {"started": started_text, "executor": executor.describe(),
                                                  "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                                                  "counts": counts})
        except ResultsError as exc:
            write_error = write_error or str(exc)
        except OSError as exc:
            write_error = write_error or f"cannot write {out_dir / 'run.json'}: {exc.strerror or exc}"
        summary = (f"done: {counts['ok']} ok, {counts['failed']} failed, {counts['skipped']} skipped"
                   + (f", {counts['pending']} not run" if counts["pending"] else "")
                   + (f"; {counts['datasets_skipped']} dataset(s) skipped" if counts["datasets_skipped"] else "")
                   + (f"; {counts['datasets_failed']} dataset(s) failed" if counts["datasets_failed"] else "")
                   + (f"; {len(scan.invalid)} damaged cell file(s) found" if scan.invalid else "")
                   + f" -> {out_dir / 'leaderboard.csv'}")
        console.line(summary, always=True)
        if write_error:
            console.error(f"tactile-zoo: error: {write_error}; every cell file written before is intact")
        if status == "interrupted":
            outcome.exit_code = stop_code
        elif write_error or counts["failed"] or counts["pending"] or counts["datasets_failed"]:
            outcome.exit_code = 1
        elif scan.invalid and not skip_invalid:  # never silent: a damaged file is a problem even once repaired
            outcome.exit_code = 1
        return outcome
    finally:
        executor.shutdown(cancel=status != "finished")


def _name_damaged(invalid: list[InvalidCell], grid_ids: set[str], skip_invalid: bool, out_dir: Path,
                  console_error: TextIO) -> None:
    """One line per damaged cell file: what is wrong, and what this run does with it."""
    level = "warning" if skip_invalid else "error"
    for item in invalid:
        fate = "it is moved to cells/damaged/ and recomputed" if item.path.stem in grid_ids else \
            "not a cell of this run's grid: left in place (`tactile-zoo report` will name it too)"
        print(f"tactile-zoo: {level}: damaged cell file {item}; {fate}", file=console_error, flush=True)


class _Loop:
    """Claim, submit, collect and write the cells of one run until none is left.

    A cell of ``todo`` moves through three places: ``pending`` (not looked at yet, in grid order), ``inflight``
    (submitted to the executor; we hold its claim) and ``deferred`` (another process held its claim when we looked).
    :meth:`run` repeats three steps: fill the executor's free slots from ``pending``, collect and write what finished,
    and, once nothing else is left, wait for a deferred cell's claim and either keep the record its holder wrote or
    run the cell ourselves. A record is written the moment its cell finishes; the claims of cells still in flight are
    released whatever stops the loop.
    """

    def __init__(self, todo: list[Cell], run: RunDir, config: BenchConfig, executor: Executor, console: RunConsole,
                 outcome: BenchOutcome, started: float, display: ProgressDisplay | None = None,
                 existing: dict[str, dict[str, Any]] | None = None) -> None:
        self.run_dir, self.config, self.executor, self.console = run, config, executor, console
        self.outcome, self.started = outcome, started
        self.display = display or ProgressDisplay(run.path, console.err, enabled=False, live=False)
        self.costs = CostModel((existing or {}).values())
        self.pending: deque[Cell] = deque(todo)
        self.inflight: dict[Any, tuple[Cell, Claim]] = {}
        self.deferred: deque[Cell] = deque()
        self.total, self.done = len(todo), 0
        self.waited_note = False

    def run(self) -> str | None:
        """Run every cell. Returns the write error that stopped the run, if one did; Ctrl-C propagates."""
        if isinstance(self.executor, LocalExecutor):
            self.executor.listener = self.on_epoch
        try:
            while self.pending or self.inflight or self.deferred:
                self.fill_slots()
                if self.inflight:
                    error = self.collect()
                    if error is not None:
                        return error
                elif self.deferred:  # everything left is claimed by other processes
                    self.take_over(self.deferred.popleft())
        except BaseException:  # Ctrl-C: stop the cells in flight first, so no worker writes their progress after this
            if self.inflight:
                self.executor.abandon()
            raise
        finally:
            for cell, claim in self.inflight.values():
                self.display.done(cell.cell_id)  # abandoned (Ctrl-C, a write error): its progress file goes
                claim.release()
            if isinstance(self.executor, LocalExecutor):
                self.executor.listener = None
        return None

    # ---------------------------------------------------------------------------------------- the three steps
    def fill_slots(self) -> None:
        """Take cells from ``pending`` until the executor's slots are full: claim each, keep a record another
        process finished meanwhile, defer one whose claim is held, submit the rest."""
        while self.pending and len(self.inflight) < self.executor.slots:
            cell = self.pending.popleft()
            claim = self.run_dir.claim(cell.cell_id)
            if claim is None:
                self.deferred.append(cell)
                continue
            record = self.fresh_record(cell)
            if record is not None:
                claim.release()
                self.finish(cell, record, by_us=False)
                continue
            self.run_dir.remove_torn(self.run_dir.cells_dir, self.run_dir.cell_path(cell.cell_id).name)  # a torn write
            if not self.set_aside(cell):
                claim.release()
                continue
            self.submit(cell, claim)
            if self.console.bar is not None and len(self.inflight) == 1 and not self.done:
                self.show_eta()

    def collect(self) -> str | None:
        """Wait for cells in flight (polling other processes' progress meanwhile) and write each that finished.
        Returns the write error that stops the run, if one happened."""
        polling = self.display.enabled and not isinstance(self.executor, LocalExecutor)
        finished = self.executor.wait(list(self.inflight), timeout=POLL_SECONDS if polling else None)
        if polling:
            self.display.poll([cell.cell_id for cell, _ in self.inflight.values()])
            if not finished and self.console.bar is not None:
                self.show_eta()
        for future in finished:
            cell, claim = self.inflight.pop(future)
            attempts = self.executor.attempts(future)  # before result(), which lets the executor forget the task
            try:
                record = self.executor.result(future)
            except KeyboardInterrupt:
                raise
            except BaseException as exc:  # noqa: BLE001 - a worker died: this cell failed, the grid goes on
                record = _worker_failure(cell, exc)
            record["attempts"] = attempts
            try:
                record = _write_record(self.run_dir, cell, record)
            except CellWriteError as exc:
                self.display.done(cell.cell_id)
                claim.release()
                self.console.error(f"tactile-zoo: error: {exc.strerror}")
                self.pending.clear()
                self.deferred.clear()
                return str(exc.strerror)
            self.display.done(cell.cell_id)  # before the claim goes: the next holder may write a new one
            claim.release()
            self.finish(cell, record, by_us=True)
        return None

    def take_over(self, cell: Cell) -> None:
        """Wait until the process holding ``cell``'s claim lets it go; keep its record, or run the cell if the
        holder stopped without finishing it."""
        if not self.waited_note:
            self.console.line(f"waiting for {len(self.deferred) + 1} cell(s) that another tactile-zoo bench on "
                              f"{self.run_dir.path} is running ({self.run_dir.claim_holder(cell.cell_id)})",
                              always=True)
            self.waited_note = True
        claim = self.run_dir.claim(cell.cell_id, blocking=True)
        assert claim is not None
        record = self.fresh_record(cell)
        if record is not None:
            claim.release()
            self.finish(cell, record, by_us=False)
        elif self.set_aside(cell):
            self.submit(cell, claim)
        else:
            claim.release()

    # ---------------------------------------------------------------------------------------- one cell
    def fresh_record(self, cell: Cell) -> dict[str, Any] | None:
        """A finished record of ``cell`` that this run may keep (written by another process since we started)."""
        record = self.run_dir.read_cell(cell.cell_id)
        if record is None or record.get("status") not in FINISHED:
            return None
        if self.config.force and self.run_dir.cell_path(cell.cell_id).stat().st_mtime < self.started:
            return None
        return record

    def set_aside(self, cell: Cell) -> bool:
        """Move a damaged file of ``cell`` (we hold its claim) to cells/damaged/ before it is recomputed, so the
        new record never silently replaces it; False when that failed (the cell is then not run)."""
        found = self.run_dir.read_cell_file(cell.cell_id)
        if not isinstance(found, InvalidCell):
            return True
        try:
            moved = move_aside(found.path)
        except OSError as exc:
            self.console.error(f"tactile-zoo: error: cannot move the damaged cell file {found.path} aside "
                               f"({exc.strerror or exc}); {cell.label()} is not run")
            return False
        self.console.line(f"moved the damaged cell file {found.path.name} to {moved.parent}/; recomputing "
                          f"{cell.label()}", always=True)
        return True

    def submit(self, cell: Cell, claim: Claim) -> None:
        """Hand ``cell`` (whose claim we hold) to the executor."""
        run, config = self.run_dir, self.config
        remove_progress(run.path, cell.cell_id)  # a killed run's leftover: we hold the claim, nobody else runs it
        try:
            future = self.executor.submit(_task(cell, config, self.executor, run.progress_dir,
                                                run.path / "weights" if config.save_weights else None, run.path))
        except BaseException:  # Ctrl-C inside a local cell: its claim and progress must not outlive it
            remove_progress(run.path, cell.cell_id)
            claim.release()
            raise
        self.inflight[future] = (cell, claim)

    def finish(self, cell: Cell, record: dict[str, Any], by_us: bool) -> None:
        """Count a finished cell, print its line, and update the ETA."""
        self.done += 1
        (self.outcome.ran if by_us else self.outcome.reused).append(cell.cell_id)
        suffix = "" if by_us else "  (finished by another process)"
        self.costs.learn(record)
        self.console.line(_cell_line(record, self.done, self.total) + suffix)
        self.console.step()
        self.show_eta()

    # ---------------------------------------------------------------------------------------- progress
    def on_epoch(self, state: dict[str, Any]) -> None:
        """The executor's listener: a cell running in this process finished an epoch."""
        self.display.show(state)
        if self.console.bar is not None:
            self.show_eta()

    def show_eta(self) -> None:
        """The cost-weighted time left for the cells in flight and those still to start."""
        left = [self.costs.remaining(c.model, c.dataset, c.config, self.display.states.get(c.cell_id))
                for c in [*(cell for cell, _ in self.inflight.values()), *self.pending, *self.deferred]]
        self.console.set_eta(self.costs.eta(left, self.executor.slots), self.done, self.total)


def _write_record(run: RunDir, cell: Cell, record: dict[str, Any]) -> dict[str, Any]:
    """Write the cell's record; one that fails the schema (a NaN score, a count below 0: a bug in a model or a
    plugin, :mod:`.schema`) is written as a failed cell naming what is wrong instead, so the grid goes on, the cell is
    retried by the next run, and the run exits 1. Returns the record written."""
    try:
        run.write_cell(record)
        return record
    except InvalidRecordError as exc:
        failed = _worker_failure(cell, exc, f"its {record.get('status')} record is not valid, so it is not kept: "
                                            f"{'; '.join(exc.problems[:3])}")
        failed["attempts"] = record.get("attempts")
        run.write_cell(failed)
        return failed


def _worker_failure(cell: Cell, exc: BaseException, text: str | None = None) -> dict[str, Any]:
    text = text or f"{type(exc).__name__}: {exc}".strip()
    if "BrokenProcessPool" in type(exc).__name__ or "KilledWorker" in type(exc).__name__:
        text = f"the worker process running this cell died (out of memory or killed): {text}"
    return {"format": RECORD_FORMAT, "cell_id": cell.cell_id, "model": cell.model, "dataset": cell.dataset,
            "fold": cell.fold, "seed": cell.seed, "config_hash": cell.config_hash, "protocol": cell.protocol,
            "status": "failed", "error": text[:2000], "config": cell.config.to_dict()}
