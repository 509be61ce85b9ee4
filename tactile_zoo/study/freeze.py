"""The freeze: what a study declared, fixed before its first cell, and the amendments appended after it.

``study run`` freezes the file before it starts any cell: ``RESULTS/study/freeze.json`` records the file's sha256,
the time, and the grids, rules and reads as written; ``RESULTS/study/study.yaml`` is a copy of the file. From then
on (once any cell exists), a file whose grids, rules or reads differ from the frozen ones is refused, naming each
key that changed. Changes go into ``amendments``, appended with a reason; each is frozen in turn (its time and
hash), and may add a grid, a read or a rule, never change one whose inputs already exist:

- a grid of a new name, or one replacing a grid whose folder holds no cell yet, or a reused grid re-declared
  unchanged but ``superseded`` (its cells no longer count, e.g. run on another CPU type) while no recorded read took
  its cells;
- a read of a new name, or one replacing a read none of whose cells exist yet (a comparison given as arms: none of
  the study's own cells it reads, a reused grid's cells being there before the study ran any);
- a rule that was not set (``cpu``, ``budget_cpu_hours``), or any rule while the study has run no cell of its own
  (a reused grid's cells do not count: the study did not run them under its rules).

A migrated study carries its freeze in the file (``freeze: {time, commit, source}``, read once from its plan's
first commit): that time is the freeze :func:`freeze_times` reports, for the audit to check cells against.
"""

from __future__ import annotations

import hashlib
import json
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from .._files import atomic_write_text
from ..bench.records import cell_files
from ..bench.rundir import STUDY_RECORDS, RunDir, atomic_write_json
from ..errors import ConfigError
from .checks import comparison_arms, read_members
from .reads import recorded_reads
from .schema import ComparisonRead, GridSpec, Study, amendment_kept, canonical_hash

__all__ = ["FREEZE_DIR", "TIME_FORMAT", "freeze_path", "read_freeze", "freeze", "changes", "freeze_times",
           "freeze_status", "parse_time", "has_cells"]

FREEZE_DIR = STUDY_RECORDS
TIME_FORMAT = "%Y-%m-%dT%H:%M:%S%z"  # as a cell record's ``started``


def freeze_path(study: Study) -> Path:
    return study.results / FREEZE_DIR / "freeze.json"


def parse_time(text: str) -> datetime:
    return datetime.strptime(text, TIME_FORMAT)


def read_freeze(study: Study) -> dict[str, Any] | None:
    path = freeze_path(study)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot be read as a study freeze ({exc})") from None
    if not isinstance(data, dict) or not {"sha256", "time", "frozen", "amendments"} <= set(data):
        raise ConfigError(f"{path}: not a study freeze (it needs sha256, time, frozen and amendments)")
    return data


def has_cells(study: Study, grid_names: list[str] | None = None) -> bool:
    return any(cell_files(study.folder(g)) for g in study.grids() if grid_names is None or g.name in grid_names)


def changes(frozen: Any, current: Any, key: str = "") -> list[str]:
    """Each key whose value differs between ``frozen`` and ``current`` (a list of named grids or reads is compared
    by name), as ``KEY: OLD -> NEW``."""
    if isinstance(frozen, list) and isinstance(current, list) and all(
            isinstance(x, dict) and "name" in x for x in [*frozen, *current]):
        frozen, current = {x["name"]: x for x in frozen}, {x["name"]: x for x in current}
    if isinstance(frozen, dict) and isinstance(current, dict):
        out = []
        for name in [*frozen, *(k for k in current if k not in frozen)]:
            sub = f"{key}.{name}" if key else str(name)
            if name not in current:
                out.append(f"{sub}: removed")
            elif name not in frozen:
                out.append(f"{sub}: added")
            else:
                out += changes(frozen[name], current[name], sub)
        return out
    return [] if frozen == current else [f"{key}: {json.dumps(frozen, default=str)} -> "
                                         f"{json.dumps(current, default=str)}"]


def _now() -> str:
    return time.strftime(TIME_FORMAT)


