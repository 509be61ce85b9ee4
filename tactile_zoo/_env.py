"""The package's environment variables: one parser for the boolean ones, one for those that name a choice.

A boolean variable accepts ``1``, ``true``, ``yes``, ``on`` (on) and ``0``, ``false``, ``no``, ``off`` (off), in any
case and with surrounding whitespace. Unset, empty or blank means the variable's default (off for every variable
here), as ``VAR= command`` reads in a shell. Anything else (``TACTILE_ZOO_TUNING=banana``) is a
:class:`~tactile_zoo.errors.ConfigError` naming the variable and its value: a setting that is silently ignored is a
wrong answer without an error (a "tuning" run that read the test split). Every read goes through :func:`env_flag`;
the command line calls :func:`check_environment` before any command runs, so a bad value stops it with one line.

One variable here is not the package's own: matplotlib's ``MPLBACKEND``. matplotlib reads it on import and raises on
a name it does not know, which would end a bench at its plots with a traceback, after every cell had run; the check
asks matplotlib itself whether it takes the value (no list of backends is kept here) and refuses the value before any
work. The bench draws its plots with the Agg backend whatever the variable names.

This module sits at the bottom of the package (beside :mod:`.errors`): every layer may read its variables here.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from .errors import ConfigError

__all__ = ["env_flag", "env_choice", "check_environment", "check_matplotlib_backend", "BOOLEAN_VARIABLES",
           "CHOICE_VARIABLES", "TRUE_WORDS", "FALSE_WORDS", "MATPLOTLIB_BACKEND_VARIABLE"]

TRUE_WORDS = ("1", "true", "yes", "on")
FALSE_WORDS = ("0", "false", "no", "off")

#: Every boolean variable the package reads, and what it turns on.
BOOLEAN_VARIABLES = {
    "TACTILE_ZOO_TUNING": "tuning mode: reading a test split raises (tactile_zoo.data.guard)",
    "TACTILE_ZOO_NO_PLUGINS": "no entry-point plugin discovery (--no-plugins)",
    "TACTILE_ZOO_STRICT_PLUGINS": "a plugin that fails to load is an error (--strict-plugins)",
    "TACTILE_ZOO_NO_HUGEPAGES": "no transparent-huge-page advice for large CPU tensors (tactile_zoo.nn.hugepages)",
    "TACTILE_ZOO_KEEP_DENORMALS": "compute with subnormal floats instead of flushing them to zero",
    "TACTILE_ZOO_DEFAULT_MALLOC": "training processes keep glibc's malloc defaults (tactile_zoo.engine.malloc)",
    "TACTILE_ZOO_CUDA_GRAPHS": "CUDA training replays each full batch's forward and backward from CUDA graphs "
                               "(tactile_zoo.engine.cuda_graph)",
}
#: Every variable that names one of a fixed set of choices, with its choices (the first is the default).
CHOICE_VARIABLES = {
    "TACTILE_ZOO_LIF_BACKEND": ("auto", "numba", "torch"),  # the fused LIF on CPU: read in tactile_zoo.nn.backend only
}
#: matplotlib's own variable: the plotting backend it starts with (checked by :func:`check_matplotlib_backend`).
MATPLOTLIB_BACKEND_VARIABLE = "MPLBACKEND"


def env_flag(name: str, default: bool = False) -> bool:
    """The boolean environment variable ``name``: ``default`` when it is unset, empty or blank.

    Raises:
        ConfigError: the value is not one of 1/0, true/false, yes/no, on/off (any case).
    """
    raw = os.environ.get(name)
    text = (raw or "").strip().lower()
    if not text:
        return default
    if text in TRUE_WORDS:
        return True
    if text in FALSE_WORDS:
        return False
    raise ConfigError(f"environment variable {name}={raw!r} is not a boolean: use 1/0, true/false, yes/no or on/off "
                      f"(any case), or leave it unset")


def env_choice(name: str, choices: Sequence[str]) -> str:
    """The environment variable ``name`` as one of ``choices`` (compared in lower case, whitespace trimmed);
    ``choices[0]`` when it is unset, empty or blank.

    Raises:
        ConfigError: the value is none of ``choices``.
    """
    raw = os.environ.get(name)
    text = (raw or "").strip().lower()
    if not text:
        return choices[0]
    if text not in choices:
        raise ConfigError(f"environment variable {name}={raw!r} must be one of {', '.join(choices)} (or unset: "
                          f"{choices[0]})")
    return text


def check_matplotlib_backend() -> None:
    """Refuse an ``MPLBACKEND`` that matplotlib does not take (unset or empty: matplotlib's default, nothing to check).

    matplotlib validates the variable when it is first imported; when it already was (before the variable was set),
    its own validator is asked. A refused import leaves no half-imported matplotlib behind.

    Raises:
        ConfigError: naming the variable and its value.
    """
    raw = os.environ.get(MATPLOTLIB_BACKEND_VARIABLE)
    if not raw:  # matplotlib ignores an empty value too
        return
    try:
        from matplotlib import rcsetup  # the first import of matplotlib reads MPLBACKEND: ValueError on a bad name

        rcsetup.validate_backend(raw)
    except ValueError:
        for module in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
            del sys.modules[module]
        raise ConfigError(f"environment variable {MATPLOTLIB_BACKEND_VARIABLE}={raw!r} is not a matplotlib backend: "
                          f"use one matplotlib knows (agg, for instance), or unset it (the bench draws its plots "
                          f"with agg either way)") from None
    except ImportError:  # matplotlib is a dependency; without it there is nothing to check
        return


def check_environment() -> None:
    """Parse every variable of :data:`BOOLEAN_VARIABLES` and :data:`CHOICE_VARIABLES` once, and check matplotlib's
    ``MPLBACKEND`` (:func:`check_matplotlib_backend`), so that a bad value stops a command before it does anything
    (the CLI and ``bench`` call this first).

    Raises:
        ConfigError: the first variable whose value is refused, named with its value.
    """
    for name in BOOLEAN_VARIABLES:
        env_flag(name)
    for name, choices in CHOICE_VARIABLES.items():
        env_choice(name, choices)
    check_matplotlib_backend()
