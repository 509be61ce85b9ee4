from __future__ import annotations

import math

import pytest

from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import (
    DEFAULT_RECIPE,
    HASH_NEUTRAL_KEYS,
    RECIPE_KEYS,
    Recipe,
    cap_epochs,
    lr_factor,
    recipe_values,
    resolve_recipe,
)


def test_default_recipe_is_cross_entropy_adam() -> None:
    assert DEFAULT_RECIPE.loss == "ce" and DEFAULT_RECIPE.optimizer == "adam"
    # every key, but those added later and left out of the hash while off
    assert set(DEFAULT_RECIPE.to_dict()) == set(RECIPE_KEYS) - set(HASH_NEUTRAL_KEYS)
    assert DEFAULT_RECIPE.replace(ema_decay=0.99).to_dict()["ema_decay"] == 0.99
    assert "micro_batch_size" not in DEFAULT_RECIPE.replace(micro_batch_size=False).to_dict()
    assert DEFAULT_RECIPE.replace(micro_batch_size=50).to_dict()["micro_batch_size"] == 50


def test_overrides_apply_in_order_and_epochs_last() -> None:
    rec = resolve_recipe({"lr": 0.01, "batch_size": 8, "max_epochs": 50}, {"lr": 1e-4}, epochs=3)
    assert rec.lr == 1e-4 and rec.batch_size == 8 and rec.max_epochs == 3
    with pytest.raises(ConfigError, match=r"recipe override: lr must be a number, got '1e-4'"):
        resolve_recipe({"lr": 0.01}, {"lr": "1e-4"})  # strict: text is never a number (YAML reads 1e-3 as one)
    assert rec.replace(patience=None).patience is None


def test_unknown_key_names_the_key_and_the_source() -> None:
    with pytest.raises(ConfigError, match=r"recipe of sgnet.*\['lrr'\]"):
        resolve_recipe({"lrr": 0.1}, where="recipe of sgnet")
    with pytest.raises(ConfigError, match="bogus"):
        resolve_recipe(None, {"bogus": 1})


@pytest.mark.parametrize("bad", [{"lr": -1}, {"lr": "fast"}, {"loss": "hinge"}, {"optimizer": "lbfgs"},
                                 {"batch_size": 0}, {"max_epochs": 2.5}, {"patience": 0}, {"amsgrad": "yes"},
                                 {"schedule": {"type": "poly"}}, {"schedule": {"type": "multistep"}},
                                 {"schedule": {"type": "cosine", "gamma": 0.1}}, {"monitor": "test_accuracy"},
                                 {"rate_targets": [1.0]}, {"label_smoothing": 1.0}])
def test_bad_values_are_config_errors(bad: dict) -> None:
    with pytest.raises(ConfigError):
        resolve_recipe(None, bad)


def test_schedules_as_pure_functions_of_the_epoch() -> None:
    multi = Recipe.from_dict({"schedule": {"type": "multistep", "milestones": [2, 4], "gamma": 0.5}})
    assert [lr_factor(multi, e) for e in range(6)] == [1, 1, 0.5, 0.5, 0.25, 0.25]
    cos = Recipe.from_dict({"schedule": "cosine", "max_epochs": 4})
    assert lr_factor(cos, 0) == 1.0 and math.isclose(lr_factor(cos, 2), 0.5) and lr_factor(cos, 4) < 1e-12
    warm = Recipe.from_dict({"schedule": {"type": "step", "step_size": 10, "gamma": 0.1, "warmup_epochs": 4}})
    assert [lr_factor(warm, e) for e in range(5)] == [0.25, 0.5, 0.75, 1.0, 1.0]
    assert lr_factor(Recipe(), 100) == 1.0


def test_registry_and_engine_share_one_recipe_schema() -> None:
    from tactile_zoo import recipe, registry

    assert registry.RECIPE_KEYS is recipe.RECIPE_KEYS is RECIPE_KEYS  # written once, not kept equal by hand
    assert "torch" not in recipe.__dict__  # the schema imports no torch, so the registry can use it cheaply


def test_every_registered_model_recipe_resolves() -> None:
    from tactile_zoo import registry
    from tactile_zoo.recipe import named_recipe_for

    for name in registry.model_names():
        for recipe_name, recipe in registry.get_model_entry(name).meta.get("recipes", {}).items():
            for dataset in (None, *registry.list_datasets()):  # a dataset's own section, where the recipe has one
                training = named_recipe_for(recipe, dataset, where=f"recipe {recipe_name!r} of {name}")[0]
                resolve_recipe(training, where=f"recipe of {name}")  # raises ConfigError naming the model


def test_cap_epochs_compresses_the_schedule_and_leaves_short_recipes_alone() -> None:
    sgnet_like = Recipe.from_dict({"loss": "mse_rate", "max_epochs": 100,
                                   "schedule": {"type": "multistep", "milestones": [40, 80], "gamma": 0.1}})
    capped = Recipe(**cap_epochs(recipe_values(sgnet_like), 15))  # the keys are capped before a Recipe is built
    assert capped.max_epochs == 15
    assert capped.schedule["milestones"] == [6, 12]  # 40 and 80 of 100 epochs -> the same fractions of 15
    assert lr_factor(capped, 5) == 1.0 and abs(lr_factor(capped, 12) - 0.01) < 1e-12
    assert capped.loss == "mse_rate" and sgnet_like.max_epochs == 100  # the original is untouched
    short = recipe_values(Recipe.from_dict({"max_epochs": 10}))
    assert cap_epochs(short, 15) == short and cap_epochs(recipe_values(sgnet_like), None) == recipe_values(sgnet_like)
