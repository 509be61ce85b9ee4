"""Installed weights: the entry-point group ``tactile_zoo.weights``, discovered apart from loading.

A distribution ships weights by declaring an entry point in the group ``tactile_zoo.weights`` whose object is

* a manifest path (``str`` or ``Path``; a relative one is relative to the entry point's module folder),
* a list of :class:`~tactile_zoo.weights.entry.WeightEntry` objects or manifest entry dicts (a relative ``file`` is
  relative to the module folder), or a manifest document (``{"format": ..., "weights": [...]}``),
* or a callable with no arguments returning one of those.

Finding the entry points is the registry's one finder (:func:`tactile_zoo.registry.find_entry_points`, which
only lists them, sorted by distribution then entry-point name; the model and dataset plugins use it too). Loading
them happens here, on the first :func:`list_weights` or lookup, is cached, and follows the plugin policy of the
model and dataset plugins (``TACTILE_ZOO_NO_PLUGINS`` / ``--no-plugins`` turns it off,
``TACTILE_ZOO_STRICT_PLUGINS`` / ``--strict-plugins`` makes a broken distribution an error). A distribution that
fails to load is skipped with a :class:`~tactile_zoo.registry.PluginWarning` naming it
(:func:`tactile_zoo.registry.load_failure`), and listed as ``failed`` by :func:`weight_sources`.

Lookups (:func:`find_weights`): ``<distribution>:<tag>`` selects one distribution's entry; a bare tag that two
distributions both ship is ambiguous (a :class:`PluginError` names both qualified tags).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import threading
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from .. import registry
from ..errors import PluginError, UnknownNameError
from .entry import WeightEntry, tag_key
from .manifest import parse_manifest, read_manifest

__all__ = ["WEIGHTS_GROUP", "WeightSource", "weight_sources", "list_weights", "find_weights", "reset_weights"]

WEIGHTS_GROUP = "tactile_zoo.weights"


@dataclass
class WeightSource:
    """One discovered ``tactile_zoo.weights`` entry point and what became of it (``status``: ok or failed)."""

    dist: str
    version: str
    name: str
    value: str
    status: str = "pending"
    error: str | None = None
    count: int = 0


_LOCK = threading.RLock()
_STATE: dict[str, Any] = {"sources": None, "entries": None, "policy": None}


def _discover_entry_points() -> list[tuple[WeightSource, registry.FoundEntryPoint]]:
    """The group's entry points (:func:`tactile_zoo.registry.find_entry_points`), each with its status record."""
    return [(WeightSource(f.dist, f.version, f.name, f.value), f) for f in registry.find_entry_points([WEIGHTS_GROUP])]


def _module_dir(ep: importlib.metadata.EntryPoint) -> Path | None:
    spec = importlib.util.find_spec(ep.module)
    if spec is None or not spec.origin:
        return None
    return Path(spec.origin).resolve().parent


def _entries_of(obj: Any, src: WeightSource, base: Path | None) -> list[WeightEntry]:
    """The entries an entry point's (called) object stands for."""
    origin = f"{src.dist} {src.version}"
    where = f"distribution {src.dist!r} ({WEIGHTS_GROUP} entry {src.name!r})"
    if isinstance(obj, str | os.PathLike):
        path = Path(obj)
        if not path.is_absolute() and base is not None:
            path = base / path
        return read_manifest(path, origin=origin, dist=src.dist)
    if isinstance(obj, Mapping):
        return parse_manifest(obj, where, base_dir=base, origin=origin, dist=src.dist)
    if isinstance(obj, list | tuple):
        out = []
        for i, item in enumerate(obj):
            if isinstance(item, WeightEntry):
                out.append(replace(item, dist=src.dist, origin=origin, base_dir=item.base_dir or (
                    None if base is None else str(base))))
            else:
                out.append(WeightEntry.from_dict(item, f"{where}: entry {i}", base_dir=base, origin=origin,
                                                 dist=src.dist))
        keys = [tag_key(e.tag) for e in out]
        if len(set(keys)) != len(keys):
            raise PluginError(f"{where} lists a tag twice")
        return out
    raise PluginError(f"{where} is a {type(obj).__name__}; expected a manifest path, a list of WeightEntry objects "
                      f"or manifest entries, or a callable returning one of them")


def _load_source(src: WeightSource, ep: importlib.metadata.EntryPoint) -> list[WeightEntry]:
    target = ep.load()
    if callable(target) and not isinstance(target, WeightEntry):
        target = target()
    return _entries_of(target, src, _module_dir(ep))


def _ensure_discovered() -> tuple[list[WeightSource], list[WeightEntry]]:
    policy = (registry._strict(), registry._enabled())
    with _LOCK:
        if _STATE["sources"] is not None and _STATE["policy"] == policy:
            return _STATE["sources"], _STATE["entries"]
        _STATE.update(sources=None, entries=None, policy=None)  # a strict-mode error leaves no half-filled cache
        sources: list[WeightSource] = []
        entries: list[WeightEntry] = []
        if policy[1]:
            for src, found in _discover_entry_points():
                sources.append(src)
                try:
                    loaded = _load_source(src, found.entry_point)
                except Exception as exc:  # a broken weights distribution must never take the others down
                    src.status = "failed"
                    src.error = registry.load_failure("weights", found, exc, strict=policy[0])
                    continue
                src.status, src.count = "ok", len(loaded)
                entries += loaded
        entries.sort(key=lambda e: (tag_key(e.tag), registry.normalize_name(e.dist or "")))
        _STATE.update(sources=sources, entries=entries, policy=policy)
        return sources, entries


def reset_weights() -> None:
    """Forget discovered weights so the next lookup discovers again (after installing a distribution, in tests)."""
    with _LOCK:
        _STATE.update(sources=None, entries=None, policy=None)


def weight_sources() -> list[WeightSource]:
    """Every discovered ``tactile_zoo.weights`` entry point with its distribution, status and load error."""
    return list(_ensure_discovered()[0])


def list_weights(model: str | None = None, dataset: str | None = None) -> list[WeightEntry]:
    """The installed weights, sorted by tag (then distribution); only ``model``'s or ``dataset``'s when given."""
    out = _ensure_discovered()[1]
    if model is not None:
        out = [e for e in out if registry.normalize_name(e.model.rpartition(":")[2]) ==
               registry.normalize_name(model.rpartition(":")[2])]
    if dataset is not None:
        out = [e for e in out if registry.normalize_name(e.dataset) == registry.normalize_name(dataset)]
    return list(out)


def find_weights(tag: str) -> WeightEntry:
    """The installed entry with ``tag`` (``<distribution>:<tag>`` picks one distribution's)."""
    dist, colon, bare = tag.rpartition(":") if ":" in tag else ("", "", tag)
    entries = _ensure_discovered()[1]
    matches = [e for e in entries if tag_key(e.tag) == tag_key(bare)
               and (not colon or registry.normalize_name(e.dist or "") == registry.normalize_name(dist))]
    if len(matches) == 1:
        return matches[0]
    if len(matches) > 1:
        names = ", ".join(repr(e.qualified_tag) for e in matches)
        raise PluginError(f"weights tag {bare!r} is shipped by several distributions; choose one of {names}")
    known = ", ".join(e.qualified_tag for e in entries) or "none installed"
    raise UnknownNameError(f"no installed weights tagged {tag!r}; installed: {known}")
