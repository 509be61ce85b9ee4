"""Issue 49: one strict schema (tactile_zoo.settings) for every settings surface, and bounded settings files.

The class test generates, for every key of the recipe and of the bench settings, values of the wrong type (text where
a number or a boolean belongs, a boolean where a number does, a float where an integer does) and values out of
range, and checks that each is refused naming the key: a ConfigError from the Python API, exit 2 from the CLI.
"""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import run_cli
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_zoo import registry
from tactile_zoo._yaml import MAX_FILE_BYTES, read_yaml_file
from tactile_zoo.bench.config import BenchConfig, merge_config, plan_cells
from tactile_zoo.cli import main
from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import resolve_recipe
from tactile_zoo.registry.recipe_files import read_recipe_file
from tactile_zoo.settings import BenchSettings, RecipeSchema, ScheduleSchema, check_field

DRY = ["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--dry-run"]
texts_of_numbers = st.one_of(st.integers(-5, 500).map(str), st.sampled_from(["1e-3", "0.5", "-1", "2.0"]))
texts_of_bools = st.sampled_from(["false", "true", "no", "yes", "off", "on", "0", "1", "False"])
non_integral = st.floats(allow_nan=False, allow_infinity=False).filter(lambda x: x != int(x))


def ints(low: int) -> st.SearchStrategy[Any]:
    """Not an integer >= low: text, booleans, floats (even integral ones), integers below ``low``."""
    return st.one_of(texts_of_numbers, st.booleans(), non_integral, st.integers(low, 10).map(float),
                     st.integers(max_value=low - 1), st.lists(st.integers(low, 10), min_size=1, max_size=2))


def numbers(low: float, high: float, low_open: bool, high_open: bool) -> st.SearchStrategy[Any]:
    """Not a number in the range: text, booleans, NaN, infinities, numbers outside it. No subnormal: every command
    runs under flush-to-zero, where the text ``-2.2e-309`` parses to -0.0, a valid 0 (a subnormal given as a float
    is refused by its bits: test_a_subnormal_number_is_refused_before_any_range_check)."""
    below = st.floats(max_value=low, exclude_max=not low_open, allow_nan=False, allow_infinity=False,
                      allow_subnormal=False)
    out = [texts_of_numbers, st.booleans(), st.just(math.nan), st.just(math.inf), st.just(-math.inf), below]
    if high != math.inf:
        out.append(st.floats(min_value=high, exclude_min=not high_open, allow_nan=False, allow_infinity=False,
                             allow_subnormal=False))
    return st.one_of(*out)


bools = st.one_of(texts_of_bools, st.integers(0, 1), st.floats(0, 1), st.none())
choices = st.one_of(st.integers(), st.booleans(), st.sampled_from(["", "bogus", "sgd2", "val-loss"]))
#: not a string once written as JSON and read as YAML (JSON writes infinity as `Infinity`, which YAML reads as text)
strings = st.one_of(st.integers(), st.floats(allow_nan=False, allow_infinity=False), st.booleans(), st.just(""))

