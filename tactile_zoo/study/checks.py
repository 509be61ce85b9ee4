"""What a study file must say consistently, checked when it is read (:func:`load_study`): unique names,
grids the bench accepts, a tuning study whose every cell is a tuning cell, and reads that name a grid, its models,
its datasets and its seeds. Each error names the file and the key."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .plan import PlannedGrid, planned
from .schema import READ_KINDS, ComparisonArm, ComparisonRead, EnsembleRead, Members, Study, parse_study

__all__ = ["load_study", "check_study", "read_members", "comparison_arms", "plans", "describe"]

#: the (page, block, table) parts whose publications may name ``models``: their rows read the claiming study's cells
CLAIMABLE = {("README.md", "headline", "recipe"), ("docs/published-results.md", "ours", "full")}
#: the statistics a threshold may read from each kind of read
_STATISTICS = {"means": ("accuracy", "low", "high"), "ensembles": ("accuracy", "low", "high"),
               "comparisons": ("difference", "low", "high", "p_value"), "validation": ("mean", "median"),
               "validation against": ("mean", "median", "difference", "improved")}


def plans(study: Study) -> dict[str, PlannedGrid]:
    """Each grid's :class:`PlannedGrid`, computed once per study."""
    cached = getattr(study, "_plans", None)
    if cached is None:
        cached = {grid.name: planned(study, grid) for grid in study.grids()}
        study._plans = cached  # type: ignore[attr-defined]
    return cached


def _twice(names: list[str]) -> list[str]:
    return sorted(name for name, n in Counter(names).items() if n > 1)


def read_members(study: Study, read: EnsembleRead) -> list[tuple[str, str, int, int, str]]:
    """The declared members of an ensemble: ``(model, dataset, fold, seed, cell id)`` each, in declared order."""
    plan = plans(study)[read.grid or study.grids()[0].name]
    return [(m.model, read.dataset, m.fold, seed, plan.cell_id_of(m.model, read.dataset, m.fold, seed))
            for m in read.members for seed in (m.seeds if m.seeds is not None else plan.config.seeds)]


def _check_selection(study: Study, key: str, grid: str | None, dataset: str, models: list[str],
                     members: list[Members] | None = None, seeds: list[int] | None = None) -> None:
    names = [g.name for g in study.grids()]
    if grid is None and len(names) > 1:
        raise ConfigError(f"{study.where}: {key}.grid is required: the study has {len(names)} grids "
                          f"({', '.join(names)})")
    if grid is not None and grid not in names:
        raise ConfigError(f"{study.where}: {key}.grid {grid!r} names no grid of the study ({', '.join(names)})")
    plan = plans(study)[grid or names[0]]
    if dataset not in plan.datasets:
        raise ConfigError(f"{study.where}: {key}.dataset {dataset!r} is not a dataset of grid {plan.spec.name} "
                          f"({', '.join(plan.datasets)})")
    for model in models:
        if model not in plan.models:
            raise ConfigError(f"{study.where}: {key}: model {model!r} is not a model of grid {plan.spec.name} "
                              f"({', '.join(plan.models)})")
    for i, member in enumerate(members or []):
        extra = sorted(set(member.seeds or []) - set(plan.config.seeds))
        if extra:
            raise ConfigError(f"{study.where}: {key}.members[{i}].seeds {extra} are not seeds of grid "
                              f"{plan.spec.name} ({plan.config.seeds})")
    extra = sorted(set(seeds or []) - set(plan.config.seeds))
    if extra:
        raise ConfigError(f"{study.where}: {key}.seeds {extra} are not seeds of grid {plan.spec.name}")


def load_study(path: str | Path) -> Study:
    """Read and check the study file at ``path``: a :class:`ConfigError` names the file and the key of the first
    problem (the YAML, the study's shape, a grid's bench settings, a read that names no grid, model or seed of it)."""
    study = parse_study(path)
    check_study(study)
    return study


