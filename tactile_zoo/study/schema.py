"""The study file: one YAML schema, checked with strict pydantic models; every error names the file and the key.

A study is a benchmark decided before it runs::

    study: quickstart                 # a name (letters, digits, _ and -)
    question: Does a two-seed ensemble of CNN-LSTM beat chance on the simulated grasps?
    notes: |                          # what a PLAN.md holds: the reasoning, the protocol, the caveats
      ...
    pre_registered: true              # false: a folder run before any plan (``report`` says so)
    freeze: null                      # a migrated study's freeze, read once from its plan's first commit:
                                      #   {time: 2026-12-01T10:00:00+0000, commit: abc123, source: PLAN.md}
    results: quickstart-results       # the results folder, relative to this file
    grids:                            # one or more, each the bench settings as ``bench --config`` takes them
      - name: main
        folder: main                  # its bench folder under ``results`` (default: the name; grids may share one)
        superseded: null              # why this folder's cells no longer count (kept, never read as results)
        reused: null                  # why the study reads cells it did not run (earlier evidence, a baseline arm)
        ran_by: null                  # a reused grid another study runs: its file; until its cells are in, reads wait
        settings: {models: [cnn_lstm, dcnn], datasets: sim_evtouch, seeds: [0, 1], quick: true, epochs: 1}
    rules:
      cpu: null                       # the one CPU type every cell runs on (default: whichever the first ran on)
      budget_cpu_hours: 0.2           # the cells' own ``seconds``, summed
      test_split: once                # once: every cell reads its test split exactly once; never: a tuning study
    reads:                            # what will be read, and what each outcome leads to
      means: [{name: dcnn_mean, grid: main, model: dcnn, dataset: sim_evtouch}]
      ensembles:
        - {name: cnn_lstm_ens2, grid: main, dataset: sim_evtouch, combine: mean_probabilities,
           members: [{model: cnn_lstm, seeds: [0, 1]}]}
      comparisons:
        - {name: dcnn_vs_cnn_lstm, grid: main, dataset: sim_evtouch, a: cnn_lstm, b: dcnn, test: paired_bootstrap}
        - {name: new_vs_old, grid: new, dataset: ev_objects, b: sgnet,   # a side as arms across grids (b minus a)
           a: [{grid: r3, model: sgnet, seeds: [0, 1, 2, 3, 4]}, {grid: r4, model: sgnet, seeds: [5, 6, 7, 8, 9]}]}
      validation:                     # a tuning study's reads: validation scores, never a test split
        - {name: gain, grid: scaled, dataset: ev_objects, model: sgnet, score: final,
           against: {grid: registered}}
      thresholds:
        - {name: above_chance, read: cnn_lstm_ens2, statistic: accuracy, at_least: 0.1,
           decision: {met: "...", missed: "..."}}
        - {name: measured_drop, read: new_vs_old, statistic: high, below: 0,   # the interval entirely below zero
           decision: {met: "back to the previous revision", missed: "the new revision stays"}}
      decisions: [{name: adopt, all_of: [above_chance, ...], decision: {met: "...", missed: "..."}}]
    publishes: [{where: README.md, block: headline, reads: [cnn_lstm_ens2]}]
    compares_with:
      - {name: paper, source: "Xu et al., X-Tacformer, Table I", figures: [{model: sgnet, dataset: ev_objects,
         value: 0.8944}]}
    amendments:                       # appended after the freeze, each with its reason (:mod:`.freeze`)
      - {reason: "...", reads: {...}, rules: {...}, grids: [...], freeze: null}  # freeze: a migrated one's

:func:`parse_study` reads the file through the bounded YAML reader (:mod:`tactile_zoo._yaml`) and checks its shape
here, each grid's settings against the bench's own schema (:class:`tactile_zoo.settings.BenchSettings`);
:func:`~.checks.load_study` then resolves each grid as the bench does (:func:`~tactile_zoo.bench.config.
merge_config`, so a grid accepts exactly what ``tactile-zoo bench --config`` accepts) and checks what the parts say
of each other. :meth:`Study.effective`
applies the amendments.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Strict, Tag, ValidationError, model_validator

from .._yaml import read_yaml_file
from ..errors import ConfigError
from ..settings import BenchSettings, describe_error

__all__ = ["Study", "StudyFile", "GridSpec", "Rules", "Reads", "MeanRead", "EnsembleRead", "ComparisonRead",
           "ValidationRead", "Arm", "ComparisonArm", "Threshold", "AllOf", "Members", "Amendment", "Freeze",
           "parse_study", "canonical_hash", "amendment_kept", "READ_KINDS"]

#: the kinds of declared read that are computed from cells (thresholds and decisions read them)
READ_KINDS = ("means", "ensembles", "comparisons", "validation")

Name = Annotated[str, Strict(), Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$", max_length=80)]
Text = Annotated[str, Strict(), Field(min_length=1)]
Seed = Annotated[int, Strict(), Field(ge=0)]
Number = Annotated[float, Strict(), Field(allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class Freeze(_Model):
    """A freeze written into the file: a migrated study's, read once from the git history of its plan."""

    time: Text  # ISO 8601 with its offset, e.g. 2026-12-01T10:00:00+0000
    commit: Text | None = None
    source: Text | None = None  # where the time was read (e.g. the first commit of PLAN.md)


