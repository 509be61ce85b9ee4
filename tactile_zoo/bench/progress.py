"""Progress of running cells: written by the worker after every epoch, read by the runner and ``tactile-zoo report``.

Transport: one small JSON file per running cell, ``--out/progress/<cell id>.json``, replaced atomically after each
epoch by whichever process runs the cell (this process, a pool worker or a Dask worker), and removed by the runner
once the cell's record is written. A file works the same under every executor, needs no connection back to the
runner (a spawned pool worker has none; a Dask pub/sub channel would tie progress to a live client), survives the
runner's restart, and lets a second terminal (``tactile-zoo report OUT --running``) see what runs. Dask workers on
other hosts write there only if ``--out`` is on a file system they share; otherwise progress is silently off for
their cells and everything else works as before.

A progress file left behind by a process that was killed says nothing about the present, so each one names the
process that writes it: its pid, host, and (on Linux) ``pid_start``, the boot and start time of that process
(:func:`process_start`). ``report --running`` lists a cell as running only while that process still exists on this
host and is the same process (a pid the kernel has since given to another one is not it); otherwise the cell is
listed as stopped (:func:`describe_running`). A file written on another host cannot be checked from here and says so.

The writer only reads the epoch's curve row after the epoch ended: it touches no RNG, no model state and no tensor,
so records and leaderboards are bit-identical with and without it (``tests/bench/test_progress.py``).

:class:`CostModel` turns finished cells into a cost-weighted ETA: a cell costs its expected epochs times the
per-epoch seconds learned from finished cells of the same model and dataset (else of the same model, else of any
cell, else :data:`DEFAULT_EPOCH_SECONDS`), and a running cell costs only its remaining epochs at its own pace.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, TextIO

from .._files import atomic_write_text, torn_temporaries
from ..engine.progress import format_seconds, interactive, make_bar

__all__ = ["ProgressWriter", "add_listener", "remove_listener", "listening", "read_progress", "running_cells",
           "remove_progress", "CostModel", "ProgressDisplay", "describe_running", "PROGRESS_DIR",
           "DEFAULT_EPOCH_SECONDS", "process_start", "process_alive", "RunConsole"]

logger = logging.getLogger(__name__)

PROGRESS_DIR = "progress"
#: per-epoch seconds assumed for a cell nothing is known about (the simulators' cells run 0.3-10 s per epoch)
DEFAULT_EPOCH_SECONDS = 2.0
#: epochs a progress file lists (the runner reads every running cell's file at least once a second)
KEPT_EPOCHS = 32

#: listeners in this process, called with the progress state after each epoch's file is written: the local
#: executor's display, or a plugin that watches epochs where cells run (see add_listener)
_LISTENERS: list[Callable[[dict[str, Any]], None]] = []


def add_listener(listener: Callable[[dict[str, Any]], None]) -> None:
    """Call ``listener(state)`` at every epoch boundary of every cell run *in this process* (``state``: the
    progress file's content). A plugin module imported on the workers can watch epochs this way."""
    _LISTENERS.append(listener)


def remove_listener(listener: Callable[[dict[str, Any]], None]) -> None:
    with contextlib.suppress(ValueError):
        _LISTENERS.remove(listener)


def progress_dir(out: str | os.PathLike) -> Path:
    return Path(out) / PROGRESS_DIR


# ----------------------------------------------------------------------------------------------- worker side
class ProgressWriter:
    """``train_cell(..., callback=ProgressWriter(...))``: after each epoch, replace the cell's progress file.

    Never raises: a folder that is not there (a remote worker without the shared ``--out``) or a full disk turns
    progress off for this cell, never fails it.
    """

    def __init__(self, folder: str | os.PathLike, cell: Mapping[str, Any], max_epochs: int) -> None:
        self.path = Path(folder) / f"{cell['cell_id']}.json"
        self.base = {**{k: cell[k] for k in ("cell_id", "model", "dataset", "fold", "seed")},
                     "max_epochs": int(max_epochs), "pid": os.getpid(), "host": socket.gethostname(),
                     "pid_start": process_start(os.getpid())}
        self.started = time.time()
        # the last KEPT_EPOCHS [epoch, val_accuracy, seconds]: a reader polling less often than epochs end still logs
        # each of them, and the file stays small (rewriting the whole history would cost O(epochs) per epoch)
        self.epochs: list[list[Any]] = []
        self.train_seconds = 0.0  # the epochs' own seconds: a pace without the data loading before epoch 1
        self.enabled = self.path.parent.is_dir()
        if not self.enabled:
            logger.debug("progress folder %s is not here: no progress for cell %s", self.path.parent, cell["cell_id"])

    def __call__(self, row: Mapping[str, Any]) -> None:
        if not self.enabled:
            return
        now = time.time()
        seconds = row.get("seconds")
        seconds = round(float(seconds), 3) if isinstance(seconds, int | float) else None
        self.epochs = [*self.epochs[-(KEPT_EPOCHS - 1):], [int(row["epoch"]), row.get("val_accuracy"), seconds]]
        self.train_seconds += seconds or 0.0
        state = {**self.base, "epoch": int(row["epoch"]), "val_accuracy": row.get("val_accuracy"),
                 "train_loss": row.get("train_loss"), "seconds": seconds, "train_seconds": round(self.train_seconds, 3),
                 "elapsed": round(now - self.started, 3), "updated": now, "epochs": self.epochs}
        try:
            _replace(self.path, json.dumps(state))
        except OSError as exc:
            self.enabled = False
            logger.debug("cannot write %s (%s): progress off for this cell", self.path, exc)
            return
        for listener in list(_LISTENERS):
            try:
                listener(state)
            except Exception as exc:  # noqa: BLE001 - a display that cannot draw must not fail the cell
                logger.debug("progress listener %r failed: %s", listener, exc)


def _replace(path: Path, text: str) -> None:
    """Atomic replace without fsync: a progress file is disposable, and an fsync per epoch would cost milliseconds."""
    atomic_write_text(path, text, fsync=False)


@contextlib.contextmanager
def listening(listener: Callable[[dict[str, Any]], None] | None) -> Any:
    """Call ``listener`` after each epoch of cells run in this process (the local executor)."""
    if listener is None:
        yield
        return
    add_listener(listener)
    try:
        yield
    finally:
        remove_listener(listener)


# ----------------------------------------------------------------------------------------------- the writer's process
def process_start(pid: int) -> str | None:
    """``"<boot id>:<start time>"`` of process ``pid`` (Linux ``/proc``: the start time in clock ticks since boot,
    field 22 of ``/proc/PID/stat``), which tells the process apart from a later one given the same pid; ``None``
    where ``/proc`` is not there (macOS, Windows) or the process is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        # the command name (field 2) is in parentheses and may hold spaces: count the fields after its ")"
        return f"{boot}:{stat.rpartition(')')[2].split()[19]}"
    except (OSError, IndexError):
        return None


def _zombie(pid: int) -> bool:
    """An exited process whose parent has not collected it yet: it still has a pid, and runs nothing."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] == "Z"
    except (OSError, IndexError):
        return False


def process_alive(pid: Any, host: Any, start: Any = None) -> bool | None:
    """Whether process ``pid`` on ``host``, started at ``start`` (:func:`process_start`, when it was recorded),
    still runs: ``False`` when it has exited or its pid now belongs to another process, ``None`` when this machine
    cannot tell (another host, or no way to ask)."""
    if host != socket.gethostname() or not isinstance(pid, int) or pid <= 0 or sys.platform == "win32":
        return None
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # it exists, under another user
    except OSError:
        return None
    if _zombie(pid):
        return False
    if start is not None:
        now = process_start(pid)
        if now is not None and now != start:
            return False  # the pid was given to another process since
    return True


# ----------------------------------------------------------------------------------------------- reader side
def read_progress(out: str | os.PathLike, cell_id: str) -> dict[str, Any] | None:
    try:
        state = json.loads((progress_dir(out) / f"{cell_id}.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return state if isinstance(state, dict) and "epoch" in state else None


def running_cells(out: str | os.PathLike) -> list[dict[str, Any]]:
    """The progress of every cell that has a progress file (running, or left by a killed run: see ``updated``)."""
    folder = progress_dir(out)
    states = []
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        state = read_progress(out, path.stem)
        if state is not None:
            states.append(state)
    return states


def remove_progress(out: str | os.PathLike, cell_id: str) -> None:
    """Remove cell ``cell_id``'s progress file, and the temporary of any write to it that did not finish (a worker
    stopped mid-write leaves one); call it only once nothing writes that file any more."""
    folder, name = progress_dir(out), f"{cell_id}.json"
    for path in (folder / name, *torn_temporaries(folder, name)):
        with contextlib.suppress(OSError):
            path.unlink()


def _epoch_text(state: Mapping[str, Any], epoch: int | None = None, acc: Any = None, seconds: Any = None) -> str:
    """``epoch 3/15 val_acc 0.412 41.2s``: the latest epoch of ``state`` unless ``epoch`` is given."""
    if epoch is None:
        epoch, acc, seconds = state["epoch"], state.get("val_accuracy"), state.get("seconds")
    return (f"epoch {epoch}/{state['max_epochs']}"
            + (f" val_acc {acc:.3f}" if isinstance(acc, int | float) else "")
            + (f" {seconds:.1f}s" if isinstance(seconds, int | float) else ""))


def _label(state: Mapping[str, Any]) -> str:
    return f"{state['model']} x {state['dataset']} fold {state['fold']} seed {state['seed']}"


def describe_running(out: str | os.PathLike, now: float | None = None) -> list[str]:
    """One line per cell with a progress file, for ``tactile-zoo report OUT --running``: ``running ...`` while the
    process that writes it still runs (:func:`process_alive`), ``stopped ...`` once it does not (interrupted or
    killed: its last epoch is all there is), and ``running ..., not checked`` for a process on another host."""
    now = time.time() if now is None else now
    lines = []
    for s in running_cells(out):
        where = f"pid {s['pid']} on {s['host']}"
        alive = process_alive(s.get("pid"), s.get("host"), s.get("pid_start"))
        head = f"{_label(s)}: {_epoch_text(s)}, updated {format_seconds(now - s['updated'])} ago"
        if alive is False:
            lines.append(f"stopped {head} ({where} is no longer running: the run was interrupted or killed; "
                         f"rerunning its bench command resumes the cell)")
        else:
            unchecked = alive is None and s.get("host") != socket.gethostname()
            lines.append(f"running {head} ({where}{', another host: not checked' if unchecked else ''})")
    return lines


# ----------------------------------------------------------------------------------------------- cost and ETA
def _max_epochs(config: Any) -> int:
    """The recipe's epoch budget of a cell: its resolved configuration (a grid's cell) or a record's ``config``."""
    try:
        return max(1, int(config["recipe"]["max_epochs"] if isinstance(config, Mapping) else config.recipe.max_epochs))
    except (AttributeError, KeyError, TypeError, ValueError):
        return 1


class CostModel:
    """Expected seconds of cells, learned from finished records (see the module docstring)."""

    def __init__(self, records: Iterable[Mapping[str, Any]] = ()) -> None:
        self._pace: dict[tuple[str, str], list[float]] = defaultdict(list)  # seconds per epoch
        self._share: dict[tuple[str, str], list[float]] = defaultdict(list)  # epochs run / max epochs
        for record in records:
            self.learn(record)

    def learn(self, record: Mapping[str, Any]) -> None:
        epochs, seconds = record.get("epochs_run"), record.get("seconds") or record.get("train_seconds")
        if record.get("status") != "ok" or not epochs or not seconds:
            return
        key = (record["model"], record["dataset"])
        self._pace[key].append(float(seconds) / int(epochs))  # the whole cell (evaluation included) per epoch
        self._share[key].append(int(epochs) / _max_epochs(record.get("config") or {}))

    def epoch_seconds(self, model: str, dataset: str) -> float:
        for values in (self._pace.get((model, dataset)),
                       [v for (m, _), vs in self._pace.items() if m == model for v in vs],
                       [v for vs in self._pace.values() for v in vs]):
            if values:
                return sum(values) / len(values)
        return DEFAULT_EPOCH_SECONDS

    def expected_epochs(self, model: str, dataset: str, config: Any) -> float:
        """The recipe's epochs, times the share of them finished cells of this pair ran (early stopping)."""
        shares = self._share.get((model, dataset))
        return _max_epochs(config) * (sum(shares) / len(shares) if shares else 1.0)

    def remaining(self, model: str, dataset: str, config: Any,
                  state: Mapping[str, Any] | None = None) -> float:
        """Seconds left of a cell; ``state`` (its progress) replaces the estimate by its own pace so far."""
        expected = self.expected_epochs(model, dataset, config)
        if not state or not state.get("epoch"):
            return expected * self.epoch_seconds(model, dataset)
        done = int(state["epoch"])
        spent = float(state.get("train_seconds") or state.get("elapsed") or 0)
        pace = spent / done or self.epoch_seconds(model, dataset)
        return max(expected - done, 0.0 if done >= _max_epochs(config) else 1.0) * pace

    def eta(self, costs: list[float], slots: int) -> float:
        """Wall seconds for ``costs`` on ``slots`` parallel workers: the larger of the even share and the longest."""
        if not costs:
            return 0.0
        return max(sum(costs) / max(1, min(slots, len(costs))), max(costs))


# ----------------------------------------------------------------------------------------------- the display
class ProgressDisplay:
    """What the runner shows of running cells: on a terminal a live bar per running cell; otherwise one log line
    per new epoch (``logging`` INFO on ``tactile_zoo.bench.progress``)."""

    def __init__(self, out: str | os.PathLike, stream: TextIO, enabled: bool, live: bool) -> None:
        self.out, self.stream, self.enabled, self.live = Path(out), stream, enabled, live and enabled
        self.seen: dict[str, tuple[int, int]] = {}  # cell id -> (pid, epoch) last shown
        self.bars: dict[str, Any] = {}
        self.states: dict[str, dict[str, Any]] = {}

    def poll(self, cell_ids: Iterable[str]) -> None:
        """Read the progress of ``cell_ids`` (the running ones) and show what is new."""
        for cell_id in cell_ids:
            state = read_progress(self.out, cell_id)
            if state is not None:
                self.show(state)

    def show(self, state: dict[str, Any]) -> None:
        cell_id = state["cell_id"]
        self.states[cell_id] = state
        last = self.seen.get(cell_id)
        mark = (int(state.get("pid", 0)), int(state["epoch"]))
        if last == mark or not self.enabled:
            return
        if last is not None and last[0] != mark[0]:  # another process took the cell over: its worker was lost
            logger.warning("%s: restarted (pid %s on %s) after its worker was lost", _label(state), state["pid"],
                           state["host"])
        shown = last[1] if last is not None and last[0] == mark[0] else 0
        self.seen[cell_id] = mark
        if not self.live:
            for epoch, acc, seconds in state.get("epochs") or [[state["epoch"], None, None]]:
                if epoch > shown:
                    logger.info("%s: %s", _label(state), _epoch_text(state, epoch, acc, seconds))
            return
        bar = self.bars.get(cell_id)
        if bar is None:
            bar = make_bar(state["max_epochs"], _label(state), "ep", self.stream,
                           bar_format="{desc} |{bar:20}| {n_fmt}/{total_fmt} ep{postfix}")
            self.bars[cell_id] = bar
        bar.n = min(state["epoch"], state["max_epochs"])
        acc = state.get("val_accuracy")
        pace = float(state.get("train_seconds") or state.get("elapsed") or 0) / max(1, state["epoch"])
        bar.set_postfix_str((f"val_acc {acc:.3f}, " if isinstance(acc, int | float) else "")
                            + (f"{pace:.1f}s" if pace < 60 else format_seconds(pace)) + "/epoch", refresh=True)

    def done(self, cell_id: str) -> None:
        """The cell's record is written: drop its line and its progress file."""
        if self.enabled and not self.live:  # epochs that ended since the last poll still get their lines
            self.poll([cell_id])
        bar = self.bars.pop(cell_id, None)
        if bar is not None:
            bar.close()
        self.seen.pop(cell_id, None)
        self.states.pop(cell_id, None)
        remove_progress(self.out, cell_id)

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
        self.bars.clear()


class RunConsole:
    """The bench runner's console: per-cell lines on ``out`` (through tqdm when a bar is shown), and the grid's
    progress bar with the cost-weighted ETA."""

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
