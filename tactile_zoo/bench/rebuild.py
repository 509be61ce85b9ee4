"""Remake a bench folder's saved weights from its cell records, without reading any test split again.

Weights are never committed (a cell record is: its configuration, seed, revision and the SHA-256 of the weights it
saved), so a clone, or a new session of the same machine, has the records but not the files. Distillation needs the
files: a student's teachers are checked by their SHA-256 before any student trains (:mod:`.teachers`).
:func:`rebuild_weights` trains each selected cell again from its record alone, at its recorded model revision and
torch thread count, with :func:`~tactile_zoo.engine.cell.train_cell`'s ``read_test=False`` (the test split is neither
loaded nor evaluated: the cell's one read stays its only one), and keeps the file only when its SHA-256 equals the
recorded one. A file that differs is not kept: the record's accuracy is the accuracy of the recorded weights, and no
other file may stand in for them. Training reproduces bit for bit on the CPU type that ran the cell (``cpu`` and
``cpu_isa`` in the record); on another one it usually does not, which the command says before any work.

    tactile-zoo rebuild-weights benchmarks/results/table1-cost-r5/rest --cell 'x_tacformer__ev_*__s[5-9]__*'
"""

from __future__ import annotations

import concurrent.futures as cf
import fnmatch
import multiprocessing
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..data.base import file_sha256
from ..engine.config import CellConfig
from ..errors import ConfigError
from .records import InvalidCellsError, run_records
from .worker import save_weights, setup_worker

__all__ = ["Rebuilt", "weight_cells", "rebuild_weights"]


@dataclass(frozen=True)
class Rebuilt:
    """The outcome for one cell. ``status``: ``present`` (the file was already there with the recorded SHA-256),
    ``rebuilt`` (trained again, the same SHA-256, now in place) or ``differs`` (trained again, another SHA-256, not
    kept)."""

    cell_id: str
    status: str
    path: Path
    sha256: str
    seconds: float = 0.0

    def line(self) -> str:
        text = {"present": "already there, sha256 as recorded",
                "rebuilt": f"rebuilt in {self.seconds:.0f} s, sha256 as recorded",
                "differs": f"trained again in {self.seconds:.0f} s, but its sha256 {self.sha256[:12]} is not the "
                           "recorded one: not kept"}[self.status]
        return f"{self.status} {self.cell_id}: {text}"


def _saved(record: dict[str, Any]) -> dict[str, Any] | None:
    weights = record.get("weights")
    return weights if isinstance(weights, dict) and weights.get("file") and weights.get("sha256") else None


def weight_cells(folder: str | os.PathLike, patterns: Sequence[str] = ()) -> list[dict[str, Any]]:
    """The records of ``folder`` whose cells saved weights, those whose id matches one of ``patterns`` (shell
    wildcards; none: every one), in cell id order.

    Raises:
        ConfigError: ``folder`` has no cells; a pattern matches no cell that saved weights; a matched cell failed, or
            distilled from teachers, or is a ``reference`` cell (its training reads the test split every epoch).
    """
    folder = Path(folder)
    try:
        records = [r for r in run_records(folder) if r.get("status") == "ok"]
    except InvalidCellsError as exc:
        raise ConfigError(str(exc)) from exc
    if not records:
        raise ConfigError(f"{folder}: no finished cell records (is it a bench folder?)")
    saved = sorted((r for r in records if _saved(r)), key=lambda r: r["cell_id"])
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(r["cell_id"], pattern) for r in saved):
            raise ConfigError(f"--cell {pattern!r}: no cell of {folder} that saved weights matches it")
    chosen = [r for r in saved if not patterns or any(fnmatch.fnmatchcase(r["cell_id"], p) for p in patterns)]
    for record in chosen:
        config = record["config"]
        if config.get("teacher_seeds"):
            raise ConfigError(f"{record['cell_id']}: a distilled cell's weights depend on its teachers' files; "
                              "rebuilding them is not supported")
        if config.get("evaluation") == "reference":
            raise ConfigError(f"{record['cell_id']}: a reference cell reads the test split after every epoch, so "
                              "its weights cannot be remade without reading it again")
    return chosen