class GridSpec(_Model):
    """One grid: a name, its bench folder and the bench settings (checked by the bench's own path)."""

    name: Name
    folder: Text | None = None  # relative to the study's results folder (default: the name)
    superseded: Text | None = None  # why its cells no longer count
    #: why the study reads cells it did not run (earlier evidence, a baseline arm): the study's freeze and test-split
    #: rules do not apply to them, and their cost is not the study's (:mod:`.audit`)
    reused: Text | None = None
    #: for a reused grid that another study runs: that study's file (relative to this one). Until its cells are all
    #: there, the grid and the reads of it wait instead of failing the audit (``check`` finds the grid in that file)
    ran_by: Text | None = None
    settings: BenchSettings  # the bench's settings schema; :func:`~.plan.bench_config` resolves them as bench does

    def given(self) -> dict[str, Any]:
        """The settings the file gives (the bench's defaults left to the bench)."""
        return self.settings.model_dump(exclude_unset=True)


class Rules(_Model):
    cpu: Text | None = None
    budget_cpu_hours: Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)] | None = None
    test_split: Literal["once", "never"] = "once"


class Members(_Model):
    """The cells of one model: its seeds (default: every seed of the grid) on fold ``fold``."""

    model: Text
    seeds: list[Seed] | None = None
    fold: Annotated[int, Strict(), Field(ge=0)] = 0


class _Read(_Model):
    name: Name
    grid: Name | None = None  # default: the study's only grid
    dataset: Text
    split: Text = "test"


class MeanRead(_Read):
    """The mean accuracy of one model's seeds with its 95 % interval (the shared-draw method)."""

    model: Text
    seeds: list[Seed] | None = None


class EnsembleRead(_Read):
    members: Annotated[list[Members], Field(min_length=1)]
    combine: Literal["mean_probabilities", "majority_vote"] = "mean_probabilities"


class Arm(_Model):
    """One arm of a validation read: a grid's cells of a model (default: the read's grid and model)."""

    grid: Name | None = None
    model: Text | None = None
    seeds: list[Seed] | None = None


class ComparisonArm(Arm):
    """One part of a comparison's side: a model's cells in a grid (default: the read's), its seeds (default: the
    grid's), each seed's folds as the bench listed them."""

    model: Text


#: a comparison's side: a model's name, or a list of arms (a list is checked as arms only, so that an error names
#: the arm's key; the tags are how :func:`tactile_zoo.settings.describe_error` knows a union member's label)
Side = Annotated[Annotated[list[ComparisonArm], Field(min_length=1), Tag("list[arms]")] | Annotated[Text, Tag("str")],
                 Discriminator(lambda value: "str" if isinstance(value, str) else "list[arms]" if isinstance(
                     value, list) else None, custom_error_type="side_type",
                     custom_error_message="must be a model's name or a list of arms ({grid, model, seeds})")]


class ComparisonRead(_Read):
    """Is ``b`` better than ``a``: the paired interval of the difference (b minus a) and its one-sided p-value.
    A side is a model of the read's grid, or a list of arms across grids (e.g. a previous revision's seeds, in the
    two folders that ran them); the cells pair by fold and seed, and a side holds at most one cell of each."""

    a: Side  # a model of the grid, or arms
    b: Side
    test: Literal["paired_bootstrap"] = "paired_bootstrap"
    level: Annotated[float, Strict(), Field(gt=0, lt=1)] = 0.95

    @property
    def arms(self) -> bool:
        """Whether a side is given as arms (its recorded inputs then name each cell's grid: ``grid/cell id``)."""
        return not (isinstance(self.a, str) and isinstance(self.b, str))


