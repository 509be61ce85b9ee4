"""One registry for models, datasets and sensors, fed by decorators and by Python entry points.

Built-ins register with the decorators when their modules are imported (``import tactile_zoo`` imports them).
Third-party distributions register through the entry-point groups ``tactile_zoo.models`` and
``tactile_zoo.datasets``. Discovery of plugins is separate from loading them, lazy (nothing is imported until the
first list/create/load call), cached, and deterministic (sorted by distribution, then entry-point name).

Name resolution, in order:

1. ``dist:name`` selects the entry ``name`` of distribution ``dist`` (every plugin entry stays reachable so);
2. a built-in (or locally registered) name always wins a clash with a plugin;
3. a plugin name that two distributions both register is ambiguous: a :class:`PluginError` names both.

Lookups are normalised (case, ``-``, ``_`` and spaces ignored): ``X-Tacformer``, ``x_tacformer`` and
``XTacformer`` are one name. This module imports nothing else from tactile-zoo but its errors.
"""

from __future__ import annotations

import difflib
import fnmatch
import importlib.metadata
import os
import re
import threading
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, TypeVar

from .errors import ConfigError, PluginError, TactileZooError, UnknownNameError

__all__ = [
    "Entry", "PluginInfo", "PluginWarning", "register_model", "register_dataset", "register_sensor",
    "list_models", "list_datasets", "list_sensors", "create_model", "load_dataset", "get_sensor",
    "get_model_entry", "get_dataset_entry", "plugins", "normalize_name", "reset_plugins", "set_plugin_policy",
    "MODEL_META_KEYS", "DATASET_META_KEYS", "ENTRY_POINT_GROUPS", "MODEL_INPUTS", "RECIPE_KEYS",
]

T = TypeVar("T")

ENTRY_POINT_GROUPS = {"model": "tactile_zoo.models", "dataset": "tactile_zoo.datasets"}

#: Keys ``register_model(**meta)`` (and a plugin's ``zoo_meta``) accept; a typo is a ConfigError, not silence.
MODEL_META_KEYS = frozenset({
    "paper", "citation", "year", "url", "description", "tags", "inputs", "recipe", "causal", "streaming",
})
#: Keys ``register_dataset(**meta)`` accepts.
DATASET_META_KEYS = frozenset({
    "sensor", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals", "num_samples",
    "folds", "protocol", "splits", "source_url", "citation", "licence", "description", "simulated", "obtain",
    "max_epochs",  # the protocol's epoch budget: caps every model's recipe on this dataset (the simulators use it)
})
SENSOR_META_KEYS = frozenset({"description", "citation"})
_META_KEYS = {"model": MODEL_META_KEYS, "dataset": DATASET_META_KEYS, "sensor": SENSOR_META_KEYS}
#: What a model's ``inputs`` metadata may name: the taxel graph, the sensor image grid, the global features.
MODEL_INPUTS = frozenset({"graph", "grid", "globals"})
#: Keys of a model's training ``recipe`` (the engine reads exactly these; anything else would be silently ignored).
RECIPE_KEYS = frozenset({
    "loss", "optimizer", "lr", "weight_decay", "amsgrad", "schedule", "max_epochs", "patience", "batch_size",
    "grad_clip",
    # optional keys the engine also reads (tactile_zoo.engine.recipe.Recipe; keep the two lists equal)
    "momentum", "nesterov", "monitor", "eval_batch_size", "label_smoothing", "rate_targets",
})
_RECIPE_CHOICES = {"loss": {"ce", "mse_rate"}, "optimizer": {"adam", "adamw", "sgd"}}
_SCHEDULE_TYPES = {"multistep", "cosine", "step", "exponential"}


class PluginWarning(UserWarning):
    """A third-party plugin was skipped or shadowed."""


def normalize_name(name: str) -> str:
    """The lookup key of a name: lower case, letters and digits only (``X-Tacformer`` -> ``xtacformer``)."""
    return re.sub(r"[^a-z0-9]", "", str(name).lower())


def _snake_case(name: str) -> str:
    name = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name)
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


