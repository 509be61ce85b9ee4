"""What a bench run is asked to do: :class:`BenchConfig`, filled from CLI flags and/or a YAML file.

A YAML config holds the same settings as the flags (flags given on the command line win), plus per-model and
per-dataset overrides the command line can only express as ``MODEL:KEY=VALUE``::

    models: [sgnet, "x_*"]          # or "all" (the default), or "sgnet,dcnn"
    datasets: all
    seeds: [0, 1, 2]                # or "0,1,2" or "0-2"
    folds: 5                        # run at most the first 5 folds of each dataset (default: all it defines)
    epochs: 50                      # replaces every model's max_epochs
    refit: false
    quick: false
    device: auto
    out: results/my-run
    executor: process               # local | process | dask
    workers: 2
    scheduler: null                 # tcp://HOST:PORT for dask (default: a local cluster of `workers` processes)
    retries: null                   # dask: reschedule a cell whose worker died up to N times (default: the
                                    #   scheduler's allowed-failures, Dask's default 3)
    dashboard: null                 # dask local cluster: dashboard address such as :8787 (default: off)
    threads: 1                      # torch threads per cell, the same under every executor (default 1)
    plugin_modules: [my_models]
    root: null                      # data home
    download: false
    force: false
    save_weights: false             # write each computed cell's trained weights to OUT/weights/<cell id>.safetensors
    tracker: null                   # tensorboard | mlflow: log every cell there too (tactile_zoo.bench.trackers)
    tracker_dir: null               # where the tracker writes (default: the run folder, OUT)
    prefixes: [0.1, 0.25, 0.5, 0.75, 1.0]
    recipe_name: source             # which named recipe every model starts from (default: each model's default)
    evaluation: validation          # or reference, tuning, final (engine.config.EVALUATIONS); default: the recipe's
    recipe: {lr: 0.001}             # every model
    hparams: {}                     # every model's constructor keywords
    model_overrides:
      sgnet: {recipe: {batch_size: 8}, hparams: {}}
    dataset_kwargs:
      sim_evtouch: {n_train_per_class: 40}
      "*": {}                       # every dataset
    model_revisions: {sgnet: 2}     # build a model at one of its revisions (default: its registered default;
                                    #   "*": every model); part of the cell hash
    teachers: null                  # distillation (a recipe's distill_weight > 0): {folder: FOLDER, seeds: [0, 1]},
                                    #   the bench folder holding the cells of the same settings with distillation
                                    #   off, run with save_weights (tactile_zoo.engine.distill)

Unknown keys anywhere in the file are a :class:`ConfigError` that names them; every value is checked against the
one settings schema (:class:`tactile_zoo.settings.BenchSettings`, strict: ``quick: "false"`` is refused) as the
file is read (:mod:`tactile_zoo._yaml`: at most 1 MiB, no anchor bomb), and an override for a model or dataset that
is not registered is refused once the plugins are imported (:meth:`BenchConfig.check_names`).
:func:`plan_cells` turns the settings into every cell's :class:`~tactile_zoo.engine.config.CellConfig` (resolved
once, in :mod:`tactile_zoo.engine.config`); nothing after it reads the settings for a cell again.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from .. import registry, settings
from .._env import check_environment
from .._yaml import load_yaml, read_yaml_file
from ..engine.config import QUICK_EPOCHS, QUICK_SUBSET, CellConfig, check_hparams, resolve_cell
from ..engine.evaluate import DEFAULT_PREFIXES
from ..engine.runtime import cpu_count, resolve_device
from ..errors import ConfigError, TactileZooError
from ..recipe import check_recipe_keys
from .parsing import check_settings, parse_folds, parse_positive_int, parse_prefixes, parse_seeds

__all__ = ["BenchConfig", "load_yaml_config", "merge_config", "parse_assignment", "parse_value", "parse_threads",
           "EXECUTORS", "OVERSUBSCRIPTION", "MAX_REMOTE_THREADS", "CellPlan", "plan_cells"]

EXECUTORS = ("local", "process", "dask")
#: ``--threads``, and worker processes x threads, may reach this many times the cores of the machine the cells run
#: on: beyond the cores they only compete for them, and each thread and process costs memory (100000 threads
#: exhausted it before the first cell ran)
OVERSUBSCRIPTION = 4
#: ``--threads`` for cells on a Dask scheduler's workers, whose cores are not known here
MAX_REMOTE_THREADS = 256


def _settings_fields(cls: type) -> type:
    """Give ``cls`` one field per setting of the schema, :class:`tactile_zoo.settings.BenchSettings`, in its order
    and with its default: the list of bench settings is written once, there (:meth:`BenchConfig.validate` brings
    each value to its plain form: ``models="all"`` -> ``["all"]``, ``seeds=0`` -> ``[0]``)."""
    annotations: dict[str, Any] = {}
    for name, info in settings.BenchSettings.model_fields.items():
        annotations[name] = info.annotation  # what may be given; validate() narrows it (a list of names, of seeds)
        setattr(cls, name, field(default_factory=info.default_factory) if info.default_factory else info.default)
    cls.__annotations__ = annotations
    return cls


@dataclass
@_settings_fields
class BenchConfig:
    """Every setting of a bench run (see the module docstring for the YAML form). Its fields are the settings of
    :class:`tactile_zoo.settings.BenchSettings`, with their defaults; once built (validated), each holds its plain
    form: ``models``, ``datasets`` and ``plugin_modules`` lists of names, ``seeds`` a sorted list, ``prefixes`` the
    sorted fractions (default :data:`~tactile_zoo.engine.evaluate.DEFAULT_PREFIXES`), a path a string."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> BenchConfig:
        """The one up-front check of every setting (the CLI's flags and a YAML file's keys alike): a bad one is a
        :class:`ConfigError` naming it, before anything is loaded, trained or written. Also checks the package's
        environment variables (:func:`tactile_zoo._env.check_environment`). Returns ``self``, normalised."""
        check_environment()
        for key in ("root", "out", "tracker_dir"):  # a path given in Python
            if isinstance(getattr(self, key), os.PathLike):
                setattr(self, key, os.fspath(getattr(self, key)))
        check_settings(self.to_dict(), "")  # the schema's types and ranges (tactile_zoo.settings.BenchSettings)
        self.models = _names("models", self.models)
        self.datasets = _names("datasets", self.datasets)
        self.seeds = parse_seeds(self.seeds)
        self.folds = parse_folds(self.folds)
        if self.epochs is not None:
            self.epochs = parse_positive_int("--epochs", self.epochs)
        if self.executor not in EXECUTORS:
            raise ConfigError(f"--executor must be one of {', '.join(EXECUTORS)}, got {self.executor!r}")
        if self.workers is not None:
            self.workers = parse_positive_int("--workers", self.workers)
        if self.scheduler is not None and self.executor != "dask":
            raise ConfigError("--scheduler only applies to --executor dask")
        if self.threads is not None:
            self.threads = parse_threads(self.threads, remote=self.remote)
        # the device's name always; that this machine has it, unless the cells run on a Dask scheduler's workers
        resolve_device(self.device, here=not self.remote)
        if self.save_weights and self.quick:
            from ..weights.manifest import unpublishable

            reason = unpublishable({"subset": self.subset})
            if reason:
                raise ConfigError(f"--save-weights with --quick: every cell would be {reason}, and such weights are "
                                  f"not publishable; drop --quick (or --save-weights)")
        if self.retries is not None:
            self.retries = parse_positive_int("--retries", self.retries, minimum=0)
            if self.executor != "dask":
                raise ConfigError("--retries only applies to --executor dask (a process pool cannot reschedule a "
                                  "cell whose worker died; rerun the command to retry it)")
        if self.dashboard is not None:
            if self.executor != "dask" or self.scheduler is not None:
                raise ConfigError("--dashboard only applies to --executor dask without --scheduler (a scheduler "
                                  "you started serves its own dashboard)")
            if not isinstance(self.dashboard, str) or not self.dashboard.strip():
                raise ConfigError(f"--dashboard must be an address such as :8787, got {self.dashboard!r}")
        self.prefixes = parse_prefixes(DEFAULT_PREFIXES if self.prefixes is None else self.prefixes)
        from .trackers import check_tracker  # its optional library is imported only when a cell is logged

        self.tracker = check_tracker(self.tracker)
        if isinstance(self.recipe, str):  # ``recipe: source`` in a YAML file names a recipe
            self.recipe_name, self.recipe = self.recipe, {}
        if self.recipe_name is not None and (not isinstance(self.recipe_name, str) or not self.recipe_name.strip()):
            raise ConfigError(f"--recipe must name a recipe (e.g. source), got {self.recipe_name!r}")
        self.plugin_modules = _names("plugin_modules", self.plugin_modules, allow_empty=True)
        if self.teachers is not None:  # its plain form: {"folder": str, "seeds": sorted ints}
            teachers = self.teachers if isinstance(self.teachers, Mapping) else dict(self.teachers)
            self.teachers = {"folder": os.fspath(teachers["folder"]), "seeds": sorted(teachers["seeds"])}
        return self

    @property
    def remote(self) -> bool:
        """Whether the cells run on other machines (a Dask scheduler's workers), whose devices and cores are not
        this machine's."""
        return self.executor == "dask" and self.scheduler is not None

    @property
    def subset(self) -> dict[str, int] | None:
        return dict(QUICK_SUBSET) if self.quick else None

    def effective_epochs(self) -> int | None:
        return self.epochs if self.epochs is not None else (QUICK_EPOCHS if self.quick else None)

    def overrides_for(self, model: str, aliases: Iterable[str] = ()) -> tuple[dict[str, Any], dict[str, Any]]:
        """(recipe overrides, hparams) for ``model``: the global ones, then its ``model_overrides`` entry."""
        from ..registry import normalize_name

        keys = {normalize_name(model), *(normalize_name(a) for a in aliases)}
        recipe, hparams = dict(self.recipe), dict(self.hparams)
        patterns = [n for n in self.model_overrides if n == "*" or _is_pattern(n) and model in registry.model_names(n)]
        named = [n for n in self.model_overrides if not _is_pattern(n) and normalize_name(n) in keys]
        for name in patterns + named:  # a pattern's override first: the one naming the model wins
            recipe.update(self.model_overrides[name].get("recipe") or {})
            hparams.update(self.model_overrides[name].get("hparams") or {})
        return recipe, hparams

    def kwargs_for(self, dataset: str) -> dict[str, Any]:
        from ..registry import normalize_name

        patterns = [n for n in self.dataset_kwargs
                    if n == "*" or _is_pattern(n) and dataset in registry.list_datasets(n)]
        named = [n for n in self.dataset_kwargs if not _is_pattern(n) and normalize_name(n) == normalize_name(dataset)]
        out: dict[str, Any] = {}
        for name in sorted(patterns, key=lambda n: n != "*") + named:  # "*", other patterns, then the dataset's own
            out.update(self.dataset_kwargs[name])
        return out

    def revision_for(self, model: str, aliases: Iterable[str] = ()) -> int | None:
        """The revision ``model`` is built at (``model_revisions``: its own entry, else ``"*"``); ``None``: its
        registered default."""
        from ..registry import normalize_name

        keys = {normalize_name(model), *(normalize_name(a) for a in aliases)}
        named = [v for n, v in self.model_revisions.items() if n != "*" and normalize_name(n) in keys]
        return named[-1] if named else self.model_revisions.get("*")

    def check_names(self) -> None:
        """An override aimed at no registered model (``--set nosuch:lr=0.1``, a config file's ``model_overrides``)
        or dataset (``--dataset-arg nosuch:seed=1``, ``dataset_kwargs``) is a :class:`ConfigError` listing the known
        names; a pattern (``"*"``, ``"x_*"``) must match one. Called once the plugins are imported."""
        for kind, overrides, listing, how in (
                ("model", self.model_overrides, registry.model_names,
                 "--set/--hparam NAME:KEY=VALUE or a config file's model_overrides"),
                ("dataset", self.dataset_kwargs, registry.list_datasets,
                 "--dataset-arg NAME:KEY=VALUE or a config file's dataset_kwargs")):
            for name in overrides:
                if _is_pattern(name) and listing(name) or not _is_pattern(name) and _registered(kind, name):
                    continue
                raise ConfigError(f"{how}: {name!r} names no registered {kind} (an override for it would be "
                                  f"ignored); known {kind}s: {', '.join(listing())}")
        for name in self.model_revisions:
            if name != "*" and not _registered("model", name):
                raise ConfigError(f"--model-revision or a config file's model_revisions: {name!r} names no registered "
                                  f"model; known models: {', '.join(registry.model_names())}")

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