class ValidationRead(_Model):
    """A tuning read: one model's validation score over its runs (folds and seeds), against another arm's where
    ``against`` names one. ``score``: ``best`` the accuracy of the epoch the cell selected (``metrics.val``),
    ``final`` the accuracy at the recipe's last epoch (``max_epochs``, from the curve), ``epoch`` the epoch selected.
    Gives ``mean`` and ``median``; with ``against`` also ``difference`` (mean minus the other arm's) and
    ``improved`` (how many runs, paired by fold and seed, score above the other arm's)."""

    name: Name
    grid: Name | None = None  # default: the study's only grid
    dataset: Text
    model: Text
    seeds: list[Seed] | None = None
    score: Literal["best", "final", "epoch"] = "best"
    against: Arm | None = None


class Decision(_Model):
    met: Text
    missed: Text


class Threshold(_Model):
    """An outcome decided in advance: the statistic of a read against a bound, and what each side leads to. ``read``
    may list several reads: the statistic is then the best (highest) of them, e.g. "a declared ensemble >= 0.93"."""

    name: Name
    read: Name | Annotated[list[Name], Field(min_length=1)]
    statistic: Literal["accuracy", "low", "high", "difference", "p_value", "mean", "median", "improved"] = "accuracy"
    at_least: Number | None = None
    below: Number | None = None
    decision: Decision

    @model_validator(mode="after")
    def _one_bound(self) -> Threshold:
        if (self.at_least is None) == (self.below is None):
            raise ValueError("give exactly one of at_least and below")
        return self


class AllOf(_Model):
    """A decision that needs several thresholds met (e.g. a gain on both datasets)."""

    name: Name
    all_of: Annotated[list[Name], Field(min_length=1)]
    decision: Decision


class Reads(_Model):
    means: list[MeanRead] = Field(default_factory=list)
    ensembles: list[EnsembleRead] = Field(default_factory=list)
    comparisons: list[ComparisonRead] = Field(default_factory=list)
    validation: list[ValidationRead] = Field(default_factory=list)
    thresholds: list[Threshold] = Field(default_factory=list)
    decisions: list[AllOf] = Field(default_factory=list)


class Publication(_Model):
    """A generated block of a page that this study's cells feed (:mod:`.publish`): ``table`` names the part it plays
    there (e.g. ``source`` in Table I), ``grid`` the grid it reads (default: the first), ``target`` a figure the
    table states beside its own (a performance issue's CPU-hours)."""

    where: Text  # a page, e.g. docs/table1.md
    block: Text | None = None  # its generated block
    table: Name | None = None
    grid: Name | None = None
    target: Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)] | None = None
    reads: list[Name] = Field(default_factory=list)
    # the README headline's `recipe` part and published-results' `ours` `full` part (checks.CLAIMABLE): the models
    # whose rows read this study's cells alone, at each model's registered revision (a study that moved them to a
    # new revision); the other studies' cells stand for the rest
    models: list[Name] = Field(default_factory=list)


class ExternalFigure(_Model):
    model: Text
    dataset: Text
    split: Text = "test"  # the test split the figure is of (BioTac-DoS: test_textures)
    value: Annotated[float, Strict(), Field(ge=0, le=1)]


class External(_Model):
    name: Name
    source: Text  # named: a paper and its table, a URL
    figures: list[ExternalFigure] = Field(default_factory=list)


class Amendment(_Model):
    """Appended after the freeze, with its reason: new grids, reads and rules (:func:`.freeze.check_amendments`
    refuses one that changes something whose inputs already exist)."""

    reason: Text
    freeze: Freeze | None = None  # a migrated amendment's, read once from the commit that appended it to the plan
    grids: list[GridSpec] = Field(default_factory=list)
    rules: dict[Literal["cpu", "budget_cpu_hours", "test_split"], Any] = Field(default_factory=dict)
    reads: Reads = Field(default_factory=Reads)


class StudyFile(_Model):
    study: Name
    question: Text
    notes: str = ""
    pre_registered: Annotated[bool, Strict()] = True
    freeze: Freeze | None = None
    results: Text | None = None
    grids: Annotated[list[GridSpec], Field(min_length=1)]
    rules: Rules = Field(default_factory=Rules)
    reads: Reads = Field(default_factory=Reads)
    publishes: list[Publication] = Field(default_factory=list)
    compares_with: list[External] = Field(default_factory=list)
    amendments: list[Amendment] = Field(default_factory=list)


def canonical_hash(value: Any) -> str:
    """The sha256 of ``value`` as canonical JSON (sorted keys): what a freeze records of a part of the study."""
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()


