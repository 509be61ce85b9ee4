"""Distillation's teachers in a bench folder: which cells they are, and whether their weights are the ones recorded.

A student cell's teachers (:mod:`tactile_zoo.engine.distill`) are the cells of its configuration with distillation
off, one per teacher seed, on the student's fold. The ``teachers`` setting names the bench folder that ran them with
``save_weights``. Before a run starts, :func:`check_teachers` finds every teacher of every cell still to run there,
so a missing or altered teacher stops the command with one error naming each, before any cell trains; the worker
finds them again (:func:`find_teachers`: a Dask worker on another machine reads its own copy) and the student's
record names each teacher's cell and the SHA-256 of the weights it learnt from.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..data.base import file_sha256
from ..engine.config import CellConfig, config_hash
from ..engine.distill import teacher_config
from ..errors import ConfigError
from .grid import cell_id
from .records import InvalidCell, cell_file, read_record

__all__ = ["Teacher", "teacher_ids", "find_teachers", "check_teachers"]


@dataclass(frozen=True)
class Teacher:
    """One teacher of a cell: its cell id, its weight file and that file's SHA-256 (as its record states it)."""

    cell_id: str
    path: Path
    sha256: str

    def to_record(self) -> dict[str, Any]:
        return {"cell": self.cell_id, "sha256": self.sha256}


def teacher_ids(config: CellConfig, fold: int) -> list[str]:
    """The cell ids of ``config``'s teachers on ``fold``, in ``teacher_seeds`` order."""
    digest = config_hash(teacher_config(config))
    return [cell_id(config.model, config.dataset, fold, seed, digest) for seed in config.teacher_seeds]


def _problem(folder: Path, teacher_id: str) -> Teacher | str:
    """The teacher ``teacher_id`` of ``folder``, or what is wrong with it."""
    try:
        path = cell_file(folder / "cells", teacher_id)
        record = read_record(path)
    except FileNotFoundError:
        return f"{teacher_id}: no cell in {folder} (run the teachers first)"
    except Exception as exc:  # noqa: BLE001 - a damaged or doubled cell file: named, never used
        return f"{teacher_id}: {exc}"
    if isinstance(record, InvalidCell):
        return f"{teacher_id}: its cell file is damaged ({record})"
    if record.get("status") != "ok":
        return f"{teacher_id}: status {record.get('status')}, not ok"
    weights = record.get("weights")
    if not isinstance(weights, dict) or not weights.get("file") or not weights.get("sha256"):
        return f"{teacher_id}: its record holds no weights (run the teachers with save_weights: true)"
    file = folder / str(weights["file"])
    if not file.is_file():
        return f"{teacher_id}: its weights {file} are missing (`tactile-zoo rebuild-weights {folder}` remakes them)"
    if file_sha256(file) != weights["sha256"]:
        return f"{teacher_id}: its weights {file} are not the ones its record states (sha256 differs)"
    return Teacher(teacher_id, file, str(weights["sha256"]))


def find_teachers(folder: str | os.PathLike, config: CellConfig, fold: int) -> list[Teacher]:
    """``config``'s teachers on ``fold`` in the bench folder ``folder``, each checked against its record.

    Raises:
        ConfigError: naming every teacher that is missing, failed, saved no weights or whose weights changed.
    """
    found = [_problem(Path(folder), tid) for tid in teacher_ids(config, fold)]
    problems = [p for p in found if isinstance(p, str)]
    if problems:
        raise ConfigError(f"teachers of {config.model} on {config.dataset} fold {fold} in {folder}: "
                          + "; ".join(problems))
    return [t for t in found if isinstance(t, Teacher)]


def check_teachers(folder: str | os.PathLike, cells: Iterable[Any]) -> None:
    """Every teacher of the ``cells`` (the grid's :class:`~.grid.Cell` objects still to run), found and checked once
    each: one :class:`ConfigError` naming the first five problems and how many there are."""
    problems: list[str] = []
    seen: set[str] = set()
    for cell in cells:
        if not cell.config.teacher_seeds:
            continue
        for tid in teacher_ids(cell.config, cell.fold):
            if tid not in seen:
                seen.add(tid)
                found = _problem(Path(folder), tid)
                if isinstance(found, str):
                    problems.append(found)
    if problems:
        more = f" (and {len(problems) - 5} more)" if len(problems) > 5 else ""
        raise ConfigError(f"teachers: {len(problems)} teacher cell(s) of {folder} cannot be used: "
                          + "; ".join(problems[:5]) + more)