CONFIG_KEYS = frozenset(f.name for f in fields(BenchConfig))


def _names(key: str, value: Any, allow_empty: bool = False) -> list[str]:
    """``"a,b"``, ``["a", "b,c"]`` -> ``["a", "b", "c"]`` (whitespace trimmed, order kept, duplicates dropped)."""
    if value is None:
        value = []
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{key} must be a name, a comma-separated list or a list of names; got {value!r}")
    out: list[str] = []
    for item in value:
        for token in item.split(","):
            token = token.strip()
            if token and token not in out:
                out.append(token)
    if not out and not allow_empty:
        raise ConfigError(f"{key}: no names given")
    return out


def _is_pattern(name: str) -> bool:
    return any(c in name for c in "*?[")


def _registered(kind: str, name: str) -> bool:
    try:
        (registry.get_model_entry if kind == "model" else registry.get_dataset_entry)(name)
    except TactileZooError:
        return False
    return True


def parse_threads(value: Any, remote: bool = False, flag: str = "--threads") -> int:
    """Torch threads per cell: a positive integer up to :data:`OVERSUBSCRIPTION` times this machine's cores (or
    :data:`MAX_REMOTE_THREADS` for cells on a Dask scheduler's workers, whose cores are unknown here)."""
    threads = parse_positive_int(flag, value)
    cores = cpu_count()
    cap = MAX_REMOTE_THREADS if remote else OVERSUBSCRIPTION * cores
    if threads > cap:
        where = "for cells on remote Dask workers" if remote else \
            f"{OVERSUBSCRIPTION} x the {cores} core(s) of this machine; more only slow every cell down"
        raise ConfigError(f"{flag} {threads}: at most {cap} ({where})")
    return threads