#: every key of the recipe schema and what is bad for it; the test below fails when a key is added without a row
RECIPE_BAD: dict[str, st.SearchStrategy[Any]] = {
    "loss": choices, "optimizer": choices, "monitor": choices,
    "lr": numbers(0, math.inf, True, False), "weight_decay": numbers(0, math.inf, False, False),
    "amsgrad": bools.filter(lambda v: v is not None), "nesterov": bools.filter(lambda v: v is not None),
    "momentum": numbers(0, 1, False, True), "label_smoothing": numbers(0, 1, False, True),
    "max_epochs": ints(1), "batch_size": ints(1), "eval_batch_size": ints(1),
    "patience": ints(1).filter(lambda v: v is not False), "grad_clip": numbers(0, math.inf, True, False).filter(
        lambda v: v is not False), "ema_decay": numbers(0, 1, True, True).filter(lambda v: v is not False),
    "micro_batch_size": ints(1).filter(lambda v: v is not False),
    "distill_weight": numbers(0, 1, False, False), "distill_temperature": numbers(0, math.inf, True, False),
    "rate_targets": st.one_of(st.tuples(numbers(0, 1, False, False), st.just(0.0)).map(list),
                              st.lists(st.floats(0, 1), min_size=3, max_size=3), st.floats(0, 1)),
    "schedule": st.one_of(st.integers(), st.just("poly"), st.just({"type": "multistep"})),
}
SCHEDULE_BAD: dict[str, tuple[str, st.SearchStrategy[Any]]] = {
    "type": ("exponential", choices),
    "milestones": ("multistep", st.one_of(
        st.lists(ints(0), min_size=1, max_size=3).map(lambda m: [*m, 5]),
        st.lists(st.integers(0, 50), min_size=2, max_size=4).filter(lambda m: m != sorted(set(m))), st.just([]))),
    "gamma": ("step", numbers(0, 1, True, False)), "step_size": ("step", ints(1)),
    "eta_min": ("cosine", numbers(0, 1, False, False)), "t_max": ("cosine", ints(1).filter(lambda v: v is not None)),
    "warmup_epochs": ("exponential", ints(0)),
}
#: every key of the bench settings and what is bad for it (the nested ones have tests of their own)
BENCH_BAD: dict[str, st.SearchStrategy[Any]] = {
    **{key: bools.filter(lambda v: v is not None) for key in ("download", "refit", "quick", "force", "save_weights")},
    **{key: ints(1).filter(lambda v: not (isinstance(v, str) and v.isdigit())) for key in (
        "epochs", "workers", "threads")},
    "folds": ints(1).filter(lambda v: not (isinstance(v, str) and v.isdigit())),
    "retries": ints(0).filter(lambda v: not (isinstance(v, str) and v.isdigit())),
    **{key: strings for key in ("root", "out", "device", "scheduler", "dashboard", "tracker_dir", "recipe_name")},
    "executor": choices, "tracker": choices, "evaluation": choices,
    "models": st.one_of(st.integers(), st.booleans(), st.lists(st.integers(), min_size=1, max_size=2)),
    "datasets": st.one_of(st.integers(), st.booleans(), st.lists(st.integers(), min_size=1, max_size=2)),
    "plugin_modules": st.one_of(st.integers(), st.booleans(), st.lists(st.integers(), min_size=1, max_size=2)),
    "seeds": st.one_of(st.booleans(), st.integers(max_value=-1), non_integral, st.lists(st.booleans(), min_size=1)),
    "prefixes": st.one_of(st.lists(st.one_of(texts_of_numbers, st.booleans()), min_size=1, max_size=2),
                          st.lists(st.sampled_from([0, -0.5, 101, 1e-7, 0.1234567]), min_size=1, max_size=2),
                          st.integers(), st.booleans()),
    "recipe": st.one_of(st.integers(), st.booleans(), st.just({"lr": "1e-3"}), st.just({"quick": True})),
    "hparams": st.one_of(st.integers(), st.just(["dim"]), st.just({"1x": 1}), st.just({"dim": math.nan})),
    "model_overrides": st.one_of(st.just({"tiny_mlp": {"recpie": {}}}), st.just({"tiny_mlp": {"recipe": {"lr": 0}}}),
                                 st.just({"tiny_mlp": 3}), st.just({"tiny_mlp": {"hparams": {"dim": "x", "b c": 1}}})),
    "dataset_kwargs": st.one_of(st.just({"tiny_blobs": 3}), st.just({"*": {"seed": math.inf}}),
                                st.just({"tiny_blobs": {"": 1}})),
    "model_revisions": st.one_of(st.integers(), st.just({"tiny_mlp": 0}), st.just({"tiny_mlp": "2"}),
                                 st.just({"tiny_mlp": 2.0}), st.just({"*": True}), st.just({"tiny_mlp": {"r": 1}})),
    "teachers": st.one_of(st.integers(), st.just("teachers"), st.just({"folder": "t"}), st.just({"seeds": [0]}),
                          st.just({"folder": "", "seeds": [0]}), st.just({"folder": 3, "seeds": [0]}),
                          st.just({"folder": "t", "seeds": []}), st.just({"folder": "t", "seeds": [-1]}),
                          st.just({"folder": "t", "seeds": [True]}), st.just({"folder": "t", "seeds": [0], "x": 1})),
}
SEEN = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def test_every_schema_key_has_bad_values_in_the_class_test() -> None:
    assert set(RECIPE_BAD) == set(RecipeSchema.model_fields)
    assert set(SCHEDULE_BAD) == set(ScheduleSchema.model_fields)
    assert set(BENCH_BAD) == set(BenchSettings.model_fields)


