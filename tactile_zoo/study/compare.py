"""``tactile-zoo study compare FILE``: a new model set against the zoo's published cells, no baseline retrained.

The file is a study file (:mod:`.schema`) whose grids train only the user's models, with one more section::

    against:
      set: published        # a published set (:mod:`.published`): ``published`` (the newest packaged one), its id
                            # (``table1-v1``, to cite), or the path of a set file (relative to this file)
      recipe: full          # which of the set's recipes to compare with (required when it holds several)
      baselines: null       # the set's models to compare with (default: every one on the dataset)
      seeds: subset         # subset: every (fold, seed) of yours must be published; equal: the same set exactly
      tuning: null          # your tuning study (a study file of ``evaluation: tuning`` cells), to state your tuning
      level: 0.95           # of the intervals

Before any cell trains, :func:`plan_comparison` refuses, naming the difference, a grid that cannot be compared:

- a dataset the set has no cells of (with that recipe);
- another dataset revision (the ``dataset_revision`` every config hash carries);
- a different protocol: the dataset's protocol (``fixed``, ``objects``, ``kfold``), the evaluation (``final``,
  ``validation``...), ``subset`` (``--quick``), ``refit`` or the early-classification prefixes;
- missing seeds: a (fold, seed) of the grid that a baseline has no published cell of (``seeds: subset``), or one a
  baseline has and the grid lacks (``seeds: equal``);
- a mismatched split: the grid's test split (loaded with its dataset keywords, as its cells will load it) holds
  other recordings than the published cells were scored on (their split identity, :func:`.published.split_identity`).

Then :func:`~.run.run_study` trains the grids (resumable, the test split read once), the finished cells' test sets
are checked once more against the published ones, and :mod:`.compare_report` writes the report. A baseline scored
on the same recordings cut into other samples (BioTac-DoS's sliding windows for SGnet and ConvLSTM) is shown beside
yours, and said to be not paired; it is never paired sample by sample.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError

from .._yaml import read_yaml_file
from ..bench.grid import build_grid
from ..engine.build import load_splits
from ..engine.tensors import take
from ..errors import ConfigError, ResultsError, TactileZooError
from .checks import check_study, plans
from .published import PublishedSet, load_set, split_identity
from .schema import Study, StudyFile, _describe

__all__ = ["Against", "Pairing", "Comparison", "load_comparison", "plan_comparison", "recordings_identity",
           "check_finished", "seed_list"]


class Against(BaseModel):
    """The ``against`` section of a comparison study (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    set: Annotated[str, Field(min_length=1)] = "published"
    recipe: Annotated[str, Field(min_length=1)] | None = None
    baselines: Annotated[list[str], Field(min_length=1)] | None = None
    seeds: Literal["subset", "equal"] = "subset"
    tuning: Annotated[str, Field(min_length=1)] | None = None
    level: Annotated[float, Strict(), Field(gt=0, lt=1)] = 0.95


def load_comparison(path: str | Path) -> tuple[Study, Against | None]:
    """The study file at ``path`` and its ``against`` section (``None`` when it has none), each checked; the other
    study commands read a comparison study through here too (they ignore ``against``)."""
    path = Path(path)
    data = read_yaml_file(path, str(path))
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping (study, question, grids, against, ...), got "
                          f"{type(data).__name__}")
    against = None
    if "against" in data:
        raw = data.pop("against")
        if not isinstance(raw, dict):
            raise ConfigError(f"{path}: against must be a mapping (set, recipe, baselines, seeds, tuning, level), "
                              f"got {raw!r}")
        try:
            against = Against.model_validate(raw)
        except ValidationError as exc:
            error = exc.errors(include_url=False)[0]
            key = ".".join(str(part) for part in ("against", *error["loc"]))
            raise ConfigError(f"{path}: {key}: {error['msg']}, got {error.get('input')!r}") from None
    try:
        spec = StudyFile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, str(path))) from None
    # ``against`` goes back into the study's data, so that the freeze fixes it with the grids (a set or baselines
    # changed after the cells ran are refused by ``run``, as a changed grid is)
    study = Study(path, path.read_text(encoding="utf-8"), data if against is None else {**data, "against": raw}, spec)
    check_study(study)
    return study, against


