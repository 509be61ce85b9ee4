"""The settings schema's wording of the errors the other tests do not meet, the keyword walk's cap, the prefix
parser's refusals, and the recipe rules and schedule arithmetic the training tests leave out. Pure functions, no
model."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from tactile_zoo import settings
from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import (
    Recipe,
    cap_epochs,
    check_named_recipe,
    check_recipe_keys,
    lr_factor,
    recipe_values,
    resolve_recipe,
)


# ------------------------------------------------------------------------------------------------ settings
def test_a_list_longer_than_its_type_says_how_long_it_must_be() -> None:
    with pytest.raises(ConfigError, match=r"^recipe: rate_targets must hold 2 item\(s\), got \[1.0, 0.0, 0.5\]$"):
        settings.check_field(settings.RecipeSchema, "rate_targets", [1.0, 0.0, 0.5], "recipe")


def _error(kind: str, ctx: dict) -> ValidationError:
    return ValidationError.from_exception_data("x", [{"type": kind, "loc": ("lr",), "input": 3, "ctx": ctx}])


def test_a_validator_error_and_an_unlisted_error_keep_their_own_words() -> None:
    assert settings.describe_error(_error("value_error", {"error": ValueError("must not be 3")}), "recipe") == \
        "recipe: lr must not be 3, got 3"
    assert settings.describe_error(_error("multiple_of", {"multiple_of": 2}), "--set lr=3") == \
        "--set lr=3: lr input should be a multiple of 2, got 3"


def test_keywords_built_from_shared_references_are_refused_not_walked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(settings, "MAX_VALUES", 1000)  # the cap, lowered to keep the walk short
    bomb: list = [0.0] * 10
    for _ in range(6):  # 10**7 values seen through 70 lists: what an anchor bomb read by another loader gives
        bomb = [bomb] * 10
    with pytest.raises(ConfigError, match=r"^--hparam depth=1: depth(\[\d\])+: more than 1,000 values$"):
        settings.check_keywords({"depth": bomb}, "--hparam depth=1", "")
    assert len(settings.check_keywords({"depth": [[0.0] * 98] * 10}, "", "")["depth"]) == 10  # 992 values: taken


def test_a_non_finite_value_nested_in_a_dict_is_named_by_its_path() -> None:
    with pytest.raises(ConfigError, match=r"^c.yaml: hparams.block.rates\[1\] is inf, expected a finite number$"):
        settings.check_keywords({"block": {"rates": [0.5, math.inf]}}, "c.yaml", "hparams")
    assert settings.check_keywords({"block": {"rates": [0.5]}}, "c.yaml", "hparams") == {"block": {"rates": [0.5]}}


@pytest.mark.parametrize(("value", "message"), [
    ("0.5,x", r"^--prefixes: 'x' is not a number$"),
    ([0.5, "a"], r"^--prefixes: 'a' is not a number$"),
    ([True], r"^--prefixes: True is not a number$"),
    ([], r"^--prefixes must be a comma-separated list of fractions in \(0, 1\], got \[\]$"),
    (" , ", r"^--prefixes must be a comma-separated list of fractions in \(0, 1\], got \[\]$"),
    (0.5, r"^--prefixes must be a comma-separated list of fractions in \(0, 1\], got 0.5$"),
])
def test_prefixes_that_are_not_fractions_are_refused(value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        settings.check_prefixes(value)


def test_empty_items_of_a_prefix_list_are_skipped() -> None:
    assert settings.check_prefixes("0.5,,25, ") == [0.25, 0.5, 1.0]


# ------------------------------------------------------------------------------------------------ recipes
def test_nesterov_needs_momentum_and_the_error_names_where_it_came_from() -> None:
    with pytest.raises(ConfigError, match="^recipe: nesterov needs a momentum > 0, got momentum=0.0$"):
        Recipe(optimizer="sgd", nesterov=True, momentum=0.0)
    with pytest.raises(ConfigError, match="^--set: nesterov needs a momentum > 0, got momentum=0.0$"):
        resolve_recipe(None, {"optimizer": "sgd", "nesterov": True, "momentum": 0}, where="--set")
    assert Recipe(optimizer="adam", nesterov=True, momentum=0.0).nesterov  # only SGD uses it


def test_false_turns_off_a_key_that_can_be_off() -> None:
    recipe = resolve_recipe(None, {"patience": False, "grad_clip": False, "ema_decay": False})
    assert (recipe.patience, recipe.grad_clip, recipe.ema_decay) == (None, None, None)
    with pytest.raises(ConfigError, match="max_epochs must be an integer"):
        resolve_recipe(None, {"max_epochs": False})  # a key that cannot be off


def test_recipe_keys_must_come_as_a_dict() -> None:
    with pytest.raises(ConfigError, match="^--set must be a dict of recipe keys, got list$"):
        check_recipe_keys([("lr", 0.1)], "--set")


def test_a_named_recipes_sections_must_be_dicts_of_keywords() -> None:
    with pytest.raises(ConfigError, match=r"^recipe x: datasets must be a dict of keyword arguments, got \['a'\]$"):
        check_named_recipe({"lr": 0.01, "datasets": ["a"]}, "recipe x")


@pytest.mark.parametrize(("schedule", "capped"), [
    ({"type": "step", "step_size": 30, "gamma": 0.5}, {"type": "step", "step_size": 6, "gamma": 0.5}),
    ({"type": "step", "step_size": 2, "gamma": 0.5}, {"type": "step", "step_size": 1, "gamma": 0.5}),
    ({"type": "cosine", "t_max": 100, "eta_min": 0.0}, {"type": "cosine", "t_max": 20, "eta_min": 0.0}),
    ({"type": "cosine", "eta_min": 0.1}, {"type": "cosine", "eta_min": 0.1}),  # follows max_epochs by itself
    ({"type": "exponential", "gamma": 0.9}, {"type": "exponential", "gamma": 0.9}),
])
def test_a_capped_schedule_keeps_its_shape(schedule: dict, capped: dict) -> None:
    values = recipe_values(None, {"max_epochs": 100, "schedule": schedule})
    out = cap_epochs(values, 20)
    assert out["max_epochs"] == 20
    assert {k: v for k, v in out["schedule"].items() if k in capped} == capped
    assert cap_epochs(values, 200) == values  # within the budget: unchanged


def test_the_exponential_schedule_multiplies_the_rate_each_epoch() -> None:
    recipe = resolve_recipe(None, {"schedule": {"type": "exponential", "gamma": 0.5}})
    assert [lr_factor(recipe, e) for e in range(4)] == [1.0, 0.5, 0.25, 0.125]
    warm = resolve_recipe(None, {"schedule": {"type": "exponential", "gamma": 0.5, "warmup_epochs": 2}})
    assert lr_factor(warm, 3) == 0.125 and lr_factor(warm, 0) < 1.0
