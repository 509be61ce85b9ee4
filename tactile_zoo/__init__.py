"""tactile-zoo: a model zoo and benchmark harness for tactile object recognition.

Importing the package registers the built-in sensors, datasets and models; third-party plugins (and installed
pretrained weights) are discovered lazily through entry points on the first list/create/load call.

``create_model`` is the weights layer's (:func:`tactile_zoo.weights.create_model`): the registry's
``Model(spec, **hparams)``, plus ``pretrained=`` weights and ``new_head=``.
"""

from __future__ import annotations

import os
from typing import Any

# Transparent huge pages for torch's large CPU tensors, set before torch is first imported (c10 reads the variable
# once, at its first allocation, so it does nothing when torch was imported before tactile_zoo). Without it every
# block over glibc's mmap threshold arrives as fresh 4 KiB pages that the kernel faults in and zeroes on first
# write, in every training step: D-CNN's Ev-Objects step (activations of (128, 128, 125, 39), 312 MiB each) took
# 2.1 million page faults per two batches, 1.9 s of system time; with 2 MiB pages 35 thousand (profiled,
# docs/pending/recurrences.md). Only where memory comes from changes, never a value. THP_MEM_ALLOC_ENABLE=0 in the
# environment keeps torch's default. Processes started from this one inherit the variable; _THP_DEFAULTED says it
# was set here (benchmarks.vs_pinned removes it again for the pinned version's processes).
_THP_DEFAULTED = "THP_MEM_ALLOC_ENABLE" not in os.environ
os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")

from . import data, models  # noqa: E402,F401  (import registers the built-ins)
from ._version import __version__  # noqa: E402
from .data import DatasetSpec, Sensor, TactileSample, collate  # noqa: E402
from .errors import ConfigError, DatasetError, PluginError, TactileZooError, UnknownNameError  # noqa: E402
from .registry import (  # noqa: E402
    get_sensor,
    list_datasets,
    list_models,
    list_sensors,
    load_dataset,
    plugins,
    register_dataset,
    register_model,
    register_sensor,
)
from .weights import create_model, list_weights, predict  # noqa: E402

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
