"""The training recipe, as the engine sees it: the schema itself lives in :mod:`tactile_zoo.recipe` (no torch), so
that the registry can validate a model's recipe metadata without importing the engine. Kept as an import path."""

from ..recipe import DEFAULT_RECIPE, RECIPE_KEYS, Recipe, cap_epochs, lr_factor, named_recipe_for, resolve_recipe

__all__ = ["Recipe", "DEFAULT_RECIPE", "RECIPE_KEYS", "resolve_recipe", "named_recipe_for", "lr_factor", "cap_epochs"]
