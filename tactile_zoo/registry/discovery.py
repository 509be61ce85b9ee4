"""Entry-point discovery, for every group tactile-zoo reads, and ``--plugin-module`` imports.

One finder (:func:`find_entry_points`) serves the model and dataset plugins (``tactile_zoo.models``,
``tactile_zoo.datasets``, loaded here) and the weights distributions (``tactile_zoo.weights``, loaded by
:mod:`tactile_zoo.weights.discovery`), in the manner of flake8's plugin finder: finding is kept apart from loading
(the finder imports nothing), the order is deterministic (sorted by distribution, then group, then entry-point
name, one entry per key), and a failure to load names the distribution and the entry point
(:func:`load_failure`). Loading runs lazily on the first lookup and is cached. A plugin that fails to load is
skipped with a :class:`PluginWarning` naming its distribution, or is an error under the strict policy; the policy
(:func:`set_plugin_policy`, ``TACTILE_ZOO_STRICT_PLUGINS``, ``TACTILE_ZOO_NO_PLUGINS``) is one for all groups.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
import warnings
from collections.abc import Iterable
from dataclasses import dataclass

from .._env import env_flag
from ..errors import PluginError
from .entries import _LOADING_DIST, _LOCK, _TABLES, Entry, _register, _same_definition, _snake_case, normalize_name

ENTRY_POINT_GROUPS = {"model": "tactile_zoo.models", "dataset": "tactile_zoo.datasets"}


@dataclass(frozen=True)
class FoundEntryPoint:
    """One entry point found, not loaded: its group, distribution (name and version), name and target."""

    group: str
    dist: str
    version: str
    name: str
    value: str
    entry_point: importlib.metadata.EntryPoint

    def describe(self) -> str:
        """``'dist' (group entry 'name' = module:attr)``: what a message about this entry point names."""
        return f"{self.dist!r} ({self.group} entry {self.name!r} = {self.value})"


def find_entry_points(groups: Iterable[str]) -> list[FoundEntryPoint]:
    """Find (not load) every entry point of ``groups``: one per (distribution, group, name), sorted by the
    normalised distribution name, then group, then entry-point name, whatever order the environment lists them in
    (the first found wins a duplicate, as ``importlib.metadata`` lists a distribution once per path entry)."""
    found: dict[tuple[str, str, str], FoundEntryPoint] = {}
    for group in groups:
        for ep in importlib.metadata.entry_points(group=group):
            dist = ep.dist.name if ep.dist is not None else "<unknown>"
            version = ep.dist.version if ep.dist is not None else "?"
            found.setdefault((normalize_name(dist), group, ep.name), FoundEntryPoint(group, dist, version, ep.name,
                                                                                     ep.value, ep))
    return [found[key] for key in sorted(found)]


def load_failure(what: str, found: FoundEntryPoint, exc: BaseException, strict: bool) -> str:
    """Handle ``exc``, raised while loading ``found`` (``what``: ``"plugin"``, ``"weights"``): a
    :class:`PluginError` naming the distribution under the strict policy, else a :class:`PluginWarning`. Returns
    the error text (``Type: message``) for the status listing."""
    error = f"{type(exc).__name__}: {exc}"
    if strict:
        raise PluginError(f"{what} distribution {found.describe()} failed to load: {error}") from exc
    warnings.warn(f"skipping {what} distribution {found.describe()}: {error}", PluginWarning, stacklevel=4)
    return error

class PluginWarning(UserWarning):
    """A third-party plugin was skipped or shadowed."""


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


_PLUGINS: list[PluginInfo] | None = None  # None until discovery has run
_POLICY: dict[str, bool | None] = {"strict": None, "enabled": None}
_DISCOVERED_UNDER: tuple[bool, bool] | None = None  # the (strict, enabled) policy _PLUGINS was discovered under


def set_plugin_policy(*, strict: bool | None = None, enabled: bool | None = None) -> None:
    """Override ``TACTILE_ZOO_STRICT_PLUGINS`` / ``TACTILE_ZOO_NO_PLUGINS`` (``None`` defers to the environment)."""
    _POLICY["strict"], _POLICY["enabled"] = strict, enabled


def _strict() -> bool:
    return _POLICY["strict"] if _POLICY["strict"] is not None else env_flag("TACTILE_ZOO_STRICT_PLUGINS")


def _enabled() -> bool:
    return _POLICY["enabled"] if _POLICY["enabled"] is not None else not env_flag("TACTILE_ZOO_NO_PLUGINS")


def _discover_entry_points() -> list[tuple[PluginInfo, FoundEntryPoint]]:
    """The model and dataset plugins' entry points (:func:`find_entry_points`), each with its status record."""
    kinds = {group: kind for kind, group in ENTRY_POINT_GROUPS.items()}
    return [(PluginInfo(kinds[f.group], f.group, f.dist, f.version, f.name, f.value), f)
            for f in find_entry_points(ENTRY_POINT_GROUPS.values())]


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
                    and str(getattr(target, "__module__", "")).partition(".")[0] != "tactile_zoo"):
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
            for info, found in _discover_entry_points():
                infos.append(info)
                try:
                    loaded.append((info, _load_plugin(info, found.entry_point)))
                except Exception as exc:  # a broken plugin must never take the built-ins down with it
                    info.status = "failed"
                    info.error = load_failure("plugin", found, exc, strict=policy[0])
            _settle(loaded)
        _PLUGINS, _DISCOVERED_UNDER = infos, policy
        return infos


def import_plugin_modules(modules: Iterable[str]) -> None:
    """Import modules that register models or datasets with the decorators (``--plugin-module``), in order.

    The explicit counterpart of entry-point discovery, for code that is not an installed distribution. A module that
    fails to import is a :class:`PluginError` naming it; one imported before is not imported again.
    """
    for module in modules:
        if module in sys.modules:
            continue
        try:
            importlib.import_module(module)
        except Exception as exc:
            raise PluginError(f"--plugin-module {module!r} cannot be imported: {type(exc).__name__}: {exc}") from None


def reset_plugins() -> None:
    """Forget discovered plugins so the next lookup discovers again (after installing one, and in tests)."""
    global _PLUGINS, _DISCOVERED_UNDER
    with _LOCK:
        for table in _TABLES.values():
            table.remove_plugins()
        _PLUGINS, _DISCOVERED_UNDER = None, None


def plugins() -> list[PluginInfo]:
    """Every discovered plugin entry point with its distribution, version, status and load error."""
    return list(_ensure_discovered())