def seed_list(seeds: list[int] | set[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    runs: list[list[int]] = []
    for seed in sorted(seeds):
        if runs and runs[-1][1] == seed - 1:
            runs[-1][1] = seed
        else:
            runs.append([seed, seed])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def recordings_identity(dataset: str, split: str, targets: list[int], groups: list[Any] | None) -> str:
    """16 hex digits naming the test *recordings* (each with its class), whatever samples they are cut into."""
    pairs = sorted({(str(g), int(t)) for g, t in zip(groups if groups is not None else range(len(targets)),
                                                     targets, strict=True)})
    blob = json.dumps([dataset, split, pairs], separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass
class TestSet:
    identity: str
    recordings: str
    samples: int
    units: int

    def describe(self) -> str:
        return f"{self.samples} samples of {self.units} recordings (split identity {self.identity})"


def _published_test_set(pset: PublishedSet, cell: dict[str, Any], split: str = "test") -> TestSet:
    ident = cell["splits"][split]["test_set"]
    test_set = pset.data["test_sets"][ident]
    groups = test_set["groups"]
    return TestSet(ident, recordings_identity(cell["dataset"], split, test_set["targets"], groups), test_set["n"],
                   len(set(groups)) if groups is not None else test_set["n"])


def _test_set(dataset: str, split: str, targets: list[int], groups: list[Any] | None) -> TestSet:
    shared = groups if groups is not None and len(set(groups)) < len(groups) else None  # as the worker stores them
    return TestSet(split_identity(dataset, split, targets, shared), recordings_identity(dataset, split, targets,
                                                                                        shared),
                   len(targets), len(set(shared)) if shared is not None else len(targets))


@dataclass
class Pairing:
    """One model of the user's on one dataset of one grid, and the baselines it is set against."""

    grid: str
    model: str
    dataset: str
    keys: list[tuple[int, int]]  # (fold, seed) of its cells
    baselines: dict[str, list[dict[str, Any]]]  # baseline model -> its published cells at ``keys``
    paired: dict[str, bool] = field(default_factory=dict)  # baseline -> scored on the same samples
    test_sets: dict[int, TestSet] = field(default_factory=dict)  # fold -> the user's test set


@dataclass
class Comparison:
    study: Study
    against: Against
    set: PublishedSet
    recipe: str
    pairings: list[Pairing]


def _refuse(study: Study, what: str, text: str) -> ConfigError:
    return ConfigError(f"{study.where}: refused, {what}: {text}. Nothing was trained; nothing is compared.")


def _recipe(study: Study, against: Against, pset: PublishedSet) -> str:
    recipes = sorted({c["recipe_name"] for c in pset.cells})
    if against.recipe is None:
        if len(recipes) > 1:
            raise ConfigError(f"{study.where}: against.recipe is required: the set {pset.set_id} holds the "
                              f"recipes {', '.join(recipes)}")
        return recipes[0]
    if against.recipe not in recipes:
        raise ConfigError(f"{study.where}: against.recipe: {against.recipe!r} is not a recipe of the set "
                          f"{pset.set_id} ({', '.join(recipes)})")
    return against.recipe


_PROTOCOL = ("protocol", "evaluation", "subset", "refit", "prefixes")


def _protocol_of(cell: dict[str, Any]) -> dict[str, Any]:
    return {"protocol": cell["protocol"], "evaluation": cell["evaluation"], "subset": cell["subset"],
            "refit": cell["refit"], "prefixes": list(cell["prefixes"] or [])}


def plan_comparison(study: Study, against: Against) -> Comparison:
    """Every user model and dataset of the study's grids against its baselines, or the first refusal (a
    :class:`ConfigError` naming the difference), before any cell trains (see the module docstring)."""
    pset = load_set(against.set, base=study.path.parent, key=f"{study.where}: against.set")
    recipe = _recipe(study, against, pset)
    cells = [c for c in pset.cells if c["recipe_name"] == recipe]
    pairings: list[Pairing] = []
    for name, plan in plans(study).items():
        if plan.spec.superseded:
            continue
        own = set(plan.models)
        try:
            grid = build_grid(plan.config)
        except TactileZooError as exc:
            raise ConfigError(f"{study.where}: grids.{name}.settings: {exc}") from None
        infos = {info.name: info for info in grid.datasets}
        for dataset in plan.datasets:
            here = [c for c in cells if c["dataset"] == dataset]
            if not here:
                have = sorted({c["dataset"] for c in cells})
                raise _refuse(study, "a dataset the set does not hold", f"grid {name} trains on {dataset}; the "
                              f"set {pset.set_id} has no `{recipe}` cells on it (it has {', '.join(have)})")
            models = sorted({c["model"] for c in here})
            baselines = against.baselines or [m for m in models if m not in own]
            unknown = [m for m in baselines if m not in models]
            if unknown:
                raise ConfigError(f"{study.where}: against.baselines: {', '.join(unknown)} has no `{recipe}` cells "
                                  f"on {dataset} in the set {pset.set_id} (it has {', '.join(models)})")
            clash = sorted(own & set(baselines))
            if clash:
                raise ConfigError(f"{study.where}: against.baselines names {', '.join(clash)}, which grid {name} "
                                  f"trains: a comparison trains only your models")
            if dataset not in infos:
                raise _refuse(study, "no data", f"grid {name}: {dataset}'s data is not here "
                              f"({grid.notes.get(dataset, 'skipped')})")
            info = infos[dataset]
            keys = [(fold, seed) for fold in info.folds for seed in plan.config.seeds]
            for model in plan.models:
                pairings.append(_pair(study, against, pset, recipe, name, plan, info, model, dataset, keys,
                                      {b: [c for c in here if c["model"] == b] for b in baselines}))
    return Comparison(study, against, pset, recipe, pairings)


def _pair(study: Study, against: Against, pset: PublishedSet, recipe: str, grid: str, plan: Any, info: Any,
          model: str, dataset: str, keys: list[tuple[int, int]], baselines: dict[str, list[dict[str, Any]]]
          ) -> Pairing:
    cfg = plan.configs[model, dataset]
    mine = {"protocol": info.protocol, "evaluation": cfg.evaluation,
            "subset": None if cfg.subset is None else dict(cfg.subset), "refit": cfg.refit,
            "prefixes": list(cfg.prefixes)}
    who = f"grid {grid}'s cells of {model} on {dataset}"
    theirs = f"the published `{recipe}` cells of {{b}} on {dataset} ({pset.set_id})"
    out = Pairing(grid, model, dataset, keys, {})
    for baseline, found in baselines.items():
        revisions = sorted({c["dataset_revision"] for c in found})
        if revisions != [cfg.dataset_revision]:
            raise _refuse(study, "another dataset revision", f"{who} would use dataset revision "
                          f"{cfg.dataset_revision}; {theirs.format(b=baseline)} use revision "
                          f"{', '.join(map(str, revisions))}")
        for key in _PROTOCOL:
            published = sorted({json.dumps(_protocol_of(c)[key], sort_keys=True) for c in found})
            if published != [json.dumps(mine[key], sort_keys=True)]:
                said = ", ".join(repr(json.loads(value)) for value in published)
                raise _refuse(study, "a different protocol", f"{who}: {key} {mine[key]!r}; "
                              f"{theirs.format(b=baseline)}: {key} {said}")
        held = {(c["fold"], c["seed"]): c for c in found}
        missing = [k for k in keys if k not in held]
        if missing:
            raise _refuse(study, "missing seeds", f"{who} would run seed(s) {seed_list({s for _, s in missing})} "
                          f"at fold(s) {seed_list({f for f, _ in missing})}, which {theirs.format(b=baseline)} do "
                          f"not hold (they hold seeds {seed_list({s for _, s in held})}); against.seeds: "
                          f"{against.seeds} needs each of yours published")
        extra = sorted(set(held) - set(keys))
        if against.seeds == "equal" and extra:
            raise _refuse(study, "missing seeds", f"{who} lack seed(s) {seed_list({s for _, s in extra})} that "
                          f"{theirs.format(b=baseline)} hold (against.seeds: equal; `subset` compares on yours)")
        out.baselines[baseline] = [held[k] for k in keys]
    for fold in sorted({f for f, _ in keys}):
        split = take(load_splits(dataset, plan.config.root, fold, plan.config.download, dict(cfg.dataset_kwargs),
                                 ("test",))["test"], (cfg.subset or {}).get("test"))
        out.test_sets[fold] = _test_set(dataset, "test", split.y.tolist(), split.unit_ids())
    for baseline, found in out.baselines.items():
        out.paired[baseline] = _check_split(study, who, theirs.format(b=baseline), pset, found, out.test_sets,
                                            dict(cfg.dataset_kwargs))
    return out


def _check_split(study: Study, who: str, theirs: str, pset: PublishedSet, found: list[dict[str, Any]],
                 mine: dict[int, TestSet], kwargs: dict[str, Any]) -> bool:
    """Whether the baseline's cells were scored on the user's samples (paired); refuse other recordings."""
    paired = True
    for cell in found:
        published, own = _published_test_set(pset, cell), mine[cell["fold"]]
        if published.recordings != own.recordings:
            raise _refuse(study, "a mismatched split", f"{who}: with the dataset keywords {kwargs or {}} the test "
                          f"split (fold {cell['fold']}) holds {own.describe()}; {theirs} were scored on "
                          f"{published.describe()}")
        paired = paired and published.identity == own.identity
    return paired


def check_finished(comparison: Comparison, records: dict[str, list[dict[str, Any]]]
                   ) -> dict[tuple[str, str, str], list[dict[str, Any]]]:
    """The user's ok records per (grid, model, dataset) at the planned keys, each test set checked once more against
    the one planned (a :class:`ResultsError` naming the cell otherwise); a cell not finished is an error too."""
    out = {}
    for pairing in comparison.pairings:
        by_key = {(r["fold"], r["seed"]): r for r in records.get(pairing.grid, [])
                  if r["model"] == pairing.model and r["dataset"] == pairing.dataset}
        chosen = []
        for key in pairing.keys:
            rec = by_key.get(key)
            if rec is None or rec.get("status") != "ok":
                raise ResultsError(f"{comparison.study.where}: grid {pairing.grid}: the cell of {pairing.model} on "
                                   f"{pairing.dataset} at fold {key[0]}, seed {key[1]} is "
                                   f"{'not there' if rec is None else rec.get('status')}: nothing is compared "
                                   f"(run it again: finished cells are kept)")
            pred = (rec.get("predictions") or {}).get("test") or {}
            got = _test_set(pairing.dataset, "test", pred.get("targets") or [], pred.get("groups"))
            planned_set = pairing.test_sets[key[0]]
            if got.identity != planned_set.identity:
                raise ResultsError(f"{rec['cell_id']}: its test split holds {got.describe()}, not the "
                                   f"{planned_set.describe()} it was planned on: nothing is compared")
            chosen.append(rec)
        out[pairing.grid, pairing.model, pairing.dataset] = chosen
    return out