def _train_one(record: dict[str, Any], root: str | None, target: str, plugins: tuple[str, ...],
               sys_path: tuple[str, ...]) -> tuple[str, str, float]:
    """In a worker process: train ``record``'s cell without its test split and save the weights to ``target``;
    returns (cell id, sha256, seconds)."""
    import time

    from ..engine.cell import train_cell

    threads = int(record.get("threads") or 1)
    os.environ["OMP_NUM_THREADS"] = str(threads)  # as the bench's process workers
    setup_worker(plugins, threads, sys_path)
    start = time.perf_counter()
    result = train_cell(CellConfig.from_dict(record["config"]), fold=record["fold"], seed=record["seed"], root=root,
                        measure=False, read_test=False)
    # the metadata the bench wrote (bench.worker.run_cell): part of the file's bytes, so of its sha256
    saved = save_weights(result.fit.model, Path(target), {"cell_id": record["cell_id"],
                                                          "config_hash": record["config_hash"],
                                                          "model": record["model"], "dataset": record["dataset"]})
    return record["cell_id"], saved["sha256"], time.perf_counter() - start


def rebuild_weights(folder: str | os.PathLike, patterns: Sequence[str] = (), *, root: str | os.PathLike | None = None,
                    workers: int = 1, plugin_modules: Sequence[str] = (),
                    on_result: Callable[[Rebuilt], None] | None = None) -> list[Rebuilt]:
    """Remake the missing (or altered) weight files of ``folder``'s cells selected by ``patterns`` (see
    :func:`weight_cells`), ``workers`` cells at a time, each in its own process at its recorded thread count.

    A file already there with the recorded SHA-256 is left as it is. A remade file replaces the cell's file only
    when its SHA-256 is the recorded one; otherwise nothing is written and the outcome is ``differs``.

    Raises:
        ConfigError: as :func:`weight_cells`, and for ``workers`` < 1.
    """
    if workers < 1:
        raise ConfigError(f"workers: {workers}; at least 1")
    folder = Path(folder)
    chosen = weight_cells(folder, patterns)
    outcomes: list[Rebuilt] = []
    todo: list[dict[str, Any]] = []
    for record in chosen:
        weights = _saved(record)
        assert weights is not None
        path = folder / str(weights["file"])
        if path.is_file() and file_sha256(path) == weights["sha256"]:
            outcomes.append(Rebuilt(record["cell_id"], "present", path, weights["sha256"]))
            if on_result:
                on_result(outcomes[-1])
        else:
            todo.append(record)
    if not todo:
        return outcomes
    context = multiprocessing.get_context("spawn")  # a fresh interpreter per pool, as the bench's process executor
    with cf.ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=context) as pool:
        pending: dict[cf.Future[tuple[str, str, float]], tuple[dict[str, Any], Path, Path]] = {}
        for record in todo:
            path = folder / str(_saved(record)["file"])  # type: ignore[index]
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.rebuild.tmp")  # renamed over the cell's file only when kept
            future = pool.submit(_train_one, record, None if root is None else str(root), str(tmp),
                                 tuple(plugin_modules), tuple(sys.path))
            pending[future] = (record, path, tmp)
        try:
            for future in cf.as_completed(pending):
                record, path, tmp = pending[future]
                cell, sha, seconds = future.result()
                if sha == _saved(record)["sha256"]:  # type: ignore[index]
                    os.replace(tmp, path)
                    outcome = Rebuilt(cell, "rebuilt", path, sha, seconds)
                else:
                    outcome = Rebuilt(cell, "differs", path, sha, seconds)
                outcomes.append(outcome)
                if on_result:
                    on_result(outcome)
        finally:
            for _, _, tmp in pending.values():
                tmp.unlink(missing_ok=True)
    return sorted(outcomes, key=lambda o: o.cell_id)

