"""The grid: which models, which datasets (and which are skipped, why, and how to get them), which cells.

A cell is ``(model, dataset, fold, seed, config hash)``. The config hash covers everything that can change a cell's
numbers except its fold and seed (:class:`~tactile_zoo.engine.config.CellConfig`): the model (and the plugin
distribution it comes from), the computational revisions of the model's and the dataset's code (registry metadata
``revision``, bumped whenever what the code computes changes), the constructor hyper-parameters, the fully resolved
training recipe (every key, defaults included, so a changed default in a model's registry metadata is a new cell
too), the dataset and its keyword arguments, ``refit``, the ``--quick`` subset sizes and the prefix fractions. It does
not cover the device, the thread count or the executor, which change speed, not the protocol; nor the package
versions, which every cell records. Rerunning the same command finds the same hashes, so finished cells are reused;
any changed setting or revision gives new hashes, so nothing stale is ever reused.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import registry
from ..engine.build import load_splits
from ..engine.config import CellConfig, check_model_builds, config_hash
from ..errors import ConfigError, DatasetError, UnknownNameError
from .config import BenchConfig, plan_cells
from .parsing import MAX_CELLS

__all__ = ["Cell", "Grid", "DatasetInfo", "SkipRow", "build_grid", "resolve_models", "resolve_datasets", "cell_id",
           "default_out_dir", "safe_name", "skip_message"]

_WILDCARD = re.compile(r"[*?\[]")


@dataclass(frozen=True)
class Cell:
    """One unit of work. ``config`` is the resolved configuration the hash covers, the object itself (a worker
    receives it as it is; ``config.to_dict()`` is its record form)."""

    model: str
    dataset: str
    fold: int
    seed: int
    config_hash: str
    config: CellConfig = field(compare=False, hash=False)
    protocol: str = field(default="fixed", compare=False)
    extra_splits: tuple[str, ...] = field(default=(), compare=False)

    @property
    def cell_id(self) -> str:
        return cell_id(self.model, self.dataset, self.fold, self.seed, self.config_hash)

    def label(self) -> str:
        return f"{self.model} x {self.dataset} fold {self.fold} seed {self.seed}"


@dataclass
class SkipRow:
    """A (model, dataset) pair that produces no cells: the dataset is absent/unloadable (``skipped``) or broken
    (``failed``)."""

    model: str
    dataset: str
    status: str
    reason: str
    obtain: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "dataset": self.dataset, "status": self.status, "reason": self.reason,
                "obtain": self.obtain}


@dataclass
class DatasetInfo:
    name: str
    num_folds: int
    folds: list[int]
    protocol: str
    extra_splits: tuple[str, ...]
    kwargs: dict[str, Any]
    num_classes: int
    max_epochs: int | None = None  # the dataset's epoch budget (meta "max_epochs"); --epochs overrides it
    spec: Any = field(default=None, repr=False)  # the dataset's spec: every model is built on it once, up front


@dataclass
class Grid:
    models: list[str]
    datasets: list[DatasetInfo]
    cells: list[Cell]
    skipped: list[SkipRow]
    dataset_notes: dict[str, str]  # dataset -> why it is skipped / failed (one line each)
    requested_models: list[str]
    requested_datasets: list[str]
    settings: dict[str, Any] = field(default_factory=dict)  # every setting of the command, as run.json records them
    quick: bool = False

    def describe(self) -> list[str]:
        """Human-readable lines: the plan, then the skipped datasets with the command that obtains them."""
        lines = [f"{len(self.cells)} cells: {len(self.models)} model(s) x {len(self.datasets)} dataset(s)"]
        for info in self.datasets:
            lines.append(f"  {info.name}: protocol {info.protocol}, folds {_ranges(info.folds)} of {info.num_folds}")
        lines.append(f"  models: {', '.join(self.models)}")
        broken = {s.dataset for s in self.skipped if s.status == "failed"}
        for name, note in self.dataset_notes.items():
            lines.append(f"  {'failed' if name in broken else 'skipped'} dataset {name}: {note}")
        return lines


def skip_message(reason: str, obtain: str) -> str:
    """The reason a dataset is skipped, plus how to obtain it when the reason does not say so already."""
    reason = reason.strip()
    if obtain and obtain.strip() not in reason:
        reason = f"{reason.rstrip('.')}. To obtain it: {obtain.strip()}"
    return reason


def _ranges(values: list[int]) -> str:
    return f"{values[0]}..{values[-1]}" if len(values) > 2 else ",".join(map(str, values))


def safe_name(name: str) -> str:
    """A name usable in a file name (``dist:model`` -> ``dist-model``)."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "-", name)