@SEEN
@given(data=st.data())
@pytest.mark.parametrize("key", sorted(RECIPE_BAD))
def test_a_bad_recipe_value_is_refused_naming_the_key(key: str, data: st.DataObject) -> None:
    value = data.draw(RECIPE_BAD[key], label=key)
    with pytest.raises(ConfigError) as caught:
        resolve_recipe(None, {key: value}, where="--set")
    assert f"--set: {key}" in str(caught.value) or "--set: schedule" in str(caught.value), str(caught.value)


@SEEN
@given(data=st.data())
@pytest.mark.parametrize("key", sorted(SCHEDULE_BAD))
def test_a_bad_schedule_value_is_refused_naming_the_key(key: str, data: st.DataObject) -> None:
    kind, bad = SCHEDULE_BAD[key]
    schedule = {"type": kind, **({"milestones": [3]} if kind == "multistep" else {}), key: data.draw(bad, label=key)}
    with pytest.raises(ConfigError) as caught:
        resolve_recipe(None, {"schedule": schedule}, where="recipe")
    message = str(caught.value)
    assert f"recipe: schedule.{key}" in message, message


@SEEN
@given(data=st.data())
@pytest.mark.parametrize("key", sorted(BENCH_BAD))
def test_a_bad_bench_setting_is_refused_naming_the_key(key: str, data: st.DataObject) -> None:
    value = data.draw(BENCH_BAD[key], label=key)
    flag = {"plugin_modules": "--plugin-module", "recipe_name": "--recipe"}.get(key, f"--{key.replace('_', '-')}")
    with pytest.raises(ConfigError) as caught:
        BenchConfig(**{key: value})
    message = str(caught.value)
    assert key in message or flag in message, message


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
@pytest.mark.parametrize("key", ["quick", "refit", "save_weights", "epochs", "out", "prefixes", "recipe", "seeds"])
def test_a_bad_config_file_value_exits_2_naming_the_file_and_the_key(key: str, data: st.DataObject,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    value = data.draw(BENCH_BAD[key], label=key)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "c.yaml"
        path.write_text(json.dumps({key: value}))  # JSON is YAML, with every string quoted
        assert run_cli([*DRY, "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"--config {path}: {key}" in err, err


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
@pytest.mark.parametrize("key", sorted(RECIPE_BAD))
def test_a_bad_set_value_exits_2_naming_the_flag_and_the_key(key: str, data: st.DataObject,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    value = json.dumps(data.draw(RECIPE_BAD[key], label=key))  # JSON is YAML: a string stays a quoted string
    assert run_cli([*DRY, "--set", f"{key}={value}"]) == 2
    err = capsys.readouterr().err
    assert f"--set {key}={value}: {key}" in err or f"--set {key}={value}: schedule" in err, err


@pytest.mark.parametrize(("text", "key"), [
    ('quick: "false"', "quick"), ('refit: "no"', "refit"), ('save_weights: "yes"', "save_weights"),
    ("out: 123", "out"), ("out: .inf", "out"), ("epochs: '5'", "epochs"), ("recipe: {lr: '1e-3'}", "recipe: lr"),
    ("prefixes: [1e-7]", "prefixes: 1e-07 has more than 6 decimals"),
])
def test_items_1_and_11_strings_are_not_booleans_or_numbers(tmp_path: Path, text: str, key: str,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "c.yaml").write_text(text + "\n")
    assert run_cli([*DRY, "--config", str(tmp_path / "c.yaml")]) == 2
    assert f"--config {tmp_path / 'c.yaml'}: {key}" in capsys.readouterr().err


@pytest.mark.parametrize("value", [-2.225073858507203e-309, 1e-310, -5e-324])
@pytest.mark.parametrize("flush", [False, True])
def test_a_subnormal_number_is_refused_before_any_range_check(value: float, flush: bool) -> None:
    """Under flush-to-zero (every command, every training step) ``-1e-310 >= 0`` holds and a learning rate of 1e-310
    trains as 0: a subnormal is refused from its bits, with or without the flush."""
    from tactile_zoo.engine.runtime import flush_denormals

    with flush_denormals() if flush else contextlib.nullcontext():
        for key in ("label_smoothing", "lr", "weight_decay"):
            with pytest.raises(ConfigError, match=f"{key} must be 0 or at least 2.2e-308 in size"):
                check_field(RecipeSchema, key, value, "x")
        assert check_field(RecipeSchema, "label_smoothing", 0.0, "x") == 0.0


def test_python_sequences_are_lists() -> None:
    config = BenchConfig(models=("tiny_mlp",), seeds=range(2), prefixes=(0.5,), plugin_modules=())
    assert config.models == ["tiny_mlp"] and config.seeds == [0, 1] and config.prefixes == [0.5, 1.0]


def test_yaml_numbers_and_cli_text_still_work(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("quick: false\nrecipe: {lr: 1e-3}\nepochs: 3\nprefixes: [0.5, 25]\n")
    from tactile_zoo.bench.config import load_yaml_config

    config = merge_config(load_yaml_config(tmp_path / "c.yaml"), {"threads": "1", "folds": "all"},
                          sets=["quick_lr=1"][:0] + ["batch_size=8", "schedule={type: cosine, eta_min: 1e-2}"])
    assert config.quick is False and config.recipe["lr"] == 1e-3 and config.epochs == 3 and config.threads == 1
    assert config.prefixes == [0.25, 0.5, 1.0] and config.folds is None
    assert config.recipe["schedule"] == {"type": "cosine", "eta_min": 0.01}
    assert merge_config(None, {"quick": True}, sets=[]).quick is True


@pytest.mark.parametrize("args", [
    ["--set", "nosuch:lr=0.1"], ["--hparam", "nosuch:hidden=4"], ["--dataset-arg", "nosuchds:seed=1"],
])
def test_item_2_an_override_for_an_unknown_name_exits_2_listing_the_names(
        args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert run_cli([*DRY, *args]) == 2
    err = capsys.readouterr().err
    assert "names no registered" in err and "nosuch" in err and ("tiny_mlp" in err or "tiny_blobs" in err), err


@pytest.mark.parametrize("text", ["model_overrides: {nosuch: {recipe: {lr: 0.1}}}",
                                  "dataset_kwargs: {nosuchds: {seed: 1}}", "model_overrides: {'zz_*': {}}"])
def test_item_2_in_a_config_file_too(tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "c.yaml").write_text(text + "\n")
    assert run_cli([*DRY, "--config", str(tmp_path / "c.yaml")]) == 2
    assert "names no registered" in capsys.readouterr().err


def test_overrides_for_registered_names_and_patterns_apply() -> None:
    config = merge_config({"model_overrides": {"tiny_*": {"recipe": {"lr": 0.5}}, "tiny_rate": {"hparams": {}}},
                           "dataset_kwargs": {"*": {"seed": 1}, "tiny_*": {"seed": 2}, "tiny_kfold": {"seed": 3}}},
                          {"models": ["tiny_mlp"]}, sets=["tiny_mlp:batch_size=4"])
    plan = plan_cells(config, ["tiny_mlp"], ["tiny_blobs", "tiny_kfold"])  # tiny_rate: registered, not selected
    assert plan.configs["tiny_mlp", "tiny_blobs"].recipe.lr == 0.5  # the pattern reaches the model
    assert plan.configs["tiny_mlp", "tiny_blobs"].recipe.batch_size == 4
    assert plan.dataset_kwargs == {"tiny_blobs": {"seed": 2}, "tiny_kfold": {"seed": 3}}  # the most specific wins


@pytest.mark.parametrize(("sets", "message"), [
    (["schedule={type: cosine, t_max: -3}"], "schedule.t_max must be an integer >= 1, got -3"),
    (["schedule={type: multistep, milestones: [-5, -10]}"], "schedule.milestones[0] must be an integer >= 0, got -5"),
    (["schedule={type: multistep, milestones: [10, 5]}"], "schedule.milestones must increase"),
    (["schedule={type: step, step_size: -2}"], "schedule.step_size must be an integer >= 1, got -2"),
    (["optimizer=sgd", "momentum=-5"], "momentum must be >= 0, got -5"),
    (["momentum=1"], "momentum must be < 1, got 1"),
])
def test_item_3_out_of_range_recipe_values_are_refused_on_every_dataset(sets: list[str], message: str) -> None:
    for dataset in ("tiny_blobs", "tiny_kfold"):
        with pytest.raises(ConfigError) as caught:
            plan_cells(merge_config(None, {"models": ["tiny_mlp"]}, sets=sets), ["tiny_mlp"], [dataset])
        assert message in str(caught.value) and str(caught.value).startswith("--set "), str(caught.value)


def test_item_3_a_simulator_budget_does_not_hide_a_bad_t_max() -> None:
    """A dataset's epoch budget compressed t_max -3 to 1 before the value was checked (issue 49, item 3)."""
    with pytest.raises(ConfigError, match="t_max must be an integer >= 1"):
        plan_cells(BenchConfig(models=["sgnet"], datasets=["sim_evtouch"],
                               recipe={"schedule": {"type": "cosine", "t_max": -3}}), ["sgnet"], ["sim_evtouch"])


def test_item_3_prefixes_name_distinct_columns() -> None:
    assert BenchConfig(prefixes=[0.1, 10, 0.000001]).prefixes == [0.000001, 0.1, 1.0]
    for bad in ([1e-7], [0.1234567], "0.00000001"):
        with pytest.raises(ConfigError, match="more than 6 decimals"):
            BenchConfig(prefixes=bad)


def test_item_11_train_with_a_negative_momentum_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--set", "optimizer=sgd",
                 "--set", "momentum=-5"]) == 2
    assert "--set momentum=-5: momentum must be >= 0, got -5" in capsys.readouterr().err


def _bench_model(name: str, recipe: dict[str, Any]) -> None:
    import torch

    def build(spec: Any, hidden: int = 4) -> torch.nn.Module:
        if not isinstance(hidden, int):
            raise TypeError(f"hidden must be an int, got {hidden!r}")
        return torch.nn.Linear(1, 1)

    registry.register_model(name, recipes={"default": recipe})(build)


@pytest.mark.parametrize(("hparams", "message"), [
    ({"hidden": [1, 2]}, "recipe 'default' of model 'zz_listy': hparams hidden=[1, 2]: model 'zz_listy' cannot be "
                         "built with it"),
    ({"nosuch": 1}, "recipe 'default' of model 'zz_listy': hparams: model 'zz_listy' takes no keyword argument(s) "
                    "'nosuch'"),
])
def test_items_11_and_13_a_recipe_hparams_error_blames_the_recipe(hparams: dict[str, Any], message: str,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    from tactile_zoo.registry.entries import _unregister

    _bench_model("zz_listy", {"hparams": hparams})
    try:
        assert main(["bench", "--models", "zz_listy", "--datasets", "tiny_blobs", "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert message in err and "--hparam" not in err, err
        assert main(["bench", "--models", "zz_listy", "--datasets", "tiny_blobs", "--dry-run",
                     "--hparam", "hidden=x" if "nosuch" not in hparams else "nosuch=2"]) == 2
        assert "--hparam" in capsys.readouterr().err  # the user's keyword, when given, is the one blamed
    finally:
        _unregister("model", "zz_listy")


#: a billion strings from nine anchors of nine aliases each, under a key every reader walks
BOMB = "".join(f"  {c}: &{c} [{', '.join([f'*{p}'] * 9) if p else ', '.join(['lol'] * 9)}]\n"
               for p, c in zip(["", *"abcdefgh"], "abcdefghi", strict=True))


@pytest.mark.parametrize("text", ["hparams:\n" + BOMB, "recipe: &a {lr: 0.1, x: [*a]}\n"])
def test_item_10_an_anchor_bomb_fails_fast_naming_the_file(tmp_path: Path, text: str,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    started = time.monotonic()
    assert run_cli([*DRY, "--config", str(path)]) == 2
    assert time.monotonic() - started < 20
    assert f"--config {path}:" in capsys.readouterr().err
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "m.yaml").write_text("recipes:\n  default:\n    hparams:\n" +
                                                 BOMB.replace("  ", "      "))
    with pytest.raises(ConfigError, match=str(tmp_path / "recipes" / "m.yaml")):
        read_recipe_file(tmp_path / "recipes" / "m.yaml")


def test_item_10_a_huge_or_endless_file_fails_fast_naming_it(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    started = time.monotonic()
    assert run_cli([*DRY, "--config", "/dev/zero"]) == 2
    assert "--config /dev/zero: larger than 1 MiB" in capsys.readouterr().err
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * MAX_FILE_BYTES)
    with pytest.raises(ConfigError, match=f"{big}: larger than"):
        read_yaml_file(big)
    assert time.monotonic() - started < 20
    with pytest.raises(ConfigError, match="aliases"):  # too many aliases, even small ones
        read_yaml_file(_write(tmp_path / "many.yaml", "a: &a 1\nb: [" + ", ".join(["*a"] * 101) + "]\n"))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path
