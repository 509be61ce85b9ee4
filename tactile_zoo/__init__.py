"""tactile-zoo: a model zoo and benchmark harness for tactile object recognition.

Importing the package registers the built-in sensors, datasets and models; third-party plugins (and installed
pretrained weights) are discovered lazily through entry points on the first list/create/load call.

This is the one public home of :func:`create_model` (the registry's ``Model(spec, **hparams)``, plus
``pretrained=`` weights (``True`` picks them), a weights tag in the name (``x_tacformer.full_ev_objects``),
``new_head=`` and ``num_classes=``) and of :func:`list_models` (``pretrained=True`` lists weight tags). Both are
defined in :mod:`tactile_zoo.weights.load`; the registry's lower-level calls are
:func:`~tactile_zoo.registry.instantiate_model` and :func:`~tactile_zoo.registry.model_names`.
"""

from __future__ import annotations

from typing import Any

from . import data, models  # noqa: E402,F401  (import registers the built-ins)
from ._version import __version__  # noqa: E402
from .data import DatasetSpec, Sensor, TactileSample, collate  # noqa: E402
from .errors import ConfigError, DatasetError, PluginError, TactileZooError, UnknownNameError  # noqa: E402
from .registry import (  # noqa: E402
    get_sensor,
    list_datasets,
    list_sensors,
    load_dataset,
    plugins,
    register_dataset,
    register_model,
    register_sensor,
)
from .weights import list_weights, predict  # noqa: E402
from .weights.load import create_model, list_models  # noqa: E402

__all__ = [
    "__version__", "DatasetSpec", "Sensor", "TactileSample", "collate", "TactileZooError", "UnknownNameError",
    "DatasetError", "PluginError", "ConfigError", "create_model", "get_sensor", "list_datasets", "list_models",
    "list_sensors", "load_dataset", "plugins", "register_dataset", "register_model", "register_sensor", "fit",
    "evaluate", "predict", "list_weights",
]


def __getattr__(name: str) -> Any:
    # the training engine is imported on first use, so `import tactile_zoo` stays light for listing and plugins
    if name in {"fit", "evaluate"}:
        from . import engine

        return getattr(engine, name)
    raise AttributeError(f"module 'tactile_zoo' has no attribute {name!r}")