def _amendment_inputs_exist(study: Study, index: int) -> list[str]:
    """Why amendment ``index`` changes something whose inputs exist (``[]``: it only adds)."""
    amendment = study.spec.amendments[index]
    before = Study(study.path, study.text, study.data,
                   study.spec.model_copy(update={"amendments": study.spec.amendments[:index]}))
    before._plans = None  # type: ignore[attr-defined]
    problems = []
    # the rules govern the study's own cells: a reused grid's were run under another study's, and the audit holds
    # them to the new rules all the same (a reused grid on another CPU type is superseded, below, or fails it)
    own_cells = has_cells(before, [g.name for g in before.grids() if not g.reused])
    old_rules = before.rules().model_dump()
    for key, value in amendment.rules.items():
        if own_cells and old_rules.get(key) is not None and old_rules[key] != value:
            problems.append(f"rules.{key}: {old_rules[key]!r} -> {value!r}, but cells already exist")
    old_grids = {g.name: g for g in before.grids()}
    recorded_records = recorded_reads(study)
    for grid in amendment.grids:
        old = old_grids.get(grid.name)
        if old is None or not has_cells(before, [grid.name]):
            continue
        if not _supersedes_reused(old, grid):
            problems.append(f"grids.{grid.name}: its folder already holds cells")
        elif grid.name in _grids_read(before, recorded_records):
            problems.append(f"grids.{grid.name}: a recorded read took its cells, so it cannot be superseded")
    old_reads = before.reads()
    recorded = set(recorded_records)
    for kind in ("means", "ensembles", "comparisons", "thresholds"):
        names = {r.name: r for r in getattr(old_reads, kind)}
        for read in getattr(amendment.reads, kind):
            if read.name not in names or names[read.name] == read:
                continue
            if read.name in recorded:
                problems.append(f"reads.{kind}.{read.name}: already read and recorded")
            elif kind == "ensembles":
                folder = study.folder(study.grid(read.grid))
                if any(RunDir(folder).cell_path(m[-1]).exists() for m in read_members(before, names[read.name])):
                    problems.append(f"reads.{kind}.{read.name}: some of its members already ran")
            elif kind == "comparisons" and (read.arms or names[read.name].arms):
                if has_cells(study, grids := _own_grids(study, [(before, names[read.name]), (study, read)])):
                    problems.append(f"reads.{kind}.{read.name}: its grids already hold cells ({', '.join(grids)})")
            elif kind != "thresholds" and has_cells(before, [read.grid or before.grids()[0].name]):
                problems.append(f"reads.{kind}.{read.name}: its grid already holds cells")
    return problems


def _supersedes_reused(old: GridSpec, new: GridSpec) -> bool:
    """Whether ``new`` re-declares the reused grid ``old`` unchanged but for a reason it no longer counts: the one
    change allowed to a grid whose folder holds cells, since the study ran none of them."""
    return (old.reused is not None and old.superseded is None and new.superseded is not None
            and new.model_copy(update={"superseded": None}) == old)


def _grids_read(study: Study, recorded: dict[str, dict[str, Any]]) -> set[str]:
    """The grids whose cells a recorded read took: named in its inputs (``grid/cell id``) or its declared grid."""
    declared = {r.name: r for kind in ("means", "ensembles", "comparisons") for r in getattr(study.reads(), kind)}
    out = set()
    for name, record in recorded.items():
        out |= {str(i).split("/", 1)[0] for i in record.get("inputs") or [] if "/" in str(i)}
        read = declared.get(name)
        if read is not None and getattr(read, "grid", None) is not None:
            out.add(read.grid)
        elif read is not None:
            out.add(study.grids()[0].name)
    return out


def _own_grids(study: Study, reads: list[tuple[Study, ComparisonRead]]) -> list[str]:
    """The grids whose cells would decide comparisons given as arms: the study's own (a reused grid's cells exist
    before the study runs any), or every grid they read where all are reused."""
    grids = list(dict.fromkeys(str(arm.grid) for owner, read in reads for side in "ab"
                               for arm in comparison_arms(owner, read, side)))
    own = [name for name in grids if not study.grid(name).reused]
    return own or grids


