"""Bounded YAML: the one reader of settings and recipe files (a bench ``--config``, a recipe file, a study file).

A settings file is small. :func:`read_yaml_file` reads at most :data:`MAX_FILE_BYTES` of it, so ``--config
/dev/zero`` fails at once instead of filling the memory, and :func:`load_yaml` refuses a document whose aliases
expand to more than :data:`MAX_EXPANDED_NODES` nodes, or that uses more than :data:`MAX_ALIASES` aliases: an anchor
bomb (nine anchors of nine aliases each name a billion strings) fails before anything walks it. Numbers in
exponent form (``1e-3``, which YAML 1.1 reads as a string) are numbers, as in YAML 1.2. Only plain data is built
(PyYAML's safe loader).
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError

__all__ = ["MAX_FILE_BYTES", "MAX_ALIASES", "MAX_EXPANDED_NODES", "read_yaml_file", "load_yaml"]

#: the largest settings or recipe file read (the zoo's largest is a few kilobytes)
MAX_FILE_BYTES = 1 << 20
#: the most aliases (``*name``) one document may use
MAX_ALIASES = 100
#: the most nodes a document may hold once its aliases are expanded
MAX_EXPANDED_NODES = 100_000


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``1e-3`` as the number it means."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _expanded_size(node: yaml.Node, memo: dict[int, int], open_: set[int]) -> int:
    """How many nodes ``node`` holds with every alias expanded (a node reached twice counts twice)."""
    key = id(node)
    if key in memo:
        return memo[key]
    if key in open_:
        raise ConfigError("a recursive alias (an anchor used inside itself)")
    open_.add(key)
    size = 1
    if isinstance(node, yaml.SequenceNode):
        size += sum(_expanded_size(item, memo, open_) for item in node.value)
    elif isinstance(node, yaml.MappingNode):
        size += sum(_expanded_size(k, memo, open_) + _expanded_size(v, memo, open_) for k, v in node.value)
    open_.discard(key)
    memo[key] = size
    if size > MAX_EXPANDED_NODES:
        raise ConfigError(f"its aliases expand to more than {MAX_EXPANDED_NODES:,} values (an anchor bomb?)")
    return size


def load_yaml(text: str, where: str, invalid: str = "not valid YAML") -> Any:
    """The plain data of the YAML document ``text``; ``where`` names it in a :class:`ConfigError` (``invalid``,
    too many aliases, an alias expansion beyond :data:`MAX_EXPANDED_NODES`)."""
    loader = _Loader(text)
    try:
        # an alias is written ``*name``: a text without a star has none, and is parsed once, not twice
        aliases = sum(1 for event in yaml.parse(text, Loader=_Loader) if isinstance(event, yaml.AliasEvent)) \
            if "*" in text else 0
        if aliases > MAX_ALIASES:
            raise ConfigError(f"{where}: {aliases} aliases; a settings file may use at most {MAX_ALIASES}")
        try:  # composing, measuring and building recurse once per level of nesting
            node = loader.get_single_node()
            if node is None:
                return None
            try:
                _expanded_size(node, {}, set())
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc}") from None
            return loader.construct_document(node)
        except RecursionError:
            raise ConfigError(f"{where}: nested too deeply") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        why = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{where}: {invalid}: {why}{at}") from None
    finally:
        loader.dispose()


def read_yaml_file(path: str | PathLike[str] | Any, where: str | None = None,
                   invalid: str = "not valid YAML") -> Any:
    """The plain data of the YAML file at ``path`` (a path or an :mod:`importlib.resources` traversable), read with
    the caps of the module docstring. ``where`` names it in a :class:`ConfigError` (default: the path)."""
    source = path if hasattr(path, "open") and not isinstance(path, str | PathLike) else Path(path)
    where = where or str(source)
    try:
        with source.open("rb") as stream:
            raw = stream.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(f"{where}: larger than {MAX_FILE_BYTES / 2**20:g} MiB; a settings file is far smaller (is it "
                          f"the right file?)")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{where}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return load_yaml(text, where, invalid)
