from __future__ import annotations

from pathlib import Path

import pytest

from tactile_zoo.bench.config import (
    BenchConfig,
    load_yaml_config,
    merge_config,
    parse_assignment,
    parse_folds,
    parse_prefixes,
    parse_seeds,
)
from tactile_zoo.errors import ConfigError


def test_seeds_lists_ranges_and_errors() -> None:
    assert parse_seeds("0,1,2") == [0, 1, 2]
    assert parse_seeds("3-5, 1") == [1, 3, 4, 5]
    assert parse_seeds([2, "0"]) == [0, 2] and parse_seeds(7) == [7]
    for bad in ("", "a", "-1", "1.5", "5-2", [], [True]):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad)


def test_folds_positive_or_all() -> None:
    assert parse_folds(None) is None and parse_folds("all") is None and parse_folds("3") == 3
    for bad in ("0", "-2", "x", 1.5):
        with pytest.raises(ConfigError, match="--folds"):
            parse_folds(bad)


def test_prefixes_fractions_percentages_and_full_length() -> None:
    assert parse_prefixes("0.5,0.1") == [0.1, 0.5, 1.0]
    assert parse_prefixes([25, 50]) == [0.25, 0.5, 1.0]
    with pytest.raises(ConfigError):
        parse_prefixes("0,0.5")


def test_assignments_with_scopes() -> None:
    assert parse_assignment("--set", "lr=1e-3") == (None, "lr", 1e-3)
    assert parse_assignment("--set", "sgnet:schedule={type: cosine}") == ("sgnet", "schedule", {"type": "cosine"})
    assert parse_assignment("--set", "dist:tcn:patience=null") == ("dist:tcn", "patience", None)
    assert parse_assignment("--hparam", "hidden=64") == (None, "hidden", 64)
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_assignment("--set", "lr")


def test_yaml_unknown_keys_name_them(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("models: all\nsedes: [0, 1]\nepoch: 3\n")
    with pytest.raises(ConfigError, match=r"c.yaml: unknown key\(s\) epoch, sedes"):
        load_yaml_config(path)
    path.write_text("models: [a\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_yaml_config(path)
    path.write_text("model_overrides: {tiny_mlp: {recipes: {}}}\n")
    with pytest.raises(ConfigError, match="recipes"):
        merge_config(load_yaml_config(path), {})


def test_flags_win_over_yaml_and_overrides_layer(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("seeds: [0, 1]\nepochs: 5\nrecipe: {lr: 0.01}\nplugin_modules: [a]\n"
                    "model_overrides: {tiny_mlp: {hparams: {hidden: 4}}}\ndataset_kwargs: {tiny_blobs: {seed: 3}}\n")
    cfg = merge_config(load_yaml_config(path), {"epochs": "2", "plugin_modules": ["b"]},
                       sets=["batch_size=8", "tiny_mlp:lr=0.5"], hparams=["dropout=0.0"],
                       dataset_args=["tiny_blobs:n_train=4", "seed=9"])
    assert cfg.seeds == [0, 1] and cfg.epochs == 2 and cfg.plugin_modules == ["a", "b"]
    assert cfg.overrides_for("tiny_mlp") == ({"lr": 0.5, "batch_size": 8}, {"dropout": 0.0, "hidden": 4})
    assert cfg.overrides_for("tiny_rate") == ({"lr": 0.01, "batch_size": 8}, {"dropout": 0.0})
    assert cfg.kwargs_for("tiny_blobs") == {"seed": 3, "n_train": 4} and cfg.kwargs_for("other") == {"seed": 9}


def test_config_validation() -> None:
    with pytest.raises(ConfigError, match="--scheduler only applies"):
        BenchConfig(scheduler="tcp://x:1")
    with pytest.raises(ConfigError, match="--workers"):
        BenchConfig(workers=0)
    with pytest.raises(ConfigError, match="--executor"):
        BenchConfig(executor="slurm")
    assert BenchConfig(quick=True).effective_epochs() == 2 and BenchConfig(quick=True, epochs=4).effective_epochs() == 4


@pytest.mark.parametrize(("flag", "items", "message"), [
    # issue 49: each assignment is checked as it is read, so the error names the flag and its text
    ("hparams", ["dropout=nan"], "--hparam dropout=nan: dropout is nan, expected a finite number"),
    ("hparams", ["tiny_mlp:hidden=-inf"], "--hparam tiny_mlp:hidden=-inf: hidden is -inf"),
    ("sets", ["schedule={type: multistep, milestones: [.inf]}"],
     "--set schedule={type: multistep, milestones: [.inf]}: schedule.milestones[0] must be an integer, got inf"),
    ("dataset_args", ["noise=.nan"], "--dataset-arg noise=.nan: noise is nan"),
])
def test_a_non_finite_setting_is_refused(flag: str, items: list[str], message: str) -> None:
    """Issue 38: every cell records its settings and a record holds no NaN or infinity, so ``--hparam x=nan`` is bad
    input, refused before anything runs (it crashed the run.json writer, and before that was written as NaN)."""
    with pytest.raises(ConfigError) as caught:
        merge_config(None, {"models": ["tiny_mlp"]}, **{flag: items})
    assert str(caught.value).startswith(message)