def cell_id(model: str, dataset: str, fold: int, seed: int, config_hash: str) -> str:
    return f"{safe_name(model)}__{safe_name(dataset)}__f{fold}__s{seed}__{config_hash}"


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def _listed_name(kind: str, entry: registry.Entry) -> str:
    return registry.listed_name(entry)  # never the bare name of a shadowed plugin: that one is the built-in's


def _resolve(kind: str, tokens: Iterable[str]) -> list[str]:
    lister = registry.model_names if kind == "model" else registry.list_datasets
    lookup = registry.get_model_entry if kind == "model" else registry.get_dataset_entry
    out: list[str] = []
    for token in (t.strip() for item in tokens for t in item.split(",") if t.strip()):
        if token.lower() == "all":
            names = lister()
        elif _WILDCARD.search(token):
            names = lister(token)
            if not names:
                raise UnknownNameError(f"--{kind}s: pattern {token!r} matches no registered {kind}; known: "
                                       f"{', '.join(lister()) or '(none)'}")
        else:
            names = [_listed_name(kind, lookup(token))]
        out.extend(n for n in names if n not in out)
    if not out:
        raise ConfigError(f"no {kind}s to run: {', '.join(tokens)} selects none")
    return out


def resolve_models(tokens: Iterable[str]) -> list[str]:
    """Names, comma lists, wildcards and ``all`` (entry-point plugins included) -> registered model names."""
    return _resolve("model", tokens)


def resolve_datasets(tokens: Iterable[str]) -> list[str]:
    return _resolve("dataset", tokens)


def _named_datasets(tokens: Iterable[str]) -> set[str]:
    """The datasets given by their own name, not through ``all`` or a wildcard: those must be here."""
    return {_listed_name("dataset", registry.get_dataset_entry(t))
            for t in (t.strip() for item in tokens for t in item.split(",") if t.strip())
            if t.lower() != "all" and not _WILDCARD.search(t)}


def _obtain_hint(entry: registry.Entry, name: str, root: str | None) -> str:
    """The command (or instructions) that gets a dataset's data."""
    from ..data.base import TactileDataset

    downloadable = isinstance(entry.obj, type) and issubclass(entry.obj, TactileDataset) and \
        bool(getattr(entry.obj, "downloadable", False))
    if downloadable:
        return f"tactile-zoo download {name}" + (f" --root {root}" if root else "") + " (or add --download)"
    return str(entry.meta.get("obtain") or getattr(entry.obj, "obtain", "") or "").strip()


def _probe_dataset(name: str, config: BenchConfig, kwargs: dict[str, Any]) -> DatasetInfo | tuple[str, str, str]:
    """Whether ``name`` can run here (with the user's keyword arguments ``kwargs``): a DatasetInfo, or
    ``(status, reason, obtain)`` for a skipped/failed one."""
    from ..data.base import TactileDataset

    entry = registry.get_dataset_entry(name)
    obj = entry.obj
    obtain = _obtain_hint(entry, name, config.root)
    present = False
    if isinstance(obj, type) and issubclass(obj, TactileDataset):
        present, reason = obj.availability(config.root)
        if not present and not (config.download and getattr(obj, "downloadable", False)):
            return "skipped", reason, obtain
    try:
        splits = load_splits(name, config.root, 0, config.download, kwargs, ("train",))
    except ConfigError:
        raise  # bad dataset keyword arguments from the user: exit 2 before anything runs
    except TypeError as exc:
        if "keyword argument" in str(exc):
            raise ConfigError(f"dataset {name!r} does not take the keyword argument(s) {sorted(kwargs)}: {exc}") \
                from None
        return "failed", f"loading {name} failed: {type(exc).__name__}: {exc}", obtain
    except (DatasetError, FileNotFoundError) as exc:
        if present:  # the raw files are there but cannot be read: broken data fails loudly, it is not "absent"
            return "failed", str(exc), ""
        return "skipped", str(exc), obtain
    except Exception as exc:  # a broken dataset must not stop the other datasets
        return "failed", f"loading {name} failed: {type(exc).__name__}: {exc}", obtain
    ds = splits["train"]
    num_folds = int(getattr(ds, "num_folds", 1) or 1)
    folds = list(range(num_folds if config.folds is None else min(num_folds, config.folds)))
    protocol = getattr(ds, "protocol", None)
    if not isinstance(protocol, str) or len(protocol) > 24:
        protocol = "kfold" if num_folds > 1 else "fixed"
    extra = tuple(getattr(ds, "extra_splits", ()) or ())
    if not extra:
        extra = tuple(s for s in entry.meta.get("splits", ()) if s not in ("train", "val", "test"))
    return DatasetInfo(name, num_folds, folds, protocol, extra, kwargs, ds.spec.num_classes,
                       entry.meta.get("max_epochs"), ds.spec)