@dataclass(frozen=True)
class Entry:
    """A registered model, dataset or sensor."""

    kind: str
    name: str  # canonical snake_case name
    obj: Any
    meta: Mapping[str, Any] = field(default_factory=dict)
    dist: str | None = None  # distribution of a plugin; None for built-ins and local registrations
    version: str | None = None

    @property
    def qualified_name(self) -> str:
        return f"{self.dist}:{self.name}" if self.dist else self.name

    @property
    def is_plugin(self) -> bool:
        return self.dist is not None


@dataclass
class PluginInfo:
    """One discovered entry point and what became of it (``status``: ok, failed, shadowed, clash)."""

    kind: str
    group: str
    dist: str
    version: str
    name: str
    value: str
    status: str = "pending"
    error: str | None = None


class _Table:
    """The entries of one kind: built-ins by normalised name, plugins by normalised name (possibly several)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.builtin: dict[str, Entry] = {}
        self.plugin: dict[str, list[Entry]] = {}

    def add(self, entry: Entry) -> Entry:
        key = normalize_name(entry.name)
        if entry.dist is None:
            old = self.builtin.get(key)
            if old is not None and old.obj is not entry.obj and not _same_definition(old.obj, entry.obj):
                raise TactileZooError(
                    f"{self.kind} name {entry.name!r} is already registered by {_describe(old.obj)}; "
                    f"{_describe(entry.obj)} cannot take it")
            self.builtin[key] = entry
            return entry
        same = self.plugin.setdefault(key, [])
        for i, old in enumerate(same):
            if old.dist == entry.dist:
                if old.obj is entry.obj or _same_definition(old.obj, entry.obj):
                    # the same object met twice (entry point + decorator): one registration, richer metadata wins
                    merged = Entry(entry.kind, old.name, old.obj, {**old.meta, **entry.meta}, old.dist, old.version)
                    same[i] = merged
                    return merged
                raise PluginError(f"distribution {entry.dist!r} registers two different {self.kind}s named "
                                  f"{entry.name!r}")
        same.append(entry)
        return entry

    def remove_plugins(self) -> None:
        self.plugin.clear()

    def visible(self) -> list[tuple[str, Entry]]:
        """(listed name, entry) pairs: bare names where unambiguous, ``dist:name`` otherwise."""
        out = [(e.name, e) for e in self.builtin.values()]
        for key, entries in self.plugin.items():
            bare_ok = key not in self.builtin and len(entries) == 1
            out += [(e.name if bare_ok else e.qualified_name, e) for e in entries]
        return sorted(out, key=lambda pair: pair[0])


def _same_definition(a: Any, b: Any) -> bool:
    """A re-executed module (reload, a plugin module imported twice) redefines the same module-level object.

    Objects defined inside functions (``<locals>``, ``<lambda>``) share a qualified name without being the same
    definition, so only module-level names count.
    """
    qualname = getattr(a, "__qualname__", None)
    if not isinstance(qualname, str) or "<" in qualname:
        return False
    return (getattr(a, "__module__", None), qualname) == (getattr(b, "__module__", None), getattr(b, "__qualname__",
                                                                                                  None))


def _describe(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


_TABLES = {kind: _Table(kind) for kind in ("model", "dataset", "sensor")}
_LOCK = threading.RLock()
_PLUGINS: list[PluginInfo] | None = None  # None until discovery has run
_LOADING_DIST: list[tuple[str, str]] = []  # stack of (dist, version) whose entry point is being imported
_POLICY: dict[str, bool | None] = {"strict": None, "enabled": None}
_DISCOVERED_UNDER: tuple[bool, bool] | None = None  # the (strict, enabled) policy _PLUGINS was discovered under


def _env_flag(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}


def set_plugin_policy(*, strict: bool | None = None, enabled: bool | None = None) -> None:
    """Override ``TACTILE_ZOO_STRICT_PLUGINS`` / ``TACTILE_ZOO_NO_PLUGINS`` (``None`` defers to the environment)."""
    _POLICY["strict"], _POLICY["enabled"] = strict, enabled


def _strict() -> bool:
    return _POLICY["strict"] if _POLICY["strict"] is not None else _env_flag("TACTILE_ZOO_STRICT_PLUGINS")


def _enabled() -> bool:
    return _POLICY["enabled"] if _POLICY["enabled"] is not None else not _env_flag("TACTILE_ZOO_NO_PLUGINS")


def _check_meta(kind: str, name: str, meta: Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(meta, Mapping):
        raise ConfigError(f"metadata of {kind} {name!r} must be a dict, got {type(meta).__name__}")
    unknown = sorted(set(meta) - _META_KEYS[kind])
    if unknown:
        raise ConfigError(f"unknown metadata key(s) {unknown} for {kind} {name!r}; known: {sorted(_META_KEYS[kind])}")
    if kind == "model":
        _check_model_meta(name, meta)
    return dict(meta)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_model_meta(name: str, meta: Mapping[str, Any]) -> None:
    """Value checks for the model metadata the CLI, the harness and the engine read."""

    def bad(key: str, why: str, value: Any) -> ConfigError:
        return ConfigError(f"model {name!r}: metadata {key!r} {why}, got {value!r}")

    for key in ("tags", "inputs"):
        value = meta.get(key, ())
        if not isinstance(value, list | tuple | set | frozenset) or not all(isinstance(v, str) for v in value):
            raise bad(key, "must be a list of strings", value)
    if not set(meta.get("inputs", ())) <= MODEL_INPUTS:
        raise bad("inputs", f"must name only {sorted(MODEL_INPUTS)}", meta["inputs"])
    for key in ("causal", "streaming"):
        if key in meta and not isinstance(meta[key], bool):
            raise bad(key, "must be True or False", meta[key])
    if "year" in meta and (not isinstance(meta["year"], int) or isinstance(meta["year"], bool)):
        raise bad("year", "must be an integer", meta["year"])
    if "recipe" not in meta:
        return
    recipe = meta["recipe"]
    if not isinstance(recipe, Mapping):
        raise bad("recipe", "must be a dict", recipe)
    unknown = sorted(set(recipe) - RECIPE_KEYS)
    if unknown:
        raise ConfigError(f"model {name!r}: unknown recipe key(s) {unknown}; known: {sorted(RECIPE_KEYS)}")
    for key, choices in _RECIPE_CHOICES.items():
        if key in recipe and recipe[key] not in choices:
            raise bad(f"recipe.{key}", f"must be one of {sorted(choices)}", recipe[key])
    for key in ("lr", "grad_clip"):
        if recipe.get(key) is not None and not (_is_number(recipe[key]) and recipe[key] > 0):
            raise bad(f"recipe.{key}", "must be a positive number", recipe[key])
    if "weight_decay" in recipe and not (_is_number(recipe["weight_decay"]) and recipe["weight_decay"] >= 0):
        raise bad("recipe.weight_decay", "must be a number >= 0", recipe["weight_decay"])
    for key in ("max_epochs", "batch_size", "patience"):
        value = recipe.get(key)
        if value is None and key == "patience":
            continue  # early stopping off
        if key in recipe and not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            raise bad(f"recipe.{key}", "must be a positive integer", value)
    if "amsgrad" in recipe and not isinstance(recipe["amsgrad"], bool):
        raise bad("recipe.amsgrad", "must be True or False", recipe["amsgrad"])
    schedule = recipe.get("schedule")
    if schedule is not None and (not isinstance(schedule, Mapping) or schedule.get("type") not in _SCHEDULE_TYPES):
        raise bad("recipe.schedule", f"must be None or a dict with 'type' in {sorted(_SCHEDULE_TYPES)}", schedule)


def _register(kind: str, obj: Any, name: str | None, meta: Mapping[str, Any]) -> Entry:
    canonical = _snake_case(name or getattr(obj, "name", None) or getattr(obj, "__name__", ""))
    if not canonical:
        raise ConfigError(f"cannot derive a {kind} name from {obj!r}; pass name=")
    meta = _check_meta(kind, canonical, meta)
    dist, version = _LOADING_DIST[-1] if _LOADING_DIST else (None, None)
    with _LOCK:
        return _TABLES[kind].add(Entry(kind, canonical, obj, MappingProxyType(meta), dist, version))


def _decorator(kind: str, name: Any, meta: dict[str, Any]) -> Any:
    def wrap(obj: T) -> T:
        entry = _register(kind, obj, name, meta)
        if kind != "sensor":
            try:  # the same metadata travels with the object, so an entry point to it needs no copy
                obj.zoo_meta = dict(entry.meta)  # type: ignore[attr-defined]
            except (AttributeError, TypeError):
                pass
        return obj

    if callable(name) and not isinstance(name, str):  # bare @register_model
        obj, name = name, None
        return wrap(obj)
    return wrap


def register_model(name: str | None = None, **meta: Any) -> Callable[[T], T]:
    """Register a model class or factory ``f(spec, **hparams) -> nn.Module``. Usable bare or with arguments."""
    return _decorator("model", name, meta)


def register_dataset(name: str | None = None, **meta: Any) -> Callable[[T], T]:
    """Register a dataset class or factory with :func:`load_dataset`'s signature minus the name."""
    return _decorator("dataset", name, meta)


