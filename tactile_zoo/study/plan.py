"""A study's grids as the bench sees them: each grid's :class:`~tactile_zoo.bench.BenchConfig`, the cells it plans
(the config hash of every model and dataset, resolved as ``bench`` resolves them, without loading any data), and an
estimate of what they cost from cells that ran before.

The estimate: for each (model, dataset) of a grid, the cells found under the history folders (committed results,
read through :mod:`tactile_zoo.bench.records`) of the same model, dataset, recipe name and subset (``--quick`` or
not), ``ok``; their median time per epoch (the cell's own ``seconds``) times the epochs the grid plans
(``max_epochs``: an upper bound where early stopping ends a cell sooner), times the grid's folds and seeds. A pair
without such cells is said to have none, and left out of the total.
"""

from __future__ import annotations

import os
import statistics
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import registry
from ..bench.config import BenchConfig, merge_config, plan_cells
from ..bench.grid import cell_id, resolve_datasets, resolve_models
from ..bench.records import InvalidCell, cell_files, read_record
from ..engine.config import CellConfig, config_hash
from ..errors import ConfigError, TactileZooError
from ..recipe import recipe_name_of
from .schema import GridSpec, Study

__all__ = ["PlannedGrid", "bench_config", "import_plugins", "planned", "Estimate", "estimate", "history_records"]

#: settings a study's grid may not give: the study decides them (``out``: the grid's folder), or they would break a
#: rule (``force`` recomputes finished cells, reading their test splits again)
_REFUSED = {"out": "the study puts each grid in its own folder (give the grid a `folder`)",
            "force": "a study never recomputes a finished cell (its test split would be read again)"}


@dataclass
class PlannedGrid:
    """One grid's plan: its settings, the resolved models and datasets, and each pair's configuration and hash."""

    spec: GridSpec
    config: BenchConfig
    folder: Path
    models: list[str]
    datasets: list[str]
    configs: dict[tuple[str, str], CellConfig] = field(default_factory=dict)
    hashes: dict[tuple[str, str], str] = field(default_factory=dict)

    def cell_id_of(self, model: str, dataset: str, fold: int, seed: int) -> str:
        return cell_id(model, dataset, fold, seed, self.hashes[model, dataset])

    def cell_ids(self, folds: Iterable[int] = (0,)) -> list[str]:
        """The ids of the cells of ``folds`` (the grid's fold count comes from the data; callers pass what they
        know): one per model, dataset, fold and seed."""
        return [cell_id(m, d, f, s, self.hashes[m, d]) for d in self.datasets for m in self.models
                for f in folds for s in self.config.seeds]


def bench_config(study: Study, grid: GridSpec) -> BenchConfig:
    """The grid's bench settings as a :class:`BenchConfig` writing into its folder; a bad setting is a
    :class:`ConfigError` naming the file, the grid and the key."""
    where = f"{study.where}: grids.{grid.name}.settings"
    settings = grid.given()
    for key, why in _REFUSED.items():
        if key in settings:
            raise ConfigError(f"{where}.{key}: not a study setting: {why}")
    root = settings.get("root")
    if isinstance(root, str) and not Path(root).expanduser().is_absolute():
        settings["root"] = str(study.path.parent / root)  # a data home relative to the study file, as `results` is
    teachers = settings.get("teachers")
    if teachers and not Path(teachers["folder"]).expanduser().is_absolute():
        # distillation's teachers: a bench folder under the results folder, as a grid's `folder` is
        settings["teachers"] = {**teachers, "folder": str(study.results / teachers["folder"])}
    try:
        return merge_config({**settings, "out": str(study.folder(grid))}, {})
    except TactileZooError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def import_plugins(study: Study, config: BenchConfig) -> None:
    """Import the grid's plugin modules, found beside the study file as well as on the path."""
    for folder in (str(study.path.parent.resolve()), os.getcwd()):
        if folder not in sys.path:
            sys.path.append(folder)
    registry.import_plugin_modules(config.plugin_modules)


def planned(study: Study, grid: GridSpec) -> PlannedGrid:
    """The grid's models, datasets and each pair's resolved configuration and hash (no data is loaded)."""
    config = bench_config(study, grid)
    where = f"{study.where}: grids.{grid.name}.settings"
    try:
        import_plugins(study, config)
        models, datasets = resolve_models(config.models), resolve_datasets(config.datasets)
        plan = plan_cells(config, models, datasets)
    except TactileZooError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    out = PlannedGrid(grid, config, study.folder(grid), models, datasets, dict(plan.configs))
    out.hashes = {pair: config_hash(cfg) for pair, cfg in plan.configs.items()}
    return out