def amendment_kept(record: dict[str, Any], amendment: Amendment) -> bool:
    """Whether ``amendment`` (as the file has it now) is the one a freeze ``record`` fixed.

    A freeze records the amendment's full form (``model_dump``: every key, defaults included) and its hash. A key
    added to the schema since (a new bench setting, off by default) changes that form without changing the amendment,
    so the recorded form, checked against its own hash, is read through today's schema and compared with the file's.
    """
    current = amendment.model_dump(mode="json")
    if canonical_hash(current) == record["sha256"]:
        return True
    stored = record.get("amendment")
    if not isinstance(stored, dict) or canonical_hash(stored) != record["sha256"]:
        return False
    try:
        then = Amendment.model_validate(stored)
    except ValidationError:  # a key the schema no longer has: a real change, named by the caller
        return False
    return canonical_hash(then.model_dump(mode="json")) == canonical_hash(current)


class Study:
    """A checked study file: its path, its raw text and data, and the parsed :class:`StudyFile`."""

    def __init__(self, path: Path, text: str, data: dict[str, Any], spec: StudyFile) -> None:
        self.path, self.text, self.data, self.spec = path, text, data, spec

    @property
    def name(self) -> str:
        return self.spec.study

    @property
    def where(self) -> str:
        return str(self.path)

    @property
    def results(self) -> Path:
        """The results folder: ``results`` relative to the file, default ``<file stem>-results`` beside it."""
        return self.path.parent / (self.spec.results or f"{self.path.stem}-results")

    def grid(self, name: str | None) -> GridSpec:
        grids = self.grids()
        if name is None:
            return grids[0]
        return next(g for g in grids if g.name == name)

    def grids(self) -> list[GridSpec]:
        """Every grid, the amendments' included (an amendment's grid of an existing name replaces it)."""
        out = {g.name: g for g in self.spec.grids}
        for amendment in self.spec.amendments:
            out.update({g.name: g for g in amendment.grids})
        return list(out.values())

    def folder(self, grid: GridSpec) -> Path:
        return self.results / (grid.folder or grid.name)

    def rules(self) -> Rules:
        merged = self.spec.rules.model_dump()
        for amendment in self.spec.amendments:
            merged.update(amendment.rules)
        return Rules.model_validate(merged)

    def reads(self) -> Reads:
        """Every declared read, the amendments' included (one of an existing name replaces it)."""
        parts: dict[str, dict[str, Any]] = {k: {} for k in (*READ_KINDS, "thresholds", "decisions")}
        for reads in (self.spec.reads, *(a.reads for a in self.spec.amendments)):
            for kind in parts:
                parts[kind].update({r.name: r for r in getattr(reads, kind)})
        return Reads(**{kind: list(found.values()) for kind, found in parts.items()})

    def frozen_parts(self) -> dict[str, Any]:
        """What a freeze fixes: the grids, rules and reads as written before the amendments (the raw data), and a
        comparison study's ``against`` (the set, recipe and baselines it is read against: :mod:`.compare`)."""
        parts = {key: self.data.get(key) for key in ("grids", "rules", "reads")}
        if "against" in self.data:  # absent from other studies, so their freezes stay as they were
            parts["against"] = self.data["against"]
        return parts


def _location(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not (isinstance(part, str) and ("[" in part or part.startswith("function-"))):
            out += f".{part}" if out else str(part)
    return out or "the file"


def _describe(exc: ValidationError, where: str) -> str:
    """One line naming the file and the key: the settings schema's wording (:func:`tactile_zoo.settings.
    describe_error`), without the value where that is a whole section (a missing key, a rule across keys)."""
    error = exc.errors(include_url=False)[0]
    if error["type"] == "missing":
        return f"{where}: {_location(error['loc'])} is required"
    if isinstance(error["input"], dict) or error["type"] == "value_error" and isinstance(error["input"], list):
        message = str((error.get("ctx") or {}).get("error", error["msg"]))
        return f"{where}: {_location(error['loc'])}: {message}"
    return describe_error(exc, where)


def parse_study(path: str | Path) -> Study:
    """Read the study file at ``path`` and check its shape (the YAML and this schema); a :class:`ConfigError` names
    the file and the key. :func:`~.checks.load_study` also checks what the parts say of each other."""
    path = Path(path)
    data = read_yaml_file(path, str(path))
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping (study, question, grids, ...), got "
                          f"{type(data).__name__}")
    try:
        spec = StudyFile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, str(path))) from None
    return Study(path, path.read_text(encoding="utf-8"), data, spec)
