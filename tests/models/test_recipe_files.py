"""Recipe files (``tactile_zoo/recipes/<model>.yaml``, :mod:`tactile_zoo.registry.recipe_files`): the built-ins
register exactly the recipes the model files declared as dicts before the move, a broken file fails naming the file
and the key, and a plugin's package finds its own file."""

from __future__ import annotations

import json
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import full_recipe
from tactile_zoo.registry import get_model_entry, model_names, read_recipe_file, recipe_file, recipe_file_path

REPO = Path(__file__).resolve().parents[2]
SNAPSHOT = json.loads((Path(__file__).parent / "fixtures" / "registered_recipes.json").read_text())
BUILT_IN = [m for m in model_names() if get_model_entry(m).obj.__module__.startswith("tactile_zoo.models.")]


def canonical(value: Any) -> str:
    """JSON text that tells 1 from 1.0 and a number from a string (``==`` on dicts does not)."""
    return json.dumps(value, sort_keys=True)


def registered(model: str) -> dict[str, Any]:
    meta = get_model_entry(model).meta
    return {"default_recipe": meta["default_recipe"], "recipes": meta["recipes"]}


def test_the_snapshot_covers_every_built_in_model() -> None:
    assert sorted(SNAPSHOT["models"]) == sorted(BUILT_IN) and len(BUILT_IN) >= 8


@pytest.mark.parametrize("model", BUILT_IN)
def test_registered_recipes_equal_the_snapshot(model: str) -> None:
    got, want = registered(model), SNAPSHOT["models"][model]
    assert got == want
    assert canonical(got) == canonical(want)  # the same types: a YAML `10.0` or `"1e-3"` would move a cell hash
    # the order the model files declared them in, which `tactile-zoo info` lists (the snapshot's keys are sorted)
    assert list(got["recipes"]) == [n for n in ("source", "zoo", "full") if n in want["recipes"]]
    assert get_model_entry(model).meta["recipe"] == want["recipes"][want["default_recipe"]]


@pytest.mark.parametrize("model", BUILT_IN)
def test_each_built_in_reads_its_own_file(model: str) -> None:
    path = Path(str(recipe_file_path("tactile_zoo", model)))
    assert path == REPO / "tactile_zoo" / "recipes" / f"{model}.yaml" and path.is_file()
    assert canonical(read_recipe_file(path)) == canonical(SNAPSHOT["models"][model])
    source = (REPO / "tactile_zoo" / "models" / f"{model}.py").read_text()
    assert "recipes=" not in source and "full_recipe" not in source  # the model file holds architecture only


def test_the_documented_recipe_file_is_x_tacformers(tmp_path: Path) -> None:
    """docs/models.md shows X-Tacformer's recipe file without its comments: it must read as the real one does."""
    [block] = re.findall(r"```yaml\n(.*?)```", (REPO / "docs" / "models.md").read_text(), flags=re.S)
    shown = read_recipe_file(write(tmp_path, block))
    assert canonical(shown) == canonical(read_recipe_file(recipe_file_path("tactile_zoo", "x_tacformer")))


def test_no_recipe_file_without_a_model() -> None:
    assert sorted(p.stem for p in (REPO / "tactile_zoo" / "recipes").glob("*")) == sorted(BUILT_IN)


@pytest.mark.parametrize(("project", "package"), [(REPO, "tactile_zoo"),
                                                   (REPO / "plugins" / "tactile-zoo-tcn", "tactile_zoo_tcn")])
