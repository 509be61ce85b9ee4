"""``study audit``: were the study's rules kept? Each broken rule is a failure line naming the cell or the read.

The checks, over the cells of every grid that is not superseded (read through :mod:`tactile_zoo.bench.records`):

- **the freeze** came before every cell's start time (``started``; the grid's own freeze for an amended grid), and
  the file's grids, rules, reads and amendments are the ones frozen;
- **the test split**: each final cell read it exactly once (``test_reads`` 1), each tuning cell never (0; a
  ``tuning`` study allows tuning cells only); a ``reference`` cell reads it after every epoch by design, and is held
  to that count (``epochs_run``);
- **one CPU type** (name and torch's instruction-set capability), the declared one where ``rules.cpu`` names it;
- **config hashes**: every cell is one the grid plans (its model, dataset, seed and configuration hash); grids that
  share a folder (a trial's arms) each take the cells they plan;
- **cells present**: every grid's folder exists and holds cells of the grid (a misspelt folder would otherwise
  pass every check over no cell); a grid of a study frozen by ``study freeze`` or ``study run`` (not a migrated
  one) that holds no cell yet is reported as not run yet, a plan waiting for its cells;
- **the budget**: the cells' own ``seconds`` summed, at most ``rules.budget_cpu_hours``;
- **ensembles**: every declared member has run, and a recorded ensemble read exactly its declared members, from the
  cell files as they are now (and every recorded read's input files are unchanged); a recorded comparison given as
  arms, likewise its declared cells, each in its grid's folder.

A grid marked ``reused`` holds cells the study reads but did not run (earlier evidence, a baseline arm): neither
the freeze nor the test-split rule applies to them (their test reads are the running study's to audit; a reused
final cell is a fact the study's notes state), and their time is not the study's cost; the one-CPU-type rule holds
for them too (their scores are compared with the study's). A folder the study only reuses may hold other cells:
those are not the study's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..bench.records import InvalidCellsError, run_records
from ..bench.rundir import RunDir
from .checks import plans, read_members
from .freeze import TIME_FORMAT, changes, freeze_times, parse_time, read_freeze
from .reads import cell_digest, comparison_inputs, input_path, recorded_reads
from .schema import Study, amendment_kept

__all__ = ["AuditResult", "audit", "cpu_type", "cpu_types", "cpu_type_clash", "study_records", "cpu_hours"]


def cpu_type(record: dict[str, Any]) -> str:
    """A cell's CPU type: the processor's name and torch's instruction-set capability."""
    return f"{record.get('cpu', '?')} ({(record.get('cpu_isa') or {}).get('capability', '?')})"


def cpu_types(records: list[dict[str, Any]]) -> list[str]:
    """The CPU types ``records`` ran on, sorted: seeds pool only within one type (the same seed can train
    differently on another)."""
    return sorted({cpu_type(r) for r in records})


def cpu_type_clash(records: Sequence[dict[str, Any]]) -> str | None:
    """The one-CPU-type check, the one copy of it (a study's audit, a published table's pooled seeds, ``tools.audit``'s
    planned round): ``None`` when ``records`` ran on one CPU type or none, else ``"N CPU types (A; B)"``."""
    types = cpu_types(list(records))
    return f"{len(types)} CPU types ({'; '.join(types)})" if len(types) > 1 else None


def cpu_hours(records: list[dict[str, Any]]) -> float:
    """The cells' own times (``seconds``, else ``train_seconds``), summed, in hours: one torch thread each."""
    return sum(float(r.get("seconds") or r.get("train_seconds") or 0) for r in records) / 3600


@dataclass
class AuditResult:
    """The audit's lines (what it found) and failures (each broken rule, one line)."""

    lines: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    rules: dict[str, bool] = field(default_factory=dict)  # rule -> held

    def fail(self, rule: str, text: str) -> None:
        self.failures.append(text)
        self.rules[rule] = False


def _grid_of(record: dict[str, Any], grids: list[Any], all_plans: dict[str, Any]) -> Any:
    """Which of the grids sharing a folder planned ``record`` (its model, dataset and configuration hash); when none
    did, the first grid the study ran there (its audit then names the cell as not the grid's), or ``None`` where
    the study only reuses the folder (its other cells are not the study's)."""
    def plans_it(grid: Any) -> bool:  # a reused grid takes its own seeds only (the folder is another study's)
        plan = all_plans[grid.name]
        return plan.hashes.get((record["model"], record["dataset"])) == record.get("config_hash") and (
            not grid.reused or record.get("seed") in plan.config.seeds)

    return next((g for g in grids if plans_it(g)), next((g for g in grids if not g.reused), None))


