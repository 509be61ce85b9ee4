"""Parsers of the bench settings that are lists or counts (seeds, folds, prefixes), and the cap on a grid's size.

:mod:`.config` re-exports them; they read values only, never a configuration object.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from ..errors import ConfigError

__all__ = ["MAX_CELLS", "parse_positive_int", "parse_seeds", "parse_folds", "parse_prefixes"]

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
    """Prefix fractions in (0, 1] for early classification; 1.0 is always included."""
    if isinstance(value, str):
        value = [v for v in value.split(",") if v.strip()]
    if not isinstance(value, Sequence) or not value:
        raise ConfigError(f"--prefixes must be a comma-separated list of fractions in (0, 1], got {value!r}")
    out = set()
    for item in value:
        try:
            frac = float(item)
        except (TypeError, ValueError):
            raise ConfigError(f"--prefixes: {item!r} is not a number") from None
        if frac > 1 and frac <= 100:  # percentages
            frac /= 100
        if not 0 < frac <= 1:
            raise ConfigError(f"--prefixes: {item!r} is not a fraction in (0, 1] (or a percentage)")
        out.add(round(frac, 6))
    return sorted(out | {1.0})