def register_sensor(sensor: Any = None, /, **meta: Any) -> Any:
    """Register a :class:`~tactile_zoo.data.sensors.Sensor` instance (call it with the sensor, or decorate a
    zero-argument factory that returns one)."""
    if sensor is None:
        return lambda factory: register_sensor(factory(), **meta)
    if callable(sensor) and not hasattr(sensor, "edge_index"):
        sensor = sensor()
    _register("sensor", sensor, getattr(sensor, "name", None), meta)
    return sensor


# ----------------------------------------------------------------------------------------------- plugin discovery
def _discover_entry_points() -> list[tuple[PluginInfo, importlib.metadata.EntryPoint]]:
    """Find (not load) every entry point of both groups, sorted, one per (distribution, group, name)."""
    found: dict[tuple[str, str, str], tuple[PluginInfo, importlib.metadata.EntryPoint]] = {}
    for kind, group in ENTRY_POINT_GROUPS.items():
        for ep in importlib.metadata.entry_points(group=group):
            dist = ep.dist.name if ep.dist is not None else "<unknown>"
            version = ep.dist.version if ep.dist is not None else "?"
            key = (normalize_name(dist), group, ep.name)
            found.setdefault(key, (PluginInfo(kind, group, dist, version, ep.name, ep.value), ep))
    return [found[k] for k in sorted(found)]