def _check_ran_by(study: Study, plan: PlannedGrid) -> None:
    """A grid ``ran_by`` another study is reused, and that study has a grid (not superseded) that runs its cells: the
    same folder and, for each of its pairs, the same configuration and its seeds."""
    key = f"{study.where}: grids.{plan.spec.name}.ran_by"
    if not plan.spec.reused:
        raise ConfigError(f"{key}: only a reused grid (`reused`: why) is run by another study")
    path = study.path.parent / str(plan.spec.ran_by)
    if not path.is_file():
        raise ConfigError(f"{key}: no study file {path}")
    other = load_study(path)
    for grid in other.grids():
        theirs = plans(other)[grid.name]
        if grid.superseded or theirs.folder.resolve() != plan.folder.resolve():
            continue
        missing = [f"{m} on {d}" for (m, d), h in plan.hashes.items() if theirs.hashes.get((m, d)) != h]
        seeds = sorted(set(plan.config.seeds) - set(theirs.config.seeds))
        if missing or seeds:
            raise ConfigError(f"{key}: grid {grid.name} of {path} runs {plan.folder} but not "
                              + "; ".join([*(f"{x} as configured here" for x in missing),
                                           *([f"seed(s) {seeds}"] if seeds else [])]))
        return
    raise ConfigError(f"{key}: {path} has no grid that runs {plan.folder}")