#: the settings whose command-line text is a number (or ``all``)
_COUNTS = ("epochs", "workers", "threads", "retries", "folds")


def parse_value(text: str) -> Any:
    """A CLI value: int, float, then YAML (``true``, ``null``, ``[1, 2]``, ``{type: cosine}``), else the string.
    The YAML is read as a settings file is (:mod:`tactile_zoo._yaml`: ``1e-3`` is a number, no anchor bomb)."""
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    try:
        return load_yaml(text, "a command-line value")
    except ConfigError as exc:
        if "not valid YAML" in str(exc):
            return text
        raise


def parse_assignment(flag: str, text: str) -> tuple[str | None, str, Any]:
    """``[SCOPE:]KEY=VALUE`` -> (scope or None, key, value). The scope is a model or dataset name (which may itself
    be ``dist:name``), separated from the key by the last ``:`` before ``=``."""
    head, eq, value = text.partition("=")
    if not eq or not head.strip():
        raise ConfigError(f"{flag} expects [NAME:]KEY=VALUE, got {text!r}")
    scope, colon, key = head.rpartition(":")
    key = key.strip()
    if not key or (colon and not scope.strip()):
        raise ConfigError(f"{flag} expects [NAME:]KEY=VALUE, got {text!r}")
    return (scope.strip() or None), key, parse_value(value.strip())


