"""One registry for models, datasets and sensors, fed by decorators and by Python entry points.

Built-ins register with the decorators when their modules are imported (``import tactile_zoo`` imports them).
Third-party distributions register through the entry-point groups ``tactile_zoo.models`` and
``tactile_zoo.datasets``. Discovery of plugins is separate from loading them, lazy (nothing is imported until the
first list/create/load call), cached, and deterministic (sorted by distribution, then entry-point name).

Name resolution, in order:

1. ``dist:name`` selects the entry ``name`` of distribution ``dist`` (every plugin entry stays reachable so);
2. a built-in (or locally registered) name always wins a clash with a plugin;
3. a plugin name that two distributions both register is ambiguous: a :class:`PluginError` names both.

Lookups are normalised (case, ``-``, ``_`` and spaces ignored): ``X-Tacformer``, ``x_tacformer`` and
``XTacformer`` are one name. The registry imports nothing else from tactile-zoo but its errors and the recipe
schema. Its parts: :mod:`.entries` (tables, metadata, decorators), :mod:`.discovery` (entry points, plugin modules),
:mod:`.lookup` (names to objects) and :mod:`.recipe_files` (a model's recipes, read from its YAML file).
"""

from __future__ import annotations

from ..errors import UnknownNameError
from ..recipe import RECIPE_KEYS

# the private names are re-exported for the test suite and the CLI's policy line (``registry._enabled()``)
from .discovery import (  # noqa: F401
    ENTRY_POINT_GROUPS,
    FoundEntryPoint,
    PluginInfo,
    PluginWarning,
    _enabled,
    _strict,
    find_entry_points,
    import_plugin_modules,
    load_failure,
    plugins,
    reset_plugins,
    set_plugin_policy,
)
from .entries import (  # noqa: F401
    _TABLES,
    DATASET_META_KEYS,
    DEFAULT_REVISION,
    MODEL_INPUTS,
    MODEL_META_KEYS,
    Entry,
    _unregister,
    model_recipe,
    normalize_name,
    register_dataset,
    register_model,
    register_sensor,
)
from .lookup import (
    get_dataset_entry,
    get_model_entry,
    get_sensor,
    instantiate_model,
    list_datasets,
    list_sensors,
    listed_name,
    load_dataset,
    model_names,
    model_revisions,
    revision_keywords,
    revision_of,
)
from .recipe_files import read_recipe_file, recipe_file, recipe_file_path

__all__ = [
    "Entry", "PluginInfo", "PluginWarning", "register_model", "register_dataset", "register_sensor",
    "model_names", "list_datasets", "list_sensors", "instantiate_model", "load_dataset", "get_sensor",
    "get_model_entry", "get_dataset_entry", "listed_name", "plugins", "normalize_name", "reset_plugins",
    "set_plugin_policy",
    "MODEL_META_KEYS", "DATASET_META_KEYS", "DEFAULT_REVISION", "revision_of",
    "model_revisions", "revision_keywords", "ENTRY_POINT_GROUPS", "MODEL_INPUTS",
    "RECIPE_KEYS", "import_plugin_modules", "find_entry_points", "FoundEntryPoint", "load_failure",
    "UnknownNameError", "model_recipe", "recipe_file", "read_recipe_file", "recipe_file_path",
]