def check_study(study: Study) -> None:
    """Raise :class:`ConfigError` at the first inconsistency (see the module docstring)."""
    where = study.where
    grids = [g.name for g in study.spec.grids]
    for name in _twice(grids):
        raise ConfigError(f"{where}: grids: the name {name!r} is given twice")
    reads = study.reads()
    kinds: dict[str, str] = {}
    for kind in READ_KINDS:
        for read in getattr(reads, kind):
            if read.name in kinds:
                raise ConfigError(f"{where}: reads: the name {read.name!r} is declared twice")
            kinds[read.name] = kind
    for name in _twice([t.name for t in reads.thresholds]):
        raise ConfigError(f"{where}: reads.thresholds: the name {name!r} is declared twice")
    all_plans = plans(study)
    _check_shared_folders(study, all_plans)
    for plan in all_plans.values():
        if plan.spec.ran_by is not None:
            _check_ran_by(study, plan)
    rules = study.rules()
    if rules.test_split == "never":
        for plan in all_plans.values():
            if plan.spec.reused:  # cells the study reads but did not run: each held to its own evaluation
                continue
            for (model, dataset), cfg in plan.configs.items():
                if cfg.evaluation != "tuning":
                    raise ConfigError(f"{where}: grids.{plan.spec.name}.settings: {model} on {dataset} runs under "
                                      f"evaluation {cfg.evaluation!r}, which reads the test split; rules.test_split "
                                      f"is 'never' (a tuning study): set evaluation: tuning")
    for read in reads.means:
        _check_selection(study, f"reads.means.{read.name}", read.grid, read.dataset, [read.model], seeds=read.seeds)
    for read in reads.ensembles:
        key = f"reads.ensembles.{read.name}"
        _check_selection(study, key, read.grid, read.dataset, [m.model for m in read.members], read.members)
        ids = [member[-1] for member in read_members(study, read)]
        for twice in _twice(ids):
            raise ConfigError(f"{where}: {key}.members: the cell {twice} is named twice")
    for read in reads.comparisons:
        if read.arms:
            _check_arms(study, read)
            continue
        _check_selection(study, f"reads.comparisons.{read.name}", read.grid, read.dataset, [read.a, read.b])
        if read.a == read.b:
            raise ConfigError(f"{where}: reads.comparisons.{read.name}: a and b are both {read.a!r}")
    _check_validation(study, reads)
    for threshold in reads.thresholds:
        key = f"reads.thresholds.{threshold.name}"
        for name in [threshold.read] if isinstance(threshold.read, str) else threshold.read:
            if name not in kinds:
                raise ConfigError(f"{where}: {key}.read {name!r} names no declared mean, ensemble, comparison or "
                                  f"validation read ({', '.join(sorted(kinds)) or 'none declared'})")
            kind = kinds[name]
            if kind == "validation" and next(r for r in reads.validation if r.name == name).against is not None:
                kind = "validation against"
            allowed = _STATISTICS[kind]
            if threshold.statistic not in allowed:
                label = "validation read" if kind.startswith("validation") else kind[:-1]
                raise ConfigError(f"{where}: {key}.statistic {threshold.statistic!r}: a {label} gives "
                                  f"{', '.join(allowed)}")
    thresholds = {t.name for t in reads.thresholds}
    for name in _twice([d.name for d in reads.decisions]):
        raise ConfigError(f"{where}: reads.decisions: the name {name!r} is declared twice")
    for decision in reads.decisions:
        if decision.name in kinds or decision.name in thresholds:
            raise ConfigError(f"{where}: reads.decisions: the name {decision.name!r} is declared twice")
        for name in decision.all_of:
            if name not in thresholds:
                raise ConfigError(f"{where}: reads.decisions.{decision.name}.all_of: {name!r} names no declared "
                                  f"threshold ({', '.join(sorted(thresholds)) or 'none declared'})")
    known = set(kinds) | thresholds | {d.name for d in reads.decisions}
    for i, publication in enumerate(study.spec.publishes):
        if publication.grid is not None and publication.grid not in [g.name for g in study.grids()]:
            raise ConfigError(f"{where}: publishes[{i}].grid {publication.grid!r} names no grid of the study")
        for name in publication.reads:
            if name not in known:
                raise ConfigError(f"{where}: publishes[{i}].reads: {name!r} names no declared read")
        card = (publication.where, publication.block) == ("docs/models.md", "cards")
        if card and (not publication.models or not publication.table):
            raise ConfigError(f"{where}: publishes[{i}]: a model card row names its `table` (the row's label) and "
                              f"the `models` whose cards it joins")
        variant = (publication.where, publication.block) == ("docs/published-results.md", "ours") \
            and publication.table not in (None, "full", "kfold")
        if publication.models and not card and not variant and \
                (publication.where, publication.block, publication.table) not in CLAIMABLE:
            raise ConfigError(f"{where}: publishes[{i}].models: only the README headline's `recipe` part, "
                              f"docs/published-results.md's `ours` `full` part and docs/models.md's `cards` take "
                              f"models (the rows a study's cells stand for)")
        planned = {m for plan in all_plans.values() if not plan.spec.superseded for m in plan.models}
        for name in publication.models:
            if name not in planned:
                raise ConfigError(f"{where}: publishes[{i}].models: {name!r} is not a model of the study's grids "
                                  f"({', '.join(sorted(planned))})")


def comparison_arms(study: Study, read: ComparisonRead, side: str) -> list[ComparisonArm]:
    """Side ``side`` (``a`` or ``b``) of a comparison as arms, each with its grid: a model's name is that model's
    cells in the read's grid (the study's only grid by default)."""
    value, grid = getattr(read, side), read.grid or study.grids()[0].name
    if isinstance(value, str):
        return [ComparisonArm(grid=grid, model=value)]
    return [arm if arm.grid is not None else arm.model_copy(update={"grid": grid}) for arm in value]


