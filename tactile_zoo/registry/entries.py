"""Entries and registration: the tables of models, datasets and sensors, metadata checks and the decorators.

A built-in or locally defined object registers with :func:`register_model`, :func:`register_dataset` or
:func:`register_sensor` when its module is imported; a plugin's object registers the same way while discovery
imports its entry point (:mod:`.discovery` tells this module which distribution is loading).
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, TypeVar

from ..errors import ConfigError, PluginError, TactileZooError
from ..recipe import check_named_recipe

T = TypeVar("T")

#: Keys ``register_model(**meta)`` (and a plugin's ``zoo_meta``) accept; a typo is a ConfigError, not silence.
MODEL_META_KEYS = frozenset({
    "paper", "citation", "year", "url", "description", "tags", "inputs", "recipe", "recipes", "default_recipe",
    "causal", "streaming", "revision", "revisions",
    # optional, for the generated pages (python -m tools.model_pages) and the zoo's tests; never part of a cell hash
    "display_name", "family", "reference", "test_hparams",
})
#: Keys ``register_dataset(**meta)`` accepts.
DATASET_META_KEYS = frozenset({
    "sensor", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals", "num_samples",
    "folds", "protocol", "splits", "source_url", "citation", "licence", "description", "simulated", "obtain",
    "max_epochs",  # the protocol's epoch budget: caps every model's recipe on this dataset (the simulators use it)
    "revision",
})
SENSOR_META_KEYS = frozenset({"description", "citation"})
#: A model's or dataset's computational revision when its metadata names none. Bump ``revision`` whenever what the
#: code computes changes (layers, initialisation, a sensor graph, preprocessing): it is part of every cell hash.
#: A model whose revisions differ only in the defaults of its compute keywords keeps the older ones selectable:
#: its ``revisions`` metadata maps each revision to those defaults (:func:`~tactile_zoo.registry.model_revisions`).
DEFAULT_REVISION = 1
_META_KEYS = {"model": MODEL_META_KEYS, "dataset": DATASET_META_KEYS, "sensor": SENSOR_META_KEYS}
#: What a model's ``inputs`` metadata may name: the taxel graph, the sensor image grid, the global features.
MODEL_INPUTS = frozenset({"graph", "grid", "globals"})
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
_LOADING_DIST: list[tuple[str, str]] = []  # stack of (dist, version) whose entry point is being imported


def _check_meta(kind: str, name: str, meta: Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(meta, Mapping):
        raise ConfigError(f"metadata of {kind} {name!r} must be a dict, got {type(meta).__name__}")
    unknown = sorted(set(meta) - _META_KEYS[kind])
    if unknown:
        raise ConfigError(f"unknown metadata key(s) {unknown} for {kind} {name!r}; known: {sorted(_META_KEYS[kind])}")
    revision = meta.get("revision", DEFAULT_REVISION)
    if not isinstance(revision, int) or isinstance(revision, bool) or revision < 1:
        raise ConfigError(f"{kind} {name!r}: metadata 'revision' must be a positive integer, got {revision!r}")
    if kind == "model":
        _check_model_meta(name, meta)
        if "revisions" in meta:
            _check_revisions(name, meta["revisions"], revision)
    return dict(meta)


def _check_revisions(name: str, revisions: Any, default: int) -> None:
    """``revisions``: revision -> {compute keyword: its default at that revision}, naming the default ``revision``.

    Each entry is a path through the same code: what a revision changes is only which compute path its constructor
    keywords default to, so every listed revision can still be built (and its cells rerun)."""
    where = f"model {name!r}: metadata 'revisions'"
    if not isinstance(revisions, Mapping) or not revisions:
        raise ConfigError(f"{where} must map revision numbers to dicts of constructor keywords, got {revisions!r}")
    for number, path in revisions.items():
        if not isinstance(number, int) or isinstance(number, bool) or number < 1:
            raise ConfigError(f"{where}: {number!r} is not a positive integer revision")
        if not isinstance(path, Mapping) or not all(isinstance(k, str) and k.isidentifier() for k in path):
            raise ConfigError(f"{where}: revision {number} must map keyword names to values, got {path!r}")
    if default not in revisions:
        raise ConfigError(f"{where} must list the default revision {default} (metadata 'revision'); it lists "
                          f"{sorted(revisions)}")


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
    for key in ("display_name", "family"):
        if key in meta and (not isinstance(meta[key], str) or not meta[key].strip()):
            raise bad(key, "must be a non-empty string", meta[key])
    for key in ("reference", "test_hparams"):
        if key in meta and (not isinstance(meta[key], Mapping) or not all(isinstance(k, str) for k in meta[key])):
            raise bad(key, "must be a dict with string keys", meta[key])
    if "recipes" in meta or "recipe" in meta:
        _check_recipes(name, meta)


def _check_recipes(name: str, meta: Mapping[str, Any]) -> None:
    """``recipes`` (name -> recipe) is where named recipes live; each is validated against the one recipe schema
    (:mod:`tactile_zoo.recipe`), so a typo fails at registration, not mid-grid."""
    recipes = meta.get("recipes", {"default": meta.get("recipe")})
    if not isinstance(recipes, Mapping) or not recipes or not all(isinstance(k, str) and k for k in recipes):
        raise ConfigError(f"model {name!r}: metadata 'recipes' must map recipe names to recipes, got {recipes!r}")
    for recipe_name, recipe in recipes.items():
        if not isinstance(recipe, Mapping):
            raise ConfigError(f"model {name!r}: metadata 'recipe' {recipe_name!r} must be a dict, got {recipe!r}")
        check_named_recipe(recipe, where=f"model {name!r}: recipe {recipe_name!r}")
    default = meta.get("default_recipe", "source" if "source" in recipes else next(iter(recipes)))
    if default not in recipes:
        raise ConfigError(f"model {name!r}: default_recipe {default!r} is not one of its recipes {sorted(recipes)}")
    if "recipe" in meta and "recipes" in meta and dict(meta["recipe"]) != dict(recipes[default]):
        raise ConfigError(f"model {name!r}: metadata 'recipe' differs from its default recipe {default!r}; give "
                          f"'recipes' only")


def _normalise_recipes(kind: str, meta: dict[str, Any]) -> dict[str, Any]:
    """Every model entry carries ``recipes``, ``default_recipe`` and, derived from them, ``recipe`` (the default one,
    which most readers want); a lone ``recipe`` (a plugin's) is the recipe named ``"default"``."""
    if kind != "model" or ("recipes" not in meta and "recipe" not in meta):
        return meta
    recipes = {k: dict(v) for k, v in (meta.get("recipes") or {"default": meta["recipe"]}).items()}
    default = meta.get("default_recipe", "source" if "source" in recipes else next(iter(recipes)))
    return {**meta, "recipes": recipes, "default_recipe": default, "recipe": dict(recipes[default])}


def _copy_revisions(kind: str, meta: dict[str, Any]) -> dict[str, Any]:
    """A model's ``revisions`` as plain dicts in the order of their numbers (a copy: the caller's dict may change)."""
    if kind != "model" or "revisions" not in meta:
        return meta
    return {**meta, "revisions": {number: dict(meta["revisions"][number]) for number in sorted(meta["revisions"])}}


def model_recipe(meta: Mapping[str, Any], name: str | None = None) -> tuple[str, Mapping[str, Any] | None]:
    """(name, recipe) of a model's recipe ``name`` (``None``: its default), as registered; ``(name, None)`` means
    the harness's default recipe for a model that registers none. Resolving it (its dataset section, the epoch budget,
    overrides) is :func:`tactile_zoo.engine.config.resolve_model_recipe`'s alone."""
    recipes = meta.get("recipes") or {}
    if name is None:
        name = meta.get("default_recipe", "default")
        return name, recipes.get(name, meta.get("recipe"))
    if name in recipes:
        return name, recipes[name]
    if not recipes and name == "default":
        return name, None
    known = ", ".join(sorted(recipes)) or "none (it trains with the harness's default recipe, called 'default')"
    raise ConfigError(f"model has no recipe named {name!r}; its recipes: {known}")


def _register(kind: str, obj: Any, name: str | None, meta: Mapping[str, Any]) -> Entry:
    canonical = _snake_case(name or getattr(obj, "name", None) or getattr(obj, "__name__", ""))
    if not canonical:
        raise ConfigError(f"cannot derive a {kind} name from {obj!r}; pass name=")
    meta = _copy_revisions(kind, _normalise_recipes(kind, _check_meta(kind, canonical, meta)))
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


def _unregister(kind: str, name: str) -> Entry | None:
    """Remove the built-in/local ``kind`` entry ``name`` and return it (None if absent). For tests only: the
    registry has no public unregister, so that a running harness never sees a model vanish."""
    with _LOCK:
        return _TABLES[kind].builtin.pop(normalize_name(name), None)
