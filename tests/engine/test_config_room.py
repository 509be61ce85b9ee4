"""The configuration room (``tactile_zoo/engine/config.py``): recipe resolution has one entry point, a cell's
configuration is one frozen, picklable object, and ``fit`` is the one public training signature."""

from __future__ import annotations

import ast
import inspect
import pickle
from pathlib import Path

import pytest

from tactile_zoo.engine import api, train
from tactile_zoo.engine.config import CellConfig, config_hash, resolve_cell, resolve_model_recipe
from tactile_zoo.recipe import Recipe

PACKAGE = Path(__file__).resolve().parents[2] / "tactile_zoo"
#: the one module that resolves recipes, and the schema module that defines the pieces it uses
ROOM = {"tactile_zoo/engine/config.py", "tactile_zoo/recipe.py"}
#: the layers' pieces: only the room combines them (the schema module calls its own for its checks)
INTERNALS = {"recipe_values", "resolve_recipe", "named_recipe_for", "cap_epochs", "declared_evaluation"}


def resolution_calls(root: Path, allowed: set[str] = ROOM) -> list[str]:
    """``file:line name`` of every call of a resolution internal in a module outside ``allowed`` (paths relative to
    ``root``'s parent), found in the syntax tree: a call through an attribute (``recipe.cap_epochs(...)``) counts."""
    hits = []
    for path in sorted(root.rglob("*.py")):
        where = path.relative_to(root.parent).as_posix()
        if where in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Call):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", None)
                if name in INTERNALS:
                    hits.append(f"{where}:{node.lineno} {name}")
    return hits


def test_recipes_are_resolved_in_one_place_only() -> None:
    assert resolution_calls(PACKAGE) == []


def test_a_second_resolution_is_found(tmp_path: Path) -> None:
    pkg = tmp_path / "tactile_zoo"
    (pkg / "engine").mkdir(parents=True)
    (pkg / "engine" / "config.py").write_text("from ..recipe import cap_epochs\nx = cap_epochs({}, 3)\n")
    (pkg / "engine" / "train.py").write_text("from .. import recipe\n\n\ndef f(r):\n"
                                             "    return recipe.resolve_recipe(r, None, 5)\n")
    (pkg / "bench.py").write_text("from .recipe import named_recipe_for as n\nn({}, None)\ncap_epochs = 1\n")
    assert resolution_calls(pkg) == ["tactile_zoo/engine/train.py:5 resolve_recipe"]
    # the real tree with a planted second caller fails the guard too
    planted = tmp_path / "real"
    (planted / "tactile_zoo" / "engine").mkdir(parents=True)
    source = (PACKAGE / "engine" / "train.py").read_text()
    (planted / "tactile_zoo" / "engine" / "train.py").write_text(
        source + "\n\ndef _again(recipe):\n    return named_recipe_for(recipe, None)\n")
    assert [h.split(":")[0] for h in resolution_calls(planted / "tactile_zoo")] == ["tactile_zoo/engine/train.py"]


def test_every_layer_applies_in_order() -> None:
    meta = {"default_recipe": "a", "recipes": {
        "a": {"lr": 0.01, "max_epochs": 40, "schedule": {"type": "multistep", "milestones": [20, 30]},
              "datasets": {"d": {"lr": 0.02, "batch_size": 8}}},
        "b": {"lr": 0.5}}}
    plain = resolve_model_recipe(meta)
    assert (plain.name, plain.recipe.lr, plain.recipe.max_epochs, plain.recipe.batch_size) == ("a", 0.01, 40, 32)
    on_d = resolve_model_recipe(meta, dataset="d", budget=10)  # the section, then the dataset's budget
    assert (on_d.recipe.lr, on_d.recipe.batch_size, on_d.recipe.max_epochs) == (0.02, 8, 10)
    assert on_d.recipe.schedule["milestones"] == [5, 8]
    over = resolve_model_recipe(meta, dataset="d", overrides={"lr": 1e-3}, budget=10)  # overrides beat the section
    assert (over.recipe.lr, over.recipe.max_epochs) == (0.001, 10)
    assert resolve_model_recipe(meta, dataset="d", epochs=60, budget=10).recipe.max_epochs == 60  # --epochs last
    assert resolve_model_recipe(meta, dataset="d", quick=True, budget=10).recipe.max_epochs == 2  # --quick
    assert resolve_model_recipe(meta, dataset="d", epochs=7, quick=True).recipe.max_epochs == 7
    assert resolve_model_recipe(meta, "b").recipe.max_epochs == Recipe().max_epochs  # the schema's default
    custom = resolve_model_recipe(meta, overrides=Recipe(lr=0.3), epochs=4, budget=2)
    assert (custom.name, custom.recipe.lr, custom.recipe.max_epochs) == ("custom", 0.3, 4)


def test_a_cell_configuration_is_frozen_picklable_and_hashes_as_its_record() -> None:
    config = resolve_cell("sgnet", "sim_evtouch", quick=True, hparams={"hidden": 16})
    with pytest.raises(AttributeError):
        config.refit = True  # type: ignore[misc]
    again = pickle.loads(pickle.dumps(config))
    assert again == config and isinstance(again.recipe, Recipe)
    assert config_hash(again) == config_hash(config) == config_hash(config.to_dict())
    assert CellConfig.from_dict(config.to_dict()) == config
    assert config.subset == {"train": 64, "val": 32, "test": 64} and config.recipe.max_epochs == 2


def test_fit_holds_the_one_public_signature_and_the_loop_takes_a_resolved_recipe() -> None:
    public = inspect.signature(api.fit).parameters
    loop = inspect.signature(train.train_model).parameters
    assert {"epochs", "hparams", "root", "fold", "dataset_kwargs"} <= set(public)
    assert not {"epochs", "hparams", "root", "fold", "dataset_kwargs"} & set(loop)  # nothing left to resolve there
    with pytest.raises(Exception, match="resolved Recipe"):
        train.train_model(None, _split(), {"lr": 0.1})  # type: ignore[arg-type]


def _split() -> object:
    import tactile_zoo as tz
    from tactile_zoo.engine import as_split

    return as_split(tz.load_dataset("sim_evtouch", split="train"))