def load_yaml_config(path: str | os.PathLike) -> dict[str, Any]:
    """Read a YAML bench config; unknown keys are a :class:`ConfigError` naming them and the file."""
    path = Path(path)
    data = read_yaml_file(path, f"--config {path}")  # bounded: a size cap, and no anchor bomb
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"--config {path}: the top level must be a mapping of settings, got {type(data).__name__}")
    aliases = {"plugin_module": "plugin_modules", "seed": "seeds", "model": "models", "dataset": "datasets"}
    data = {aliases.get(str(k), str(k)): v for k, v in data.items()}
    unknown = sorted(set(data) - CONFIG_KEYS)
    if unknown:
        raise ConfigError(f"--config {path}: unknown key(s) {', '.join(unknown)}; known keys: "
                          f"{', '.join(sorted(CONFIG_KEYS))}")
    check_settings(data, f"--config {path}")
    return data


def merge_config(yaml_data: Mapping[str, Any] | None, flags: Mapping[str, Any], sets: Sequence[str] = (),
                 hparams: Sequence[str] = (), dataset_args: Sequence[str] = (),
                 model_revisions: Sequence[str] = ()) -> BenchConfig:
    """A :class:`BenchConfig` from a YAML file's settings overlaid with command-line flags (``None`` = not given)
    and the ``--set`` / ``--hparam`` / ``--dataset-arg`` assignments (``[NAME:]KEY=VALUE``) and the
    ``--model-revision`` ones (``[MODEL=]N``)."""
    import copy

    data: dict[str, Any] = copy.deepcopy(dict(yaml_data or {}))
    for key, value in flags.items():
        if value is None:
            continue
        if key not in CONFIG_KEYS:
            raise ConfigError(f"internal: unknown bench setting {key!r}")
        if key == "plugin_modules":
            value = [*_names("plugin_modules", data.get("plugin_modules"), allow_empty=True), *value]
        if key in _COUNTS and isinstance(value, str):  # a flag's text, read by YAML rules as --set's is
            value = parse_value(value.strip())
        data[key] = value
    data.setdefault("recipe", {})
    data.setdefault("hparams", {})
    data.setdefault("model_overrides", {})
    data.setdefault("dataset_kwargs", {})
    for flag, items, field_name in (("--set", sets, "recipe"), ("--hparam", hparams, "hparams")):
        for text in items:
            scope, key, value = parse_assignment(flag, text)
            if field_name == "recipe":  # each assignment checked as it is read: the error names it
                check_recipe_keys({key: value}, f"--set {text}")
            else:
                settings.check_keywords({key: value}, f"--hparam {text}", "")
            if scope is None:
                data[field_name] = {**(data[field_name] or {}), key: value}
            else:
                over = data["model_overrides"].setdefault(scope, {})
                over[field_name] = {**(over.get(field_name) or {}), key: value}
    for text in model_revisions:
        model, eq, number = text.rpartition("=")
        value = parse_value(number.strip())
        if (eq and not model.strip()) or isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"--model-revision expects [MODEL=]N with N a positive integer, got {text!r}")
        data["model_revisions"] = {**(data.get("model_revisions") or {}), model.strip() or "*": value}
    for text in dataset_args:
        scope, key, value = parse_assignment("--dataset-arg", text)
        settings.check_keywords({key: value}, f"--dataset-arg {text}", "")
        target = data["dataset_kwargs"].setdefault(scope or "*", {})
        target[key] = value
    return BenchConfig(**data)


