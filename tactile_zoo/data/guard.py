"""Tuning mode: a guard that makes reading a test split an error, so choices made under it cannot see test data.

Hyper-parameters, epochs and window lengths are chosen on validation data. "We did not look" is a promise; this
module turns it into a check. Inside :func:`tuning` (or in a process started with ``TACTILE_ZOO_TUNING=1``), building
any split that holds test samples raises :class:`~tactile_zoo.errors.TestSplitForbidden`: ``"test"``, a dataset's
extra test splits (``"test_textures"``...) and ``split=None`` (every sample). The harness runs ``--evaluation
tuning`` cells inside it, so a tuning trial that reaches for test data fails instead of quietly using it.

    from tactile_zoo.data.guard import tuning

    with tuning():
        train = tactile_zoo.load_dataset("biotac_dos", split="train")   # fine
        test = tactile_zoo.load_dataset("biotac_dos", split="test")     # raises TestSplitForbidden
"""

from __future__ import annotations

import contextvars
from collections.abc import Iterator
from contextlib import contextmanager

from .._env import env_flag
from ..errors import TestSplitForbidden

__all__ = ["tuning", "in_tuning_mode", "check_readable", "TUNING_ENV"]

#: set to ``1`` (or ``true``, ``yes``, ``on``: :func:`tactile_zoo._env.env_flag`) in the environment to put a whole
#: process (and the workers it starts) in tuning mode; a value that is not a boolean is an error, never "off"
TUNING_ENV = "TACTILE_ZOO_TUNING"
_TUNING: contextvars.ContextVar[bool] = contextvars.ContextVar("tactile_zoo_tuning", default=False)


def in_tuning_mode() -> bool:
    """Whether test splits are forbidden here: inside :func:`tuning`, or ``TACTILE_ZOO_TUNING`` set to a true value.

    Raises:
        ConfigError: ``TACTILE_ZOO_TUNING`` holds something that is not a boolean.
    """
    return _TUNING.get() or env_flag(TUNING_ENV)


@contextmanager
def tuning() -> Iterator[None]:
    """Forbid test splits for the duration of the block (nested blocks and threads of the same context included)."""
    token = _TUNING.set(True)
    try:
        yield
    finally:
        _TUNING.reset(token)


def check_readable(dataset: str, split: str | None, train_splits: tuple[str, ...] = ("train", "val")) -> None:
    """Raise :class:`TestSplitForbidden` if ``split`` of ``dataset`` holds test samples and test splits are
    forbidden here; anything but ``train_splits`` counts as test (``None`` is every sample, test included)."""
    if split in train_splits or not in_tuning_mode():
        return
    what = "every sample (split=None), test included" if split is None else f"the {split!r} split"
    raise TestSplitForbidden(f"{dataset}: {what} cannot be read in tuning mode; tuning reads train and val only "
                             f"(choices made here must not see test data)")