def test_the_recipe_files_are_package_data(project: Path, package: str) -> None:
    """Every recipe file matches a package-data pattern, so the wheel (and the sdist) carries it."""
    patterns = tomllib.loads((project / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"][package]
    files = sorted((project / package / "recipes").glob("*.yaml"))
    assert files
    for path in files:
        assert any(path.relative_to(project / package).match(p) for p in patterns), path


def write(tmp_path: Path, text: str, name: str = "model.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


GOOD = """\
default: full
recipes:
  source: {loss: ce, lr: 1e-3, max_epochs: 30, schedule: cosine, datasets: {b: {patience: 5}}}
  zoo:
    from: source
    datasets: {a: {dataset_kwargs: {window: 10}}}
  full: {from: zoo, epochs: {a: 12}}
"""


def test_from_replaces_keys_whole_and_epochs_applies_the_full_rule(tmp_path: Path) -> None:
    meta = read_recipe_file(write(tmp_path, GOOD))
    source = {"loss": "ce", "lr": 1e-3, "max_epochs": 30, "schedule": "cosine", "datasets": {"b": {"patience": 5}}}
    zoo = {**source, "datasets": {"a": {"dataset_kwargs": {"window": 10}}}}
    assert meta == {"default_recipe": "full", "recipes": {"source": source, "zoo": zoo,
                                                           "full": full_recipe(zoo, {"a": 12})}}
    assert isinstance(meta["recipes"]["source"]["lr"], float)  # YAML 1.1 would read `1e-3` as a string
    assert meta["recipes"]["full"]["datasets"]["a"]["evaluation"] == "final"
    meta["recipes"]["zoo"]["datasets"]["a"]["dataset_kwargs"]["window"] = 99  # recipes share no nested dicts
    assert meta["recipes"]["full"]["datasets"]["a"]["dataset_kwargs"]["window"] == 10


def test_without_default_the_registry_picks_it(tmp_path: Path) -> None:
    assert read_recipe_file(write(tmp_path, "recipes: {default: {lr: 0.01}}\n")) == {"recipes": {"default":
                                                                                           {"lr": 0.01}}}


@pytest.mark.parametrize(("text", "names"), [
    # a typo in a training key, in a dataset section, a bad value, a bad section: the schema's own checks
    (GOOD.replace("lr: 1e-3", "lrr: 1e-3"), ["recipe 'source'", "lrr"]),
    (GOOD.replace("patience: 5", "patiense: 5"), ["recipe 'source'", "patiense"]),
    (GOOD.replace("lr: 1e-3", "lr: -1"), ["recipe 'source'", "lr must be a positive number"]),
    (GOOD.replace("{window: 10}", "[10]"), ["recipe 'zoo'", "dataset_kwargs"]),
    (GOOD.replace("full: {from: zoo", "full: {evaluation: best, from: zoo"), ["recipe 'full'", "evaluation"]),
    # the file's own structure
    (GOOD.replace("default: full", "defualt: full"), ["unknown key(s) ['defualt']"]),
    (GOOD.replace("default: full", "default: fast"), ["default: 'fast'"]),
    (GOOD.replace("from: zoo", "from: zo"), ["recipe 'full'", "from: 'zo'"]),
    (GOOD.replace("from: source", "from: full"), ["recipe 'zoo'", "from: 'full'"]),  # only recipes above it
    (GOOD.replace("{a: 12}", "{a: 0}"), ["recipe 'full'", "epochs.a"]),
    (GOOD.replace("{a: 12}", "12"), ["recipe 'full'", "epochs"]),
    ("recipes: []\n", ["'recipes' must map recipe names to recipes"]),
    ("- lr: 1\n", ["a recipe file is a mapping"]),
    ("recipes: {zoo: {lr: [1}\n", ["not a valid YAML recipe file"]),
])
def test_a_broken_file_names_the_file_and_the_key(tmp_path: Path, text: str, names: list[str]) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        read_recipe_file(path)
    message = str(info.value)
    assert message.startswith(f"{path}:"), message
    for name in names:
        assert name in message, message


def test_a_missing_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=re.escape(str(tmp_path / "absent.yaml"))):
        read_recipe_file(tmp_path / "absent.yaml")


def test_a_plugin_package_finds_its_own_recipe_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``recipe_file(package, model)`` reads ``<package>/recipes/<model>.yaml`` of an importable package, as a
    plugin's module does at import (tests/test_plugin_tcn.py checks the installed TCN's)."""
    package = tmp_path / "zt_recipe_plugin"
    (package / "recipes").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    write(package / "recipes", "recipes: {default: {loss: ce, lr: 2e-3, batch_size: 8}}\n", "net.yaml")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        assert recipe_file("zt_recipe_plugin", "net") == {"recipes": {"default": {"loss": "ce", "lr": 2e-3,
                                                                                  "batch_size": 8}}}
        with pytest.raises(ConfigError, match=re.escape(str(package / "recipes" / "other.yaml"))):
            recipe_file("zt_recipe_plugin", "other")
    finally:
        sys.modules.pop("zt_recipe_plugin", None)
