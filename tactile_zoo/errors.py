"""The one exception hierarchy of tactile-zoo.

Callers catch :class:`TactileZooError` to handle anything the library raises on purpose; the CLI prints such errors
as one line (exit code 2) and shows a traceback only with ``--debug``.
"""

from __future__ import annotations

__all__ = ["TactileZooError", "UnknownNameError", "DatasetError", "PluginError", "ConfigError", "TestSplitForbidden",
           "ModelCannotConsume", "ExportError", "ResultsError"]


class TactileZooError(Exception):
    """Base class of every error tactile-zoo raises deliberately."""


class UnknownNameError(TactileZooError, KeyError):
    """A model, dataset or sensor name that is not registered. The message lists close matches and all names."""

    def __str__(self) -> str:  # KeyError would repr() the message and add quotes
        return str(self.args[0]) if self.args else ""


class DatasetError(TactileZooError):
    """Data that is missing, malformed or fails its checksum. The message names the file and what is wrong."""


class PluginError(TactileZooError):
    """A third-party plugin that fails to load, has the wrong type, or clashes with another plugin."""


class ConfigError(TactileZooError, ValueError):
    """A bad argument, hyper-parameter, recipe or configuration file."""


class TestSplitForbidden(ConfigError):
    """A test split was requested in tuning mode (:func:`tactile_zoo.data.guard.tuning`), where only training and
    validation data may be read."""

    __test__ = False  # not a pytest test class, despite the name


class ModelCannotConsume(ConfigError):
    """A model's constructor declares that it cannot take this dataset at all (its spec lacks what the model reads:
    global features, a sensor layout...). Raise it explicitly, naming what is missing; the harness then records the
    cell as ``skipped``, not failed. Any other error from a constructor (a bad hyper-parameter value included) is
    an error: ``tactile-zoo bench`` builds every model once on every dataset's spec before a cell runs, and stops
    there with exit 2."""


class ResultsError(TactileZooError):
    """A bench results folder that cannot be used as asked: damaged cell files, a folder that is not a bench folder,
    tables that cannot be written there. The message names the folder or the files."""


class ExportError(TactileZooError):
    """A model that cannot be exported as asked, or an export whose check against eager PyTorch failed."""
