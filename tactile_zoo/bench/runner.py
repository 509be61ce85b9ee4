"""The bench run: resolve the grid, reuse finished cells, run the rest on an executor, write every output.

Resuming: a cell whose file exists with status ``ok`` or ``skipped`` is finished and never recomputed (``force``
recomputes); a ``failed`` cell is retried on the next run. A cell is written the moment it finishes, atomically, so a
run killed at any point (SIGKILL included) loses at most the cells that were running.

Exit codes: 0 every cell ok (or skipped), 1 a cell or a dataset failed or a file could not be written, 130
interrupted (Ctrl-C: running cells are abandoned, finished ones kept, the tables written for them).

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
from ..engine.progress import interactive, make_bar
from ..errors import ResultsError, TactileZooError
from .cell import CellTask
from .config import BenchConfig
from .environment import environment
from .executors import Executor, LocalExecutor, check_workers, make_executor
from .grid import Cell, Grid, build_grid, default_out_dir
from .progress import CostModel, ProgressDisplay, format_seconds, remove_progress
from .records import InvalidCell, move_aside, refuse_newer
from .results import BENCH_FORMAT, CellWriteError, Claim, RunDir, atomic_write_json
from .schema import RECORD_FORMAT, InvalidRecordError

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


class _Console:
    """Per-cell lines on ``out`` (through tqdm when a bar is shown), and the grid's progress bar."""

    def __init__(self, total: int, quiet: bool, out: TextIO, err: TextIO) -> None:
        self.quiet, self.out, self.err = quiet, out, err
        self.bar = None
        if not quiet and total and interactive(err):
            # tqdm's own ETA assumes equally costly cells; the cost-weighted one goes in the postfix (set_eta)
            self.bar = make_bar(total, "cells", "cell", err, leave=True,
                                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")

    def line(self, text: str, always: bool = False) -> None:
        if self.quiet and not always:
            return
        if self.bar is not None:
            self.bar.write(text, file=self.out)
        else:
            print(text, file=self.out, flush=True)

    def error(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text, file=self.err)
        else:
            print(text, file=self.err, flush=True)

    def step(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def set_eta(self, seconds: float, done: int, total: int) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(f"eta {format_seconds(seconds)}", refresh=True)
        elif not self.quiet and done < total:
            logger.info("%d/%d cells done, eta %s", done, total, format_seconds(seconds))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


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
                    tracker_dir=str(tracker_dir.resolve()) if config.tracker and tracker_dir is not None else None)


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
    ``cells/damaged/`` and recomputed. Either way the exit code is 1 unless ``skip_invalid``."""
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
    run.prepare()
    started = time.time()
    started_text = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    existing = scan.records  # prepare() writes no cell: the scan above still holds
    todo = [c for c in grid.cells if config.force or (existing.get(c.cell_id) or {}).get("status") not in FINISHED]
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
        console = _Console(len(todo), quiet, out, err)
        display = ProgressDisplay(run.path, err, enabled=not quiet, live=console.bar is not None)
        console.line(f"tactile-zoo bench: {len(grid.cells)} cells, {len(outcome.reused)} already finished, "
                     f"{len(todo)} to run on {executor.describe()} -> {out_dir}")
        broken = {s.dataset for s in grid.skipped if s.status == "failed"}
        for name, note in grid.dataset_notes.items():
            if name in broken:  # present but unreadable: an error, not a skip
                console.error(f"tactile-zoo: error: dataset {name} failed to load: {note}")
            else:
                console.line(f"skipped dataset {name}: {note}", always=True)
        status = "finished"
        try:
            write_error = _loop(todo, run, config, executor, console, outcome, started, display, existing)
        except KeyboardInterrupt:
            status = "interrupted"
            write_error = None
            console.error(f"tactile-zoo: interrupted; {len(outcome.ran)} cell(s) finished in this run are saved in "
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
            outcome.exit_code = 130
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


def _loop(todo: list[Cell], run: RunDir, config: BenchConfig, executor: Executor, console: _Console,
          outcome: BenchOutcome, started: float, display: ProgressDisplay | None = None,
          existing: dict[str, dict[str, Any]] | None = None) -> str | None:
    """Claim, submit, collect and write cells until none is left. Returns a write error, if one stopped the run."""
    pending = deque(todo)
    inflight: dict[Any, tuple[Cell, Claim]] = {}
    deferred: deque[Cell] = deque()
    total, done = len(todo), 0
    waited_note = False
    display = display or ProgressDisplay(run.path, console.err, enabled=False, live=False)
    costs = CostModel((existing or {}).values())

    def running() -> list[str]:
        return [cell.cell_id for cell, _ in inflight.values()]

    def eta() -> None:
        left = [costs.remaining(c.model, c.dataset, c.config, display.states.get(c.cell_id))
                for c in [*(cell for cell, _ in inflight.values()), *pending, *deferred]]
        console.set_eta(costs.eta(left, executor.slots), done, total)

    def epoch(state: dict[str, Any]) -> None:  # a cell running in this process finished an epoch
        display.show(state)
        if console.bar is not None:
            eta()

    if isinstance(executor, LocalExecutor):
        executor.listener = epoch

    def fresh(cell: Cell) -> dict[str, Any] | None:
        """A finished record of ``cell`` that this run may keep (written by another process since we started)."""
        record = run.read_cell(cell.cell_id)
        if record is None or record.get("status") not in FINISHED:
            return None
        if config.force and run.cell_path(cell.cell_id).stat().st_mtime < started:
            return None
        return record

    def set_aside(cell: Cell) -> bool:
        """Move a damaged file of ``cell`` (we hold its claim) to cells/damaged/ before it is recomputed, so the
        new record never silently replaces it; False when that failed (the cell is then not run)."""
        found = run.read_cell_file(cell.cell_id)
        if not isinstance(found, InvalidCell):
            return True
        try:
            moved = move_aside(found.path)
        except OSError as exc:
            console.error(f"tactile-zoo: error: cannot move the damaged cell file {found.path} aside "
                          f"({exc.strerror or exc}); {cell.label()} is not run")
            return False
        console.line(f"moved the damaged cell file {found.path.name} to {moved.parent}/; recomputing "
                     f"{cell.label()}", always=True)
        return True

    def finish(cell: Cell, record: dict[str, Any], by_us: bool) -> None:
        nonlocal done
        done += 1
        (outcome.ran if by_us else outcome.reused).append(cell.cell_id)
        suffix = "" if by_us else "  (finished by another process)"
        costs.learn(record)
        console.line(_cell_line(record, done, total) + suffix)
        console.step()
        eta()

    try:
        while pending or inflight or deferred:
            while pending and len(inflight) < executor.slots:
                cell = pending.popleft()
                claim = run.claim(cell.cell_id)
                if claim is None:
                    deferred.append(cell)
                    continue
                record = fresh(cell)
                if record is not None:
                    claim.release()
                    finish(cell, record, by_us=False)
                    continue
                run.remove_torn(run.cells_dir, f"{cell.cell_id}.json")  # a killed writer's half file
                if not set_aside(cell):
                    claim.release()
                    continue
                _submit(executor, cell, claim, config, inflight, run)
                if console.bar is not None and len(inflight) == 1 and not done:
                    eta()
            if inflight:
                polling = display.enabled and not isinstance(executor, LocalExecutor)
                finished = executor.wait(list(inflight), timeout=POLL_SECONDS if polling else None)
                if polling:
                    display.poll(running())
                    if not finished and console.bar is not None:
                        eta()
                for future in finished:
                    cell, claim = inflight.pop(future)
                    attempts = executor.attempts(future)  # before result(), which lets the executor forget the task
                    try:
                        record = executor.result(future)
                    except KeyboardInterrupt:
                        raise
                    except BaseException as exc:  # noqa: BLE001 - a worker died: this cell failed, the grid goes on
                        record = _worker_failure(cell, exc)
                    record["attempts"] = attempts
                    try:
                        record = _write_record(run, cell, record)
                    except CellWriteError as exc:
                        display.done(cell.cell_id)
                        claim.release()
                        console.error(f"tactile-zoo: error: {exc.strerror}")
                        pending.clear()
                        deferred.clear()
                        return str(exc.strerror)
                    display.done(cell.cell_id)  # before the claim goes: the next holder may write a new one
                    claim.release()
                    finish(cell, record, by_us=True)
                continue
            if not deferred:  # the last pending cells were found finished by another process
                continue
            # everything left is claimed by other processes: wait for them, then take over what they left undone
            cell = deferred.popleft()
            if not waited_note:
                console.line(f"waiting for {len(deferred) + 1} cell(s) that another tactile-zoo bench on {run.path} "
                             f"is running ({run.claim_holder(cell.cell_id)})", always=True)
                waited_note = True
            claim = run.claim(cell.cell_id, blocking=True)
            assert claim is not None
            record = fresh(cell)
            if record is not None:
                claim.release()
                finish(cell, record, by_us=False)
            elif set_aside(cell):  # its holder stopped without finishing it
                _submit(executor, cell, claim, config, inflight, run)
            else:
                claim.release()
    except BaseException:  # Ctrl-C: stop the cells in flight first, so no worker writes their progress after this
        if inflight:
            executor.abandon()
        raise
    finally:
        for cell, claim in inflight.values():
            display.done(cell.cell_id)  # abandoned (Ctrl-C, a write error): its progress file goes, not running
            claim.release()
        if isinstance(executor, LocalExecutor):
            executor.listener = None
    return None


def _submit(executor: Executor, cell: Cell, claim: Claim, config: BenchConfig, inflight: dict[Any, Any],
            run: RunDir) -> None:
    remove_progress(run.path, cell.cell_id)  # a killed run's leftover: we hold the claim, nobody else runs it
    try:
        future = executor.submit(_task(cell, config, executor, run.progress_dir,
                                       run.path / "weights" if config.save_weights else None, run.path))
    except BaseException:  # Ctrl-C inside a local cell: its claim and progress must not outlive it
        remove_progress(run.path, cell.cell_id)
        claim.release()
        raise
    inflight[future] = (cell, claim)


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
