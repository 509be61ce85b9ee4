"""Lookups: resolving a (normalised, possibly ``dist:``-qualified) name, listing, building and loading."""

from __future__ import annotations

import difflib
import fnmatch
import os
import re
from collections.abc import Iterable
from typing import Any

from ..errors import ConfigError, PluginError, UnknownNameError
from .discovery import _ensure_discovered
from .entries import _TABLES, DEFAULT_REVISION, Entry, _describe, normalize_name


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


def listed_name(entry: Entry) -> str:
    """The name :func:`model_names` (or :func:`list_datasets`) shows for ``entry``, the one that resolves back to it:
    the bare name where that is unambiguous, ``dist:name`` for a plugin shadowed by a built-in or clashing with
    another plugin. Callers that turn a user's name into a listed one (the harness's grid) go through here, so that
    ``dist:name`` never collapses to the bare name, which would select the built-in."""
    if entry.kind != "sensor":
        _ensure_discovered()
    for listed, candidate in _TABLES[entry.kind].visible():
        if candidate is entry:
            return listed
    return entry.qualified_name


def revision_of(entry: Entry) -> int:
    """The computational revision of a model or dataset entry (``DEFAULT_REVISION`` when its metadata has none)."""
    return int(entry.meta.get("revision", DEFAULT_REVISION))


def model_revisions(entry: Entry) -> dict[int, dict[str, Any]]:
    """Every revision model ``entry`` can still be built at, in order, each with its path: the constructor keywords
    whose defaults that revision fixes (its compute path; ``{}``: the constructor's own defaults).

    A model without ``revisions`` metadata has one, its ``revision``; every revision a model lists stays selectable
    (:func:`instantiate_model`'s ``revision``), so a cell trained at it can be rebuilt."""
    declared = entry.meta.get("revisions") or {}
    out = {int(number): dict(path) for number, path in declared.items()}
    out.setdefault(revision_of(entry), {})
    return dict(sorted(out.items()))


def revision_keywords(entry: Entry, revision: int | None = None) -> dict[str, Any]:
    """The constructor keywords that select revision ``revision`` of model ``entry`` (``None``: its default one).

    Raises:
        ConfigError: ``revision`` is not one of the model's revisions; the message names the model and its revisions.
    """
    known = model_revisions(entry)
    number = revision_of(entry) if revision is None else revision
    if isinstance(number, bool) or not isinstance(number, int) or number not in known:
        listed = ", ".join(f"{n} (default)" if n == revision_of(entry) else str(n) for n in known)
        raise ConfigError(f"model {entry.qualified_name!r} has no revision {revision!r}; its revisions: {listed}")
    return known[number]


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


def model_names(pattern: str | Iterable[str] = "*", tags: Iterable[str] | None = None) -> list[str]:
    """Registered model names matching fnmatch ``pattern`` (and having all ``tags``), sorted.

    The registry's listing; :func:`tactile_zoo.list_models` is the public one (it lists pretrained weights too)."""
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


def instantiate_model(name: str, spec: Any, *, revision: int | None = None, **hparams: Any) -> Any:
    """Build model ``name`` for a dataset ``spec`` at revision ``revision`` (``None``: the model's default one):
    ``Model(spec, **path, **hparams)``, a fresh ``torch.nn.Module``, where ``path`` is the revision's compute keywords
    (:func:`revision_keywords`; ``hparams`` win over them).

    The registry's constructor call; :func:`tactile_zoo.create_model` is the public one (it loads pretrained weights
    too).

    Raises:
        ConfigError: an unknown ``revision``, naming the model's revisions.
    """
    import torch

    entry = get_model_entry(name)
    model = entry.obj(spec, **{**revision_keywords(entry, revision), **hparams})
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
