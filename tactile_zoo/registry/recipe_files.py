"""Recipe files: a model's named training recipes as data, one YAML file per model.

A model's recipes live in ``<package>/recipes/<model>.yaml``: the built-ins' in ``tactile_zoo/recipes/``, a plugin's
in its own package's ``recipes/`` folder, shipped as package data. The model's module reads its file at import and
hands it to the registry unchanged in shape: ``register_model(..., **recipe_file("tactile_zoo", "tacformer"))`` (or
``zoo_meta = {..., **recipe_file("my_plugin", "my_model")}``) gives the metadata ``recipes={name: recipe}`` and
``default_recipe``, exactly what a dict written in the module gave. A file reads::

    default: full                 # the recipe a run uses when it names none (else "source", else the first)
    recipes:
      source: {loss: ce, optimizer: adamw, lr: 2e-3, max_epochs: 30, patience: 10}
      zoo:
        from: source              # recipe "source" (defined above), with the keys given here replacing its keys whole
        datasets: {biotac_dos: {dataset_kwargs: {window: 10}}}
      full:
        from: zoo
        epochs: {ev_objects: 15}  # the full variant: tactile_zoo.recipe.full_recipe(zoo, epochs)

Each recipe holds the keys of :mod:`tactile_zoo.recipe` (training keys, ``hparams``, ``dataset_kwargs``,
``evaluation``, ``datasets``) and is validated by its one schema (:func:`~tactile_zoo.recipe.check_named_recipe`)
when the file is read, so a typo fails at import with a :class:`ConfigError` naming the file, the recipe and the key.
``epochs`` keeps the ``full`` derivation a rule applied to declared counts (the counts are the evidence a plan
declares; the rule turns early stopping off, declares ``evaluation: final`` and pins a cosine period), not six
hand-written copies of its result. Numbers in exponent form (``1e-3``) are numbers, as in YAML 1.2. A file is read
with a size cap and an alias limit (:mod:`tactile_zoo._yaml`).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from importlib import resources
from importlib.resources.abc import Traversable
from os import PathLike
from pathlib import Path
from typing import Any

from .._yaml import read_yaml_file
from ..errors import ConfigError
from ..recipe import check_named_recipe, full_recipe

__all__ = ["recipe_file", "read_recipe_file", "recipe_file_path", "FILE_KEYS", "DERIVATION_KEYS"]

#: the keys a recipe file's top level may hold
FILE_KEYS = ("default", "recipes")
#: the keys a recipe in a file may hold besides the recipe schema's: how it derives from one defined above it
DERIVATION_KEYS = ("from", "epochs")


def recipe_file_path(package: str, model: str) -> Traversable:
    """Where package ``package`` keeps model ``model``'s recipe file: ``<package>/recipes/<model>.yaml``."""
    return resources.files(package).joinpath("recipes", f"{model}.yaml")


def recipe_file(package: str, model: str) -> dict[str, Any]:
    """The ``recipes`` and ``default_recipe`` metadata that ``<package>/recipes/<model>.yaml`` declares, validated
    (see the module docstring); pass it on as ``register_model(**recipe_file(...))`` or into a plugin's ``zoo_meta``.
    """
    return read_recipe_file(recipe_file_path(package, model))


def read_recipe_file(path: str | PathLike[str] | Traversable) -> dict[str, Any]:
    """The ``recipes`` and ``default_recipe`` metadata of the recipe file at ``path`` (any file, not only a package's).

    Raises:
        ConfigError: the file is missing or not YAML, or a key is unknown or has a bad value; the message names the
            file and the key.
    """
    source = path if isinstance(path, Traversable) else Path(path)
    where = str(source)
    data = read_yaml_file(source, where, "not a valid YAML recipe file")  # a size cap, no anchor bomb
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: a recipe file is a mapping with the keys {', '.join(FILE_KEYS)}; got "
                          f"{type(data).__name__}")
    unknown = sorted(set(data) - set(FILE_KEYS), key=str)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; a recipe file holds {', '.join(FILE_KEYS)}")
    raw = data.get("recipes")
    if not isinstance(raw, Mapping) or not raw or not all(isinstance(k, str) and k for k in raw):
        raise ConfigError(f"{where}: 'recipes' must map recipe names to recipes, got {raw!r}")
    recipes: dict[str, dict[str, Any]] = {}
    for name, recipe in raw.items():
        recipes[name] = _derive(where, name, recipe, recipes)
        check_named_recipe(recipes[name], where=f"{where}: recipe {name!r}")
    meta: dict[str, Any] = {"recipes": recipes}
    if "default" in data:
        if data["default"] not in recipes:
            raise ConfigError(f"{where}: default: {data['default']!r} is not one of its recipes {list(recipes)}")
        meta["default_recipe"] = data["default"]
    return meta


def _derive(where: str, name: str, recipe: Any, above: Mapping[str, dict[str, Any]]) -> dict[str, Any]:
    """Recipe ``name`` as written, with its ``from`` (a recipe above it, its keys replaced whole by the ones given
    here) and ``epochs`` (:func:`~tactile_zoo.recipe.full_recipe`) applied."""
    where = f"{where}: recipe {name!r}"
    if not isinstance(recipe, Mapping) or not all(isinstance(k, str) for k in recipe):
        raise ConfigError(f"{where} must be a mapping of recipe keys, got {recipe!r}")
    own = {k: copy.deepcopy(v) for k, v in recipe.items() if k not in DERIVATION_KEYS}
    base: dict[str, Any] = {}
    if "from" in recipe:
        parent = recipe["from"]
        if not isinstance(parent, str) or parent not in above:
            raise ConfigError(f"{where}: from: {parent!r} is not a recipe defined above it "
                              f"({', '.join(above) or 'none is'})")
        base = copy.deepcopy(above[parent])
    out = {**base, **own}
    if "epochs" in recipe:
        epochs = recipe["epochs"]
        if not isinstance(epochs, Mapping) or not epochs:
            raise ConfigError(f"{where}: epochs must map datasets to epoch counts, got {epochs!r}")
        for dataset, count in epochs.items():
            if not isinstance(count, int) or isinstance(count, bool) or count < 1:
                raise ConfigError(f"{where}: epochs.{dataset} must be a positive integer, got {count!r}")
        out = full_recipe(out, {str(d): c for d, c in epochs.items()})
    return out