# ----------------------------------------------------------------------------------------------- the estimate
def history_records(folders: Iterable[Path]) -> list[dict[str, Any]]:
    """The valid ``ok`` cell records of every bench folder under ``folders`` (damaged files are skipped: an estimate
    is not a table)."""
    out = []
    for folder in folders:
        for path in cell_files(folder, recursive=True):
            rec = read_record(path)
            if not isinstance(rec, InvalidCell) and rec.get("status") == "ok":
                out.append(rec)
    return out


def _epochs(rec: dict[str, Any]) -> int:
    return max(1, int(rec.get("epochs_run") or 0) + len(rec.get("refit_curve") or []))


@dataclass
class Estimate:
    """CPU-hours per (grid, model, dataset) with the cells it rests on; ``None`` where no cell ran before."""

    rows: list[tuple[str, str, str, int, float | None, int]]  # grid, model, dataset, cells, hours, history cells

    @property
    def hours(self) -> float:
        return sum(h for *_, h, _ in self.rows if h is not None)

    @property
    def missing(self) -> list[tuple[str, str, str]]:
        return [(g, m, d) for g, m, d, _, h, _ in self.rows if h is None]

    def lines(self) -> list[str]:
        out = []
        for grid, model, dataset, cells, hours, found in self.rows:
            said = f"{hours:.3f} CPU-hours from {found} earlier cell(s)" if hours is not None else \
                "no earlier cell of this model, dataset and recipe: no estimate"
            out.append(f"  {grid}: {model} x {dataset}, {cells} cell(s): {said}")
        total = f"estimate: {self.hours:.3f} CPU-hours"
        if len(self.missing) == len(self.rows):
            total = "estimate: none (no pair of the grids has an earlier cell to measure by)"
        elif self.missing:
            total += f" for the pairs with earlier cells ({len(self.missing)} pair(s) without any are not counted)"
        return [*out, total]


def estimate(grids: list[PlannedGrid], history: list[dict[str, Any]], folds: dict[str, int] | None = None
             ) -> Estimate:
    """CPU-hours of ``grids`` from the ``history`` records (see the module docstring); ``folds``: the folds each
    dataset runs (default 1)."""
    per_epoch: dict[tuple[str, str, str, bool], list[float]] = {}
    for rec in history:
        cfg = rec.get("config") or {}
        key = (rec["model"], rec["dataset"], recipe_name_of(cfg), bool(cfg.get("subset")))
        per_epoch.setdefault(key, []).append(float(rec.get("seconds") or rec.get("train_seconds") or 0) / _epochs(rec))
    rows = []
    for grid in grids:
        for (model, dataset), cfg in grid.configs.items():
            n = len(grid.config.seeds) * (folds or {}).get(dataset, 1)
            found = per_epoch.get((model, dataset, cfg.recipe_name, bool(cfg.subset)), [])
            epochs = cfg.recipe.max_epochs + (cfg.recipe.max_epochs if cfg.refit else 0)
            hours = statistics.median(found) * epochs * n / 3600 if found else None
            rows.append((grid.spec.name, model, dataset, n, hours, len(found)))
    return Estimate(rows)


def check_lines(study: Study, plans: dict[str, PlannedGrid], history: Iterable[Path]) -> list[str]:
    """What ``study check`` prints after the file's summary: each grid's cells as ``bench --dry-run`` lists them
    (the datasets are probed), then the CPU-hour estimate from the cells under ``history`` and the study's own."""
    from ..bench.grid import build_grid

    lines: list[str] = []
    folds: dict[str, int] = {}
    for name, plan in plans.items():
        if plan.spec.superseded:
            lines.append(f"grid {name}: superseded ({plan.spec.superseded}); not run")
            continue
        try:
            grid = build_grid(plan.config)
        except TactileZooError as exc:
            raise ConfigError(f"{study.where}: grids.{name}.settings: {exc}") from None
        lines.append(f"grid {name} -> {plan.folder}")
        lines += [f"  {line}" for line in grid.describe()]
        lines += [f"    cell {cell.cell_id}" for cell in grid.cells]
        folds.update({info.name: len(info.folds) for info in grid.datasets})
    folders = [*history, study.results]
    records = history_records(folders)
    lines.append(f"earlier cells read for the estimate: {len(records)} under {', '.join(map(str, folders))}")
    reused = [name for name, p in plans.items() if p.spec.reused and not p.spec.superseded]
    if reused:
        lines.append(f"reused grid(s) {', '.join(reused)}: their cells are read, not run (not in the estimate)")
    lines += estimate([p for p in plans.values() if not p.spec.superseded and not p.spec.reused], records,
                      folds).lines()
    return lines