def _check_size(models: int, folds: int, seeds: int, bound: str) -> None:
    """Refuse a grid of more than :data:`~.config.MAX_CELLS` cells, with its count, before listing a single one."""
    count = models * folds * seeds
    if count > MAX_CELLS:
        raise ConfigError(f"the grid has {bound + ' ' if bound else ''}{count:,} cells ({models} model(s) x {folds} "
                          f"dataset fold(s) x {seeds} seed(s)); a bench command runs at most {MAX_CELLS:,} (split the "
                          f"study into several commands sharing one --out)")


def build_grid(config: BenchConfig) -> Grid:
    """Resolve names, probe datasets, and list the cells in run order (dataset, fold, seed, model)."""
    models = resolve_models(config.models)
    dataset_names = resolve_datasets(config.datasets)
    _check_size(len(models), 1, len(config.seeds), "at least")  # before any dataset is loaded
    # every pair's configuration first, resolved once: a bad recipe override fails here, before any dataset is loaded
    plan = plan_cells(config, models, dataset_names)
    infos: list[DatasetInfo] = []
    skipped: list[SkipRow] = []
    notes: dict[str, str] = {}
    named = _named_datasets(config.datasets)
    for name in dataset_names:
        probe = _probe_dataset(name, config, plan.dataset_kwargs[name])
        if isinstance(probe, DatasetInfo):
            infos.append(probe)
            continue
        status, reason, obtain = probe
        if status == "skipped" and name in named:  # asked for by name: its absence is an error, not a skip
            raise ConfigError(f"--datasets {name}: its data is not here: {skip_message(reason, obtain)}")
        notes[name] = skip_message(reason, obtain)
        skipped.extend(SkipRow(m, name, status, reason, obtain) for m in models)
    if not infos and skipped and all(s.status == "skipped" for s in skipped):
        raise ConfigError(f"--datasets {', '.join(config.datasets)}: none of the selected datasets has its data here "
                          f"({'; '.join(f'{n}: {why}' for n, why in notes.items())})")
    _check_size(len(models), sum(len(info.folds) for info in infos), len(config.seeds), "")
    for info in infos:  # every model once on every dataset's spec: a bad --hparam value stops the command here
        for model in models:
            check_model_builds(plan.configs[model, info.name], info.spec, plan.given[model])
    cells: list[Cell] = []
    for info in infos:
        for model in models:
            resolved = plan.configs[model, info.name]
            digest = config_hash(resolved)
            for fold in info.folds:
                for seed in config.seeds:
                    cells.append(Cell(model, info.name, fold, seed, digest, resolved, info.protocol,
                                      info.extra_splits))
    cells.sort(key=lambda c: (dataset_names.index(c.dataset), c.fold, c.seed, models.index(c.model)))
    return Grid(models, infos, cells, skipped, notes, list(config.models), list(config.datasets), plan.settings,
                plan.quick)


def _tag(requested: list[str], resolved: list[str], word: str) -> str:
    if any(t.lower() == "all" for t in requested):
        return f"all-{word}"
    text = "+".join(safe_name(n) for n in resolved)
    return text if len(text) <= 40 else f"{len(resolved)}-{word}"


def default_out_dir(config: BenchConfig, grid: Grid, base: str | Path = "tactile-zoo-results") -> Path:
    """``tactile-zoo-results/<models>_<datasets>_<digest>``: the digest covers the resolved models and datasets, the
    seeds, the folds and every setting that enters a cell's config, so the same command finds the same folder (and
    resumes) while a changed grid or setting gets its own."""
    cells = sorted({(c.model, c.dataset, c.fold, c.seed, c.config_hash) for c in grid.cells})
    skipped = sorted({(s.model, s.dataset) for s in grid.skipped})
    digest = hashlib.sha256(_canonical({"cells": cells, "skipped": skipped}).encode()).hexdigest()[:10]
    dataset_names = [d.name for d in grid.datasets] + list(grid.dataset_notes)
    name = f"{_tag(grid.requested_models, grid.models, 'models')}_" \
           f"{_tag(grid.requested_datasets, dataset_names, 'datasets')}_{'quick_' if grid.quick else ''}{digest}"
    return Path(base) / name