@dataclass(frozen=True)
class CellPlan:
    """What a bench or train command's settings make of its cells: every (model, dataset) pair's resolved
    :class:`~tactile_zoo.engine.config.CellConfig`, and the few settings the grid reads beside them."""

    configs: dict[tuple[str, str], CellConfig]
    given: dict[str, dict[str, Any]]  # the constructor keywords the user gave each model (blamed for a failed build)
    dataset_kwargs: dict[str, dict[str, Any]]  # the user's keyword arguments of each dataset (to probe it)
    settings: dict[str, Any]  # every setting of the command, as run.json records them
    quick: bool = False


def plan_cells(config: BenchConfig, models: Sequence[str], datasets: Sequence[str]) -> CellPlan:
    """The one place a command's settings become cells: each pair resolved once (:func:`resolve_cell`, the recipe's
    layers in order), its constructor keywords checked. ``tactile-zoo bench`` and ``tactile-zoo train`` both call it;
    every setting is read here first, so nothing downstream reads ``config`` for a cell again."""
    config.check_names()
    settings = config.to_dict()
    per_model = {m: config.overrides_for(m, _aliases(registry.get_model_entry(m))) for m in models}
    kwargs = {d: config.kwargs_for(d) for d in datasets}
    revisions = {m: config.revision_for(m, _aliases(registry.get_model_entry(m))) for m in models}
    for model, revision in revisions.items():
        try:
            registry.revision_keywords(registry.get_model_entry(model), revision)
        except ConfigError as exc:  # the model's revisions named, with the setting that asked for another
            raise ConfigError(f"--model-revision or a config file's model_revisions: {exc}") from None
    common = {"recipe_name": config.recipe_name, "epochs": config.epochs, "quick": config.quick,
              "refit": config.refit, "prefixes": config.prefixes, "evaluation": config.evaluation,
              "teacher_seeds": tuple(config.teachers["seeds"]) if config.teachers else ()}
    configs: dict[tuple[str, str], CellConfig] = {}
    for dataset in datasets:
        for model in models:
            recipe, hparams = per_model[model]
            configs[model, dataset] = resolve_cell(model, dataset, recipe=recipe, hparams=hparams,
                                                   dataset_kwargs=kwargs[dataset], model_revision=revisions[model],
                                                   **common)
            check_hparams(configs[model, dataset], hparams)  # an unknown constructor keyword stops the command here
    return CellPlan(configs, {m: hparams for m, (_, hparams) in per_model.items()}, kwargs, settings,
                    bool(settings["quick"]))


def _aliases(entry: registry.Entry) -> list[str]:
    """The names of a model entry that resolve to it: a ``MODEL:KEY=VALUE`` override scoped by one of them applies to
    it. A shadowed plugin's bare name is the built-in's, so ``sgnet:dim=64`` never reaches ``tz-clash:sgnet``."""
    out = []
    for name in (entry.name, entry.qualified_name):
        try:
            if registry.get_model_entry(name) is entry:
                out.append(name)
        except TactileZooError:  # a bare name two plugins share names neither of them
            pass
    return out