def study_records(study: Study, read: Callable[[Path], list[dict[str, Any]]] = run_records
                  ) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """Per grid that is not superseded, its cell records; and a line per grid folder with damaged cell files. Grids
    may share a folder (a trial's arms): each cell goes to the grid that plans it. ``read`` reads a folder's records
    (a caller that reads the same folders again passes a memo of :func:`run_records`)."""
    all_plans = plans(study)
    by_folder: dict[str, list[Any]] = {}
    for grid in study.grids():
        by_folder.setdefault(str(study.folder(grid).resolve()), []).append(grid)
    out: dict[str, list[dict[str, Any]]] = {g.name: [] for g in study.grids() if not g.superseded}
    damaged = []
    for grids in by_folder.values():
        if all(g.superseded for g in grids):
            continue
        try:
            records = read(study.folder(grids[0]))
        except InvalidCellsError as exc:
            damaged.append(str(exc))
            continue
        for record in records:
            grid = _grid_of(record, grids, all_plans)
            if grid is None or grid.superseded:
                continue
            out[grid.name].append(record)
    return out, damaged


def _expected_reads(record: dict[str, Any]) -> int:
    evaluation = (record.get("config") or {}).get("evaluation") or "validation"
    return 0 if evaluation == "tuning" else int(record.get("epochs_run") or 0) if evaluation == "reference" else 1


def audit(study: Study, records: tuple[dict[str, list[dict[str, Any]]], list[str]] | None = None) -> AuditResult:
    """Every check of the module docstring; ``failures`` is empty when the study kept its rules. ``records``: what
    :func:`study_records` gives for the study, when the caller has read it already (read here otherwise)."""
    result = AuditResult(rules={k: True for k in ("freeze", "test split", "one CPU type", "config hashes",
                                                  "cells present", "budget", "ensemble members")})
    state = read_freeze(study)
    times = freeze_times(study, state)
    rules = study.rules()
    if not study.spec.pre_registered:
        result.lines.append("not pre-registered: the cells ran before any plan; the freeze checks are left out")
    elif not times:
        result.fail("freeze", f"{study.where}: never frozen (no {study.results / 'study' / 'freeze.json'}); "
                              f"`tactile-zoo study run` freezes it before the first cell")
    if state is not None:
        changed = changes(state["frozen"], study.frozen_parts())
        amended = [f"amendments[{i}]" for i, record in enumerate(state.get("amendments") or [])
                   if i >= len(study.spec.amendments)
                   or not amendment_kept(record, study.spec.amendments[i])]
        unfrozen = [f"amendments[{i}] (never frozen)"
                    for i in range(len(state.get("amendments") or []), len(study.spec.amendments))]
        if changed or amended or unfrozen:
            result.fail("freeze", f"{study.where}: not the file that was frozen ({state['time']}): "
                                  f"{'; '.join([*changed, *amended, *unfrozen])}")
    by_grid, damaged = records if records is not None else study_records(study)
    for text in damaged:
        result.fail("config hashes", text)
    everything: list[dict[str, Any]] = []
    own: list[dict[str, Any]] = []
    all_plans = plans(study)
    waiting: set[str] = set()  # grids of a frozen plan that hold no cell yet
    for name, records in by_grid.items():
        plan = all_plans[name]
        reused = plan.spec.reused
        frozen = times.get(name)
        ok = [r for r in records if r.get("status") == "ok"]
        everything += records
        own += [] if reused else records
        result.lines.append(f"grid {name}: {len(ok)} ok cell(s) of {len(plan.cell_ids())} planned per fold, in "
                            f"{plan.folder}" + (" (reused)" if reused else ""))
        ran_by = plan.spec.ran_by
        if ran_by is not None and {r["cell_id"] for r in ok} < set(plan.cell_ids()):
            # another study runs this grid (checked to have it): until its cells are all in, its reads wait
            result.lines.append(f"grid {name}: not run yet (frozen in {ran_by}, which runs it)")
            waiting.add(name)
        elif not records and not reused and state is not None and study.spec.freeze is None:
            # frozen by `study run` or `study freeze` and not run yet: a plan, not a broken rule (a migrated
            # study points at cells that exist, so there an empty grid is a misspelt folder)
            when = frozen.strftime(TIME_FORMAT) if frozen is not None else state["time"]
            result.lines.append(f"grid {name}: not run yet (frozen {when})")  # an amended grid: its amendment's
            waiting.add(name)
        elif not plan.folder.is_dir():
            result.fail("cells present", f"grid {name}: its folder {plan.folder} does not exist")
        elif not records:
            result.fail("cells present", f"grid {name}: {plan.folder} holds no cell of the grid")
        for rec in records:
            where = f"grid {name}: cell {rec['cell_id']}"
            want = plan.hashes.get((rec["model"], rec["dataset"]))
            if want is None:
                result.fail("config hashes", f"{where}: {rec['model']} on {rec['dataset']} is not a pair of the grid")
            elif rec["config_hash"] != want:
                result.fail("config hashes", f"{where}: config hash {rec['config_hash']} is not the grid's ({want} "
                                             f"for {rec['model']} on {rec['dataset']})")
            elif rec["seed"] not in plan.config.seeds:
                result.fail("config hashes", f"{where}: seed {rec['seed']} is not a seed of the grid")
            if rec.get("status") != "ok":
                continue
            if study.spec.pre_registered and frozen is not None and not reused:
                started = rec.get("started")
                if not started or parse_time(started) < frozen:
                    result.fail("freeze", f"{where}: started {started or 'at an unrecorded time'}, before the freeze "
                                          f"({frozen.strftime('%Y-%m-%dT%H:%M:%S%z')})")
            if reused:  # read here, run by another study: its test reads are that study's to audit
                continue
            evaluation = (rec.get("config") or {}).get("evaluation") or "validation"
            reads, expected = rec.get("test_reads"), _expected_reads(rec)
            if rules.test_split == "never" and evaluation != "tuning":
                result.fail("test split", f"{where}: a {evaluation} cell in a tuning study (rules.test_split: never)")
            elif reads != expected:
                kind = "tuning" if evaluation == "tuning" else "final"
                result.fail("test split", f"{where}: a {kind} cell that read its test split {reads} time(s), not "
                                          f"{'never' if expected == 0 else 'once' if expected == 1 else expected}")
    finished = [r for r in everything if r.get("status") == "ok"]
    types = cpu_types(finished)
    result.lines.append(f"CPU types: {'; '.join(types) or 'no cell yet'}")
    if clash := cpu_type_clash(finished):
        result.fail("one CPU type", f"cells on {clash}; a study runs on one")
    if rules.cpu and types and any(not t.startswith(rules.cpu) for t in types):
        result.fail("one CPU type", f"cells on {'; '.join(types)}; rules.cpu declares {rules.cpu}")
    hours = cpu_hours(own)
    result.lines.append(f"cost: {hours:.3f} CPU-hours"
                        + (f" of a budget of {rules.budget_cpu_hours:g}" if rules.budget_cpu_hours else "")
                        + (" (reused cells not counted)" if len(own) < len(everything) else ""))
    if rules.budget_cpu_hours is not None and hours > rules.budget_cpu_hours:
        result.fail("budget", f"budget exceeded: {hours:.3f} CPU-hours spent, {rules.budget_cpu_hours:g} declared")
    _ensembles(study, by_grid, result, waiting)
    return result