def freeze(study: Study) -> dict[str, Any]:
    """Freeze ``study`` (or check it against its freeze) before any cell runs; returns the freeze record.

    Raises :class:`ConfigError` naming what changed when the grids, rules or reads differ from the frozen ones
    while cells exist, when a frozen amendment was edited, or when a new amendment changes something whose inputs
    exist."""
    path = freeze_path(study)
    state = read_freeze(study)
    parts = study.frozen_parts()
    cells = has_cells(study)
    digest = hashlib.sha256(study.text.encode()).hexdigest()
    copies = []
    if state is None or (not cells and changes(state["frozen"], parts)):
        when = study.spec.freeze.time if study.spec.freeze is not None else _now()
        copies.append("study.yaml")
        state = {"format": 1, "study": study.name, "sha256": digest, "time": when, "frozen": parts,
                 "hashes": {k: canonical_hash(v) for k, v in parts.items()}, "amendments": []}
    else:
        changed = changes(state["frozen"], parts)
        if changed:
            raise ConfigError(f"{study.where}: changed after cells exist (frozen {state['time']} in {path}): "
                              f"{'; '.join(changed)}; put the change in an amendment with its reason instead")
    amendments = [a.model_dump(mode="json") for a in study.spec.amendments]
    frozen_amendments = state["amendments"]
    if len(amendments) < len(frozen_amendments):
        raise ConfigError(f"{study.where}: amendments: {len(frozen_amendments)} were frozen, the file has "
                          f"{len(amendments)}; an amendment is never removed")
    for i, record in enumerate(frozen_amendments):
        if not amendment_kept(record, study.spec.amendments[i]):
            raise ConfigError(f"{study.where}: amendments[{i}] changed after its freeze ({record['time']}): "
                              f"{'; '.join(changes(record['amendment'], amendments[i])) or 'its content'}")
    for i in range(len(frozen_amendments), len(amendments)):
        problems = _amendment_inputs_exist(study, i)
        if problems:
            raise ConfigError(f"{study.where}: amendments[{i}] changes what already has inputs: "
                              f"{'; '.join(problems)}; an amendment may only add")
        copies.append(f"study.amendment-{i}.yaml")
        frozen_amendments.append({"sha256": canonical_hash(amendments[i]), "time": _now(), "copy": copies[-1],
                                  "reason": amendments[i]["reason"], "amendment": amendments[i]})
    state["sha256_now"] = digest
    path.parent.mkdir(parents=True, exist_ok=True)
    for name in copies:  # the file as each freeze saw it
        atomic_write_text(path.parent / name, study.text)
    atomic_write_json(path, state)
    return state


def freeze_times(study: Study, state: dict[str, Any] | None) -> dict[str, datetime]:
    """When each grid was frozen: the study's freeze (the file's own ``freeze`` for a migrated study), or the
    amendment that last declared the grid (its own ``freeze`` for a migrated amendment). A grid never frozen is
    absent."""
    base = study.spec.freeze.time if study.spec.freeze is not None else (state or {}).get("time")
    out = {g.name: parse_time(base) for g in study.spec.grids} if base else {}
    for i, amendment in enumerate(study.spec.amendments):
        records = (state or {}).get("amendments") or []
        if amendment.freeze is not None:  # a migrated amendment: when the plan's history says it was appended
            out.update({g.name: parse_time(amendment.freeze.time) for g in amendment.grids})
        elif i < len(records):
            out.update({g.name: parse_time(records[i]["time"]) for g in amendment.grids})
    return out



def freeze_status(study: Study) -> list[str]:
    """What ``study check`` says of the freeze: not frozen yet, or frozen and unchanged, or what changed since."""
    if study.spec.freeze is not None:
        return [f"  freeze: {study.spec.freeze.time} (written in the file"
                + (f"; {study.spec.freeze.source}" if study.spec.freeze.source else "") + ")"]
    state = read_freeze(study)
    if state is None:
        return ["  freeze: not frozen yet (`study run` freezes it before the first cell)"]
    changed = changes(state["frozen"], study.frozen_parts())
    if not changed:
        return [f"  freeze: {state['time']}; the grids, rules and reads are as frozen"]
    said = "`study run` will refuse it" if has_cells(study) else "no cell exists yet: `study run` freezes it anew"
    return [f"  freeze: {state['time']}; changed since: {'; '.join(changed)} ({said})"]
