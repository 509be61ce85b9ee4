"""Named recipes: a model registers ``recipes={"source": ..., ...}``; ``--recipe NAME`` / ``recipe="NAME"`` starts from
one of them, the cell records the name, and the leaderboard and report show it."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import tiny_zoo

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.engine.config import CellConfig, resolve_cell
from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import declared_evaluation

FREEZE = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "tuning" / "freeze.json"
TWO = {"source": {**tiny_zoo.TINY_RECIPE, "lr": 0.03}, "fast": {**tiny_zoo.TINY_RECIPE, "lr": 0.1, "max_epochs": 2}}


@pytest.fixture()
def two_recipes():
    """tiny_mlp registered again with two named recipes (the tiny zoo's fixture restores it afterwards)."""
    registry.register_model("tiny_two", recipes=TWO, tags=["test"])(tiny_zoo.TinyMLP)
    yield "tiny_two"
    registry._unregister("model", "tiny_two")


def test_every_frozen_builtin_defaults_to_full_and_a_later_one_to_zoo() -> None:
    simulated = {d for d in tz.list_datasets() if registry.get_dataset_entry(d).meta.get("simulated")}
    builtins = [name for name in tz.list_models()
                if str(getattr(registry.get_model_entry(name).obj, "__module__", "")).startswith("tactile_zoo.")]
    assert len(builtins) >= 7  # test zoos registered by other tests in this worker are not built-ins
    frozen = json.loads(FREEZE.read_text())["models"]
    assert set(frozen) < set(builtins)  # a frozen model is never dropped; models added since are not frozen
    for name in builtins:
        meta = registry.get_model_entry(name).meta
        assert meta["recipe"] == meta["recipes"][meta["default_recipe"]], name  # the derived default, for older readers
        if name in frozen:
            # the round-3 plan's rule made `full` the frozen models' default (tools.published_tables --check agrees)
            assert meta["default_recipe"] == "full" and {"source", "zoo", "full"} <= set(meta["recipes"]), name
            # what full builds on; the simulators' sections came later (sized for a first run) and real data never
            # reads them (tests/models/test_simulator_sizing.py), so the freeze is of the rest
            zoo = json.loads(json.dumps(meta["recipes"]["zoo"]))
            zoo["datasets"] = {d: s for d, s in zoo.get("datasets", {}).items() if d not in simulated}
            assert zoo == frozen[name], name
        else:
            # a model added after the freeze (DeepTactile) keeps `zoo`, whose epoch is selected on validation, as
            # its default: its `full` (declared later from its own `zoo` cells) became the default by no rule
            assert meta["default_recipe"] == "zoo", name
            assert {"source", "zoo"} <= set(meta["recipes"]), name
            assert all(declared_evaluation(meta["recipe"], d) in (None, "validation")
                       for d in (None, *tz.list_datasets())), name


def test_the_registry_derives_the_default_and_names_a_lone_recipe_default(two_recipes: str) -> None:
    meta = registry.get_model_entry(two_recipes).meta
    assert meta["default_recipe"] == "source" and meta["recipe"]["lr"] == 0.03 and set(meta["recipes"]) == {
        "source", "fast"}
    lone = registry.get_model_entry("tiny_mlp").meta
    assert lone["default_recipe"] == "default" and lone["recipes"] == {"default": lone["recipe"]}


@pytest.mark.parametrize(("meta", "culprit"), [
    ({"recipes": {"source": {"lr": -1}}}, "recipe 'source': lr"),
    ({"recipes": {}}, "must map recipe names"),
    ({"recipes": TWO, "default_recipe": "slow"}, "default_recipe 'slow'"),
    ({"recipes": TWO, "recipe": {"lr": 0.5}}, "differs from its default recipe"),
])
def test_bad_named_recipes_fail_at_registration(meta: dict, culprit: str) -> None:
    with pytest.raises(ConfigError, match=culprit):
        registry.register_model("tiny_bad_recipes", **meta)(tiny_zoo.TinyMLP)
    assert "tiny_bad_recipes" not in tz.list_models()


def test_resolve_cell_starts_from_the_named_recipe(two_recipes: str) -> None:
    default = resolve_cell(two_recipes, "tiny_blobs")
    fast = resolve_cell(two_recipes, "tiny_blobs", recipe_name="fast", recipe={"batch_size": 4})
    assert (default.recipe_name, default.recipe.lr) == ("source", 0.03)
    assert (fast.recipe_name, fast.recipe.lr, fast.recipe.max_epochs, fast.recipe.batch_size) == ("fast", 0.1, 2, 4)
    assert resolve_cell(two_recipes, "tiny_blobs", recipe="fast").recipe == fast.recipe.replace(batch_size=16)
    # the name is a label: the hash covers the resolved recipe, so the same recipe under another name is one cell
    assert "recipe_name" not in fast.hashed() and fast.to_dict()["recipe_name"] == "fast"
    assert CellConfig.from_dict(fast.to_dict()) == fast
    with pytest.raises(ConfigError, match="no recipe named 'slow'; its recipes: fast, source"):
        resolve_cell(two_recipes, "tiny_blobs", recipe_name="slow")


TUNED = {**tiny_zoo.TINY_RECIPE, "hparams": {"hidden": 8, "dropout": 0.0},
         "dataset_kwargs": {"augment": ["jitter"], "augment_factor": 2},
         "datasets": {"tiny_kfold": {"lr": 0.01, "hparams": {"hidden": 4}, "dataset_kwargs": {"augment_factor": 3}}}}


@pytest.fixture()
def tuned():
    registry.register_model("tiny_tuned", recipes={"source": tiny_zoo.TINY_RECIPE, "zoo": TUNED})(tiny_zoo.TinyMLP)
    yield "tiny_tuned"
    registry._unregister("model", "tiny_tuned")


def test_a_named_recipe_carries_model_and_dataset_settings_per_dataset(tuned: str) -> None:
    blobs = resolve_cell(tuned, "tiny_blobs", recipe_name="zoo")
    assert blobs.hparams == {"hidden": 8, "dropout": 0.0} and blobs.recipe.lr == tiny_zoo.TINY_RECIPE["lr"]
    assert blobs.dataset_kwargs == {"augment": ["jitter"], "augment_factor": 2}
    kfold = resolve_cell(tuned, "tiny_kfold", recipe_name="zoo")  # its own section on top
    assert kfold.hparams == {"hidden": 4, "dropout": 0.0} and kfold.recipe.lr == 0.01
    assert kfold.dataset_kwargs == {"augment": ["jitter"], "augment_factor": 3}
    # the user's settings win over the recipe's, and the source recipe carries none
    mine = resolve_cell(tuned, "tiny_blobs", recipe_name="zoo", hparams={"hidden": 32},
                        dataset_kwargs={"augment_factor": 1})
    assert mine.hparams["hidden"] == 32 and mine.dataset_kwargs["augment_factor"] == 1
    assert resolve_cell(tuned, "tiny_blobs").hparams == {}
    # the settings reach the model: a cell trained with the recipe has the recipe's width
    from tactile_zoo.engine.cell import train_cell

    result = train_cell(resolve_cell(tuned, "tiny_kfold", recipe_name="zoo", epochs=1), measure=False)
    assert result.fit.model.net[0].out_features == 4


@pytest.mark.parametrize(("recipe", "culprit"), [
    ({"hparams": [1]}, "hparams must be a dict"),
    ({"datasets": {"tiny_blobs": {"lr": "fast"}}}, "recipe 'zoo' on tiny_blobs: lr"),
    ({"datasets": {"tiny_blobs": {"speed": 2}}}, "unknown recipe key"),
    ({"datasets": {"tiny_blobs": {"datasets": {}}}}, "cannot nest"),
    ({"datasets": {"tiny_blobs": 3}}, "datasets.tiny_blobs must be a dict"),
])
def test_bad_recipe_sections_fail_at_registration(recipe: dict, culprit: str) -> None:
    with pytest.raises(ConfigError, match=culprit):
        registry.register_model("tiny_bad_sections", recipes={"zoo": {**tiny_zoo.TINY_RECIPE, **recipe}}
                                )(tiny_zoo.TinyMLP)


def test_fit_takes_a_recipe_name(two_recipes: str) -> None:
    result = tz.fit(two_recipes, "tiny_blobs", recipe="fast", seed=0)
    assert result.recipe.lr == 0.1 and result.epochs_run == 2
    with pytest.raises(ConfigError, match="no recipe named"):
        tz.fit(two_recipes, "tiny_blobs", recipe="slow")


def test_bench_records_the_recipe_name_in_cell_leaderboard_and_report(two_recipes: str, tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    args = ["bench", "--models", two_recipes, "--datasets", "tiny_blobs", "--recipe", "fast", "--out", str(out),
            "--no-plots", "-q"]
    assert main(args) == 0
    cell = json.loads(next((out / "cells").glob("*.json")).read_text())
    assert cell["config"]["recipe_name"] == "fast" and cell["config"]["recipe"]["lr"] == 0.1
    board = list(csv.DictReader((out / "leaderboard.csv").open()))
    assert [row["recipe"] for row in board] == ["fast"]
    assert list(csv.DictReader((out / "summary.csv").open()))[0]["recipe"] == "fast"
    assert f"| {two_recipes} | fast | tiny_blobs |" in (out / "report.md").read_text()
    capsys.readouterr()
    assert main([*args[:-4], "--recipe", "slow", "--out", str(tmp_path / "x"), "--no-plots"]) == 2
    assert "no recipe named 'slow'" in capsys.readouterr().err


def test_full_recipe_fixes_the_epochs_and_keeps_the_learning_rates() -> None:
    from tactile_zoo.recipe import full_recipe, resolve_recipe

    zoo = {"loss": "ce", "lr": 0.002, "schedule": {"type": "cosine"}, "max_epochs": 30, "patience": 10,
           "datasets": {"b": {"max_epochs": 20, "dataset_kwargs": {"window": 5}}}}
    full = full_recipe(zoo, {"a": 12, "b": 7})
    # the period of the budget the count came from; a fixed count, final evaluation, on the declared datasets only
    assert full["datasets"]["a"] == {"max_epochs": 12, "patience": None, "evaluation": "final",
                                     "schedule": {"type": "cosine", "t_max": 30}}
    # a section with its own budget had its own period, and keeps its other settings
    assert full["datasets"]["b"] == {"max_epochs": 7, "patience": None, "dataset_kwargs": {"window": 5},
                                     "evaluation": "final", "schedule": {"type": "cosine", "t_max": 20}}
    # elsewhere (no declared count) the recipe is the zoo recipe itself: selected on validation
    assert {k: v for k, v in full.items() if k != "datasets"} == {k: v for k, v in zoo.items() if k != "datasets"}
    multistep = {"schedule": {"type": "multistep", "milestones": [5]}, "max_epochs": 10}
    assert full_recipe(multistep, {"a": 4})["datasets"]["a"]["schedule"] == multistep["schedule"]  # absolute epochs
    resolve_recipe({k: v for k, v in full.items() if k not in ("datasets", "evaluation")})  # valid keys
    assert zoo["patience"] == 10 and "evaluation" not in zoo  # the zoo recipe itself is untouched