def _load_plugin(info: PluginInfo, ep: importlib.metadata.EntryPoint) -> Entry:
    """Import one entry point and register its target under the plugin's distribution."""
    _LOADING_DIST.append((info.dist, info.version))
    try:
        target = ep.load()
        if not callable(target):
            raise PluginError(f"entry point {info.name!r} ({info.value}) is a {type(target).__name__}, not a class "
                              f"or callable")
        meta = dict(getattr(target, "zoo_meta", None) or {})
        table = _TABLES[info.kind]
        key = normalize_name(_snake_case(info.name))
        with _LOCK:
            old = table.builtin.get(key)
            if (old is not None and (old.obj is target or _same_definition(old.obj, target))
                    and str(getattr(target, "__module__", "")).partition(".")[0] != __package__):
                # the plugin module was imported (its decorator run) before discovery and filed the object as a
                # local registration; it is the same registration, and it belongs to this distribution
                del table.builtin[key]
                meta = {**old.meta, **meta}
            return _register(info.kind, target, info.name, meta)
    finally:
        _LOADING_DIST.pop()


def _settle(loaded: list[tuple[PluginInfo, Entry]]) -> None:
    """Once every plugin is loaded: mark each ok, shadowed by a built-in, or clashing with another plugin."""
    warned: set[tuple[str, str]] = set()
    for info, entry in loaded:
        table, key = _TABLES[info.kind], normalize_name(entry.name)
        rivals = table.plugin.get(key, [])
        if key in table.builtin:
            info.status = "shadowed"
            info.error = f"built-in {info.kind} {table.builtin[key].name!r} wins; use {entry.qualified_name!r}"
            warnings.warn(f"plugin {info.kind} {entry.qualified_name!r} is shadowed by the built-in of the same name; "
                          f"use {entry.qualified_name!r} to reach it", PluginWarning, stacklevel=4)
        elif len(rivals) > 1:
            dists = ", ".join(repr(e.dist) for e in rivals)
            qualified = ", ".join(repr(e.qualified_name) for e in rivals)
            info.status = "clash"
            info.error = f"{info.kind} {entry.name!r} is registered by distributions {dists}; use {qualified}"
            if _strict():
                raise PluginError(f"plugin clash: {info.error}")
            if (info.kind, key) not in warned:
                warned.add((info.kind, key))
                warnings.warn(f"plugin clash: {info.error}", PluginWarning, stacklevel=4)
        else:
            info.status = "ok"