def _ensembles(study: Study, by_grid: dict[str, list[dict[str, Any]]], result: AuditResult,
               waiting: set[str]) -> None:
    recorded = recorded_reads(study)
    for read in study.reads().ensembles:
        grid = read.grid or study.grids()[0].name
        declared = [m[-1] for m in read_members(study, read)]
        have = {r["cell_id"] for r in by_grid.get(grid, []) if r.get("status") == "ok"}
        missing = [i for i in declared if i not in have]
        if missing and grid in waiting:
            result.lines.append(f"ensemble {read.name}: waits for its members (grid {grid} not run yet)")
        elif missing:
            result.fail("ensemble members", f"ensemble {read.name}: declared member(s) not present: "
                                            f"{', '.join(missing)}")
        entry = recorded.get(read.name)
        if entry is None:
            continue
        for cell in entry.get("inputs", []):
            if cell not in declared:
                result.fail("ensemble members", f"ensemble {read.name}: member {cell} was not declared")
        folder = plans(study)[grid].folder
        for cell, digest in (entry.get("digests") or {}).items():
            path = RunDir(folder).cell_path(cell)
            if path.is_file() and cell_digest(path) != digest:
                result.fail("ensemble members", f"ensemble {read.name}: member {cell} changed after the read was "
                                                f"recorded")
    _comparisons(study, recorded, result)
    folders = list(dict.fromkeys(plans(study)[g.name].folder for g in study.grids()))
    for read in study.reads().validation:
        for cell, digest in ((recorded.get(read.name) or {}).get("digests") or {}).items():
            path = next((p for p in (RunDir(f).cell_path(cell) for f in folders) if p.is_file()), None)
            if path is not None and cell_digest(path) != digest:
                result.fail("ensemble members", f"validation read {read.name}: input {cell} changed after the read "
                                                f"was recorded")



def _comparisons(study: Study, recorded: dict[str, dict[str, Any]], result: AuditResult) -> None:
    """A recorded comparison given as arms read its declared cells (``grid/cell id``), from files unchanged since."""
    folders = {g.name: plans(study)[g.name].folder for g in study.grids()}
    for read in study.reads().comparisons:
        entry = recorded.get(read.name)
        if entry is None or not read.arms:
            continue
        declared = {cell for cells in comparison_inputs(study, read).values() for cell in cells}
        for cell in entry.get("inputs", []):
            if cell not in declared:
                result.fail("ensemble members", f"comparison {read.name}: input {cell} was not declared")
        for cell, digest in (entry.get("digests") or {}).items():
            if cell not in declared:
                continue
            path = input_path(folders, cell)
            if not path.is_file():
                result.fail("ensemble members", f"comparison {read.name}: input {cell} is gone ({path})")
            elif cell_digest(path) != digest:
                result.fail("ensemble members", f"comparison {read.name}: input {cell} changed after the read was "
                                                f"recorded")
