"""Parsers of the bench settings that are lists or counts (seeds, folds, prefixes), the cap on a grid's size, and
the check of every setting against the one schema (:func:`check_settings`).

:mod:`.config` re-exports them; they read values only, never a configuration object.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

from .. import settings
from ..errors import ConfigError
from ..recipe import check_recipe_keys
from ..settings import check_prefixes

__all__ = ["MAX_CELLS", "parse_positive_int", "parse_seeds", "parse_folds", "parse_prefixes", "check_settings"]

#: The most cells (and so seeds) one bench command takes: weeks of computing at a second per cell, far above any grid
#: the zoo's tables need (the largest is a few hundred), and small enough that the grid is listed in about a second.
#: A larger study is several commands sharing one ``--out`` (its cells are reused across them).
MAX_CELLS = 10_000


def parse_positive_int(flag: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, str) and re.fullmatch(r"\s*\d+\s*", value):
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{flag} must be an integer >= {minimum}, got {value!r}")
    return value


def parse_seeds(value: Any) -> list[int]:
    """``"0,1,2"``, ``"0-4"``, ``3``, ``[0, 1]`` -> sorted distinct non-negative seeds."""
    if isinstance(value, int) and not isinstance(value, bool):
        value = [value]
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, Sequence) or not value:
        raise ConfigError(f"--seeds must be a comma-separated list of non-negative integers such as 0,1,2 (or a "
                          f"range 0-4), got {value!r}")
    spans: list[tuple[int, int]] = []  # inclusive ranges, counted before any is expanded
    for item in value:
        tokens = [item] if isinstance(item, int) and not isinstance(item, bool) else str(item).split(",")
        for token in tokens:
            text = str(token).strip()
            if isinstance(token, int) and not isinstance(token, bool) and token >= 0:
                spans.append((token, token))
            elif re.fullmatch(r"\d+", text):
                spans.append((int(text), int(text)))
            elif (m := re.fullmatch(r"(\d+)\s*-\s*(\d+)", text)) and int(m.group(1)) <= int(m.group(2)):
                spans.append((int(m.group(1)), int(m.group(2))))
            else:
                raise ConfigError(f"--seeds: {text!r} is not a non-negative integer or a range like 0-4 (got "
                                  f"{value!r})")
    if any(high >= 2**63 for _, high in spans):
        raise ConfigError("--seeds: a seed must be below 2**63")
    count = _count_distinct(spans)
    if count > MAX_CELLS:
        raise ConfigError(f"--seeds {_shown(value)}: {count:,} seeds; a bench command runs at most {MAX_CELLS:,} cells "
                          f"(split the study into several commands sharing one --out)")
    return sorted({seed for low, high in spans for seed in range(low, high + 1)})


def _count_distinct(spans: list[tuple[int, int]]) -> int:
    """How many integers the inclusive ranges ``spans`` hold together (overlaps counted once)."""
    count, reached = 0, -1
    for low, high in sorted(spans):
        if high > reached:
            count += high - max(low, reached + 1) + 1
            reached = high
    return count


def _shown(value: Any) -> str:
    return ",".join(str(v) for v in value) if isinstance(value, list | tuple) else str(value)


def parse_folds(value: Any) -> int | None:
    """``--folds K``: run at most the first K folds of each dataset (``None``: every fold it defines)."""
    if value is None or (isinstance(value, str) and value.strip().lower() in {"all", ""}):
        return None
    try:
        return parse_positive_int("--folds", value)
    except ConfigError:
        raise ConfigError(f"--folds must be a positive integer (run the first K folds of each dataset) or 'all', got "
                          f"{value!r}") from None


def parse_prefixes(value: Any) -> list[float]:
    """Prefix fractions in (0, 1] for early classification; 1.0 is always included (the schema's rule:
    :func:`tactile_zoo.settings.check_prefixes`, which keeps the ``accuracy_at_<percent>`` columns distinct)."""
    return check_prefixes(value)


#: the flag that gives each setting on the command line: an error about a setting names it (a config file's errors
#: name the file and the key instead)
_FLAGS = {"plugin_modules": "--plugin-module", "recipe_name": "--recipe", "recipe": "recipe", "hparams": "hparams",
          "model_overrides": "model_overrides", "dataset_kwargs": "dataset_kwargs"}


def check_settings(data: Mapping[str, Any], where: str = "") -> None:
    """Every setting in ``data`` (a config file's, or a :class:`BenchConfig`'s) checked against the one schema,
    :class:`tactile_zoo.settings.BenchSettings`: its type and range, and the keys and values of the nested recipe
    (:func:`~tactile_zoo.recipe.check_recipe_keys`), ``hparams`` and dataset keywords. ``where`` names a file
    (``--config FILE``); without it an error names the setting's flag."""
    prefix = f"{where}: " if where else ""
    for model, over in (data.get("model_overrides") or {}).items() if isinstance(data.get("model_overrides"),
                                                                                   Mapping) else ():
        unknown = sorted(set(over) - {"recipe", "hparams"}, key=str) if isinstance(over, Mapping) else []
        if unknown:
            raise ConfigError(f"{prefix}model_overrides.{model}: unknown key(s) {unknown}; allowed: recipe, hparams")
    try:  # their own messages, which say what the values mean
        if isinstance(data.get("folds"), int) and not isinstance(data["folds"], bool):
            parse_folds(data["folds"])
        if where and "seeds" in data:
            parse_seeds(data["seeds"])
    except ConfigError as exc:
        raise ConfigError(re.sub(r"^--(seeds|folds)", f"{prefix}\\1", str(exc)) if where else str(exc)) from None
    for key, value in data.items():
        if isinstance(value, tuple | range):  # a sequence given in Python checks as the list it stands for
            value = list(value)
        settings.check_field(settings.BenchSettings, key, value, where,
                             key if where else _FLAGS.get(key, f"--{key.replace('_', '-')}"))
    if where and data.get("prefixes") is not None:
        settings.check_prefixes(data["prefixes"], f"{prefix}prefixes")
    if isinstance(data.get("recipe"), Mapping):
        check_recipe_keys(data["recipe"], f"{prefix}recipe")
    if "hparams" in data:
        settings.check_keywords(data["hparams"], where, "hparams")
    for model, over in (data.get("model_overrides") or {}).items():
        if "recipe" in over:
            check_recipe_keys(over["recipe"], f"{prefix}model_overrides.{model}.recipe")
        if "hparams" in over:
            settings.check_keywords(over["hparams"], where, f"model_overrides.{model}.hparams")
    for name, kwargs in (data.get("dataset_kwargs") or {}).items():
        settings.check_keywords(kwargs, where, f"dataset_kwargs.{name}")