def _ensure_discovered() -> list[PluginInfo]:
    global _PLUGINS, _DISCOVERED_UNDER
    policy = (_strict(), _enabled())
    if _PLUGINS is not None and _DISCOVERED_UNDER == policy:
        return _PLUGINS
    with _LOCK:
        if _PLUGINS is not None and _DISCOVERED_UNDER == policy:
            return _PLUGINS
        # first call, or the policy changed since (CLI flag, environment): discover under the current one; until
        # that succeeds nothing counts as discovered, so a strict-mode error leaves no half-filled cache behind
        _PLUGINS, _DISCOVERED_UNDER = None, None
        for table in _TABLES.values():
            table.remove_plugins()
        infos: list[PluginInfo] = []
        loaded: list[tuple[PluginInfo, Entry]] = []
        if policy[1]:
            for info, ep in _discover_entry_points():
                infos.append(info)
                try:
                    loaded.append((info, _load_plugin(info, ep)))
                except Exception as exc:  # a broken plugin must never take the built-ins down with it
                    info.status, info.error = "failed", f"{type(exc).__name__}: {exc}"
                    if policy[0]:
                        raise PluginError(f"plugin distribution {info.dist!r} ({info.group} entry {info.name!r} = "
                                          f"{info.value}) failed to load: {info.error}") from exc
                    warnings.warn(f"skipping plugin distribution {info.dist!r} ({info.group} entry {info.name!r} = "
                                  f"{info.value}): {info.error}", PluginWarning, stacklevel=3)
            _settle(loaded)
        _PLUGINS, _DISCOVERED_UNDER = infos, policy
        return infos


def reset_plugins() -> None:
    """Forget discovered plugins so the next lookup discovers again (after installing one, and in tests)."""
    global _PLUGINS, _DISCOVERED_UNDER
    with _LOCK:
        for table in _TABLES.values():
            table.remove_plugins()
        _PLUGINS, _DISCOVERED_UNDER = None, None


def _unregister(kind: str, name: str) -> Entry | None:
    """Remove the built-in/local ``kind`` entry ``name`` and return it (None if absent). For tests only: the
    registry has no public unregister, so that a running harness never sees a model vanish."""
    with _LOCK:
        return _TABLES[kind].builtin.pop(normalize_name(name), None)


def plugins() -> list[PluginInfo]:
    """Every discovered plugin entry point with its distribution, version, status and load error."""
    return list(_ensure_discovered())


# ----------------------------------------------------------------------------------------------- lookups
def _resolve(kind: str, name: str) -> Entry:
    if kind != "sensor":
        _ensure_discovered()
    table = _TABLES[kind]
    if not isinstance(name, str) or not name.strip():
        raise UnknownNameError(f"{kind} name must be a non-empty string, got {name!r}")
    if ":" in name:
        dist, _, bare = name.partition(":")
        for entry in table.plugin.get(normalize_name(bare), []):
            if normalize_name(entry.dist or "") == normalize_name(dist):
                return entry
        if normalize_name(dist) in {"builtin", "tactilezoo"} and normalize_name(bare) in table.builtin:
            return table.builtin[normalize_name(bare)]
    key = normalize_name(name)
    if key in table.builtin:
        return table.builtin[key]
    candidates = table.plugin.get(key, [])
    if len(candidates) == 1:
        return candidates[0]
    if len(candidates) > 1:
        names = ", ".join(e.qualified_name for e in candidates)
        raise PluginError(f"{kind} name {name!r} is registered by several plugin distributions; choose one of: {names}")
    known = [listed for listed, _ in table.visible()]
    by_key = {normalize_name(n): n for n in known}
    close = [by_key[k] for k in difflib.get_close_matches(key, list(by_key), n=3, cutoff=0.6)]
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    raise UnknownNameError(f"unknown {kind} {name!r}.{hint} Known {kind}s: {', '.join(known) or '(none)'}")