def _check_arms(study: Study, read: ComparisonRead) -> None:
    """A comparison given as arms: each arm names a grid of the study (or the read does), a model, dataset and seeds
    of it; a side selects each seed once (its cells pair by fold and seed), and no cell is on both sides."""
    key = f"reads.comparisons.{read.name}"
    cells: dict[str, dict[tuple[str, str], str]] = {}  # side -> {(folder, fold-0 cell id): its grid}
    for side in ("a", "b"):
        value = getattr(read, side)
        keyed = [f"{key}.{side}"] if isinstance(value, str) else [f"{key}.{side}[{i}]" for i in range(len(value))]
        for arm_key, arm in zip(keyed, [value] if isinstance(value, str) else value, strict=True):
            if isinstance(arm, str):
                _check_selection(study, key, read.grid, read.dataset, [arm])
            else:
                _check_selection(study, arm_key, arm.grid or read.grid, read.dataset, [arm.model], seeds=arm.seeds)
        seeds: dict[int, str] = {}
        cells[side] = {}
        for arm_key, arm in zip(keyed, comparison_arms(study, read, side), strict=True):
            plan = plans(study)[str(arm.grid)]
            for seed in arm.seeds if arm.seeds is not None else plan.config.seeds:
                if seed in seeds:
                    raise ConfigError(f"{study.where}: {arm_key}: seed {seed} is also selected by {seeds[seed]}: a "
                                      f"side holds one cell per fold and seed (its cells pair by them)")
                seeds[seed] = arm_key
                cells[side][str(plan.folder.resolve()), plan.cell_id_of(arm.model, read.dataset, 0, seed)] = \
                    str(arm.grid)
    for folder, cell in sorted(cells["a"].keys() & cells["b"].keys()):
        raise ConfigError(f"{study.where}: {key}: a and b both select the cell {cell} (grid {cells['a'][folder, cell]}"
                          f"): a comparison pairs two different cells")


def _check_validation(study: Study, reads: Any) -> None:
    """Each validation read names a grid, model, dataset and seeds of the study; its other arm likewise, and not
    the read's own."""
    for read in reads.validation:
        key = f"reads.validation.{read.name}"
        _check_selection(study, key, read.grid, read.dataset, [read.model], seeds=read.seeds)
        against = read.against
        if against is None:
            continue
        _check_selection(study, f"{key}.against", against.grid or read.grid, read.dataset,
                         [against.model or read.model], seeds=against.seeds)
        if (against.grid or read.grid, against.model or read.model, against.seeds) == \
                (read.grid, read.model, read.seeds):
            raise ConfigError(f"{study.where}: {key}.against is the read's own arm (name another grid, model or "
                              f"seeds)")


def _check_shared_folders(study: Study, all_plans: dict[str, PlannedGrid]) -> None:
    """Grids may share a bench folder (a trial's arms, run one command each into one folder), as long as no cell
    could belong to two of them: no two plan the same model and dataset with the same configuration."""
    owner: dict[tuple[str, str, str, str], str] = {}
    for name, plan in all_plans.items():
        folder = str(plan.folder.resolve())
        for (model, dataset), digest in plan.hashes.items():
            other = owner.setdefault((folder, model, dataset, digest), name)
            if other != name:
                raise ConfigError(f"{study.where}: grids {other} and {name} share the folder {plan.folder} and both "
                                  f"plan {model} on {dataset} as configuration {digest}: whose cells are they?")


def describe(study: Study) -> list[str]:
    """The lines ``study check`` prints about the file (the cells come from the bench's grid, printed beside)."""
    rules = study.rules()
    lines: list[Any] = [f"study {study.name}: {study.spec.question}",
                        f"  results folder: {study.results}",
                        f"  rules: one CPU type ({rules.cpu or 'the first cell decides'}); budget "
                        f"{'none' if rules.budget_cpu_hours is None else f'{rules.budget_cpu_hours:g} CPU-hours'}; "
                        f"test split read {'never (tuning)' if rules.test_split == 'never' else 'once per cell'}"]
    if not study.spec.pre_registered:
        lines.append("  not pre-registered: its cells ran before any plan")
    reads = study.reads()
    for kind in (*READ_KINDS, "thresholds", "decisions"):
        names = [r.name for r in getattr(reads, kind)]
        if names:
            lines.append(f"  declared {kind}: {', '.join(names)}")
    return lines