def get_model_entry(name: str) -> Entry:
    return _resolve("model", name)


def get_dataset_entry(name: str) -> Entry:
    return _resolve("dataset", name)


def _normalize_pattern(pattern: str) -> str:
    """Normalise a wildcard pattern like a name, keeping its wildcards (``X-Tac*`` -> ``xtac*``)."""
    return re.sub(r"[^a-z0-9*?\[\]!]", "", pattern.lower())


def _list(kind: str, pattern: str | Iterable[str], tags: Iterable[str] | None = None) -> list[str]:
    if kind != "sensor":
        _ensure_discovered()
    patterns = [pattern] if isinstance(pattern, str) else list(pattern)
    wanted = {tags} if isinstance(tags, str) else set(tags or ())
    out = []
    for listed, entry in _TABLES[kind].visible():
        # a qualified plugin entry (dist:name) matches a pattern through its bare name as well
        if not any(fnmatch.fnmatchcase(candidate.lower(), p.lower()) or
                   fnmatch.fnmatchcase(normalize_name(candidate), _normalize_pattern(p))
                   for p in patterns for candidate in {listed, entry.name}):
            continue
        if wanted and not wanted.issubset(set(entry.meta.get("tags", ()))):
            continue
        out.append(listed)
    return out


def list_models(pattern: str | Iterable[str] = "*", tags: Iterable[str] | None = None) -> list[str]:
    """Registered model names matching fnmatch ``pattern`` (and having all ``tags``), sorted."""
    return _list("model", pattern, tags)


def list_datasets(pattern: str | Iterable[str] = "*", tags: Iterable[str] | None = None) -> list[str]:
    """Registered dataset names matching fnmatch ``pattern``, sorted."""
    return _list("dataset", pattern, tags)


def list_sensors(pattern: str = "*") -> list[str]:
    """Registered sensor names, sorted."""
    return _list("sensor", pattern)


def get_sensor(name: str) -> Any:
    """The registered :class:`~tactile_zoo.data.sensors.Sensor` called ``name``."""
    return _resolve("sensor", name).obj


def create_model(name: str, spec: Any, **hparams: Any) -> Any:
    """Build model ``name`` for a dataset ``spec``: ``Model(spec, **hparams)``, a ``torch.nn.Module``."""
    import torch

    entry = get_model_entry(name)
    model = entry.obj(spec, **hparams)
    if not isinstance(model, torch.nn.Module):
        where = f"plugin distribution {entry.dist!r}" if entry.dist else _describe(entry.obj)
        raise PluginError(f"model {entry.qualified_name!r} from {where} returned a {type(model).__name__}, "
                          f"not a torch.nn.Module")
    return model


def load_dataset(name: str, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, **kwargs: Any) -> Any:
    """Load dataset ``name``: a ``torch.utils.data.Dataset`` of ``TactileSample`` with ``.spec`` and ``.num_folds``.

    Args:
        root: data home holding one folder per dataset; default ``$TACTILE_ZOO_DATA`` or
            ``~/.cache/tactile_zoo/data``.
        split: ``"train"``, ``"val"``, ``"test"``, a dataset's extra test split, or ``None`` for all samples.
        fold: which fold of a k-fold protocol (0 for fixed splits).
        download: fetch the raw files into ``<root>/<name>/raw/`` if they are missing.
    """
    entry = get_dataset_entry(name)
    dataset = entry.obj(root=root, split=split, fold=fold, download=download, **kwargs)
    for attr in ("spec", "num_folds"):
        if not hasattr(dataset, attr):
            where = f"plugin distribution {entry.dist!r}" if entry.dist else _describe(entry.obj)
            raise PluginError(f"dataset {entry.qualified_name!r} from {where} returned an object without .{attr}")
    return dataset
