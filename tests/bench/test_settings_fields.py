"""The bench settings are listed once, in the schema (:class:`tactile_zoo.settings.BenchSettings`):
:class:`~tactile_zoo.bench.config.BenchConfig` takes its fields, their order and their defaults from it, so a setting
added to the schema is a ``BenchConfig`` field, a ``--config`` key and a ``run.json`` setting with nothing else to
edit (and one cannot be added to ``BenchConfig`` alone)."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import pytest

from tactile_zoo import settings
from tactile_zoo.bench import config as bench_config
from tactile_zoo.bench.config import CONFIG_KEYS, BenchConfig, load_yaml_config
from tactile_zoo.engine.evaluate import DEFAULT_PREFIXES
from tactile_zoo.errors import ConfigError

#: what a BenchConfig built with no arguments holds for the settings it had when its fields came to be read from the
#: schema (as the dataclass declared them before; run.json records these, so they must not move). A setting added
#: since is checked against the schema's own default.
PLAIN_DEFAULTS = {
    "models": ["all"], "datasets": ["all"], "root": None, "download": False, "seeds": [0], "folds": None,
    "epochs": None, "refit": False, "quick": False, "device": "auto", "out": None, "force": False,
    "executor": "local", "workers": None, "scheduler": None, "retries": None, "dashboard": None,
    "save_weights": False, "tracker": None, "tracker_dir": None, "threads": None, "plugin_modules": [],
    "prefixes": list(DEFAULT_PREFIXES), "recipe_name": None, "evaluation": None, "recipe": {}, "hparams": {},
    "model_overrides": {}, "dataset_kwargs": {},
}
SCHEMA_FIELDS = list(settings.BenchSettings.model_fields)


def test_bench_config_has_the_schema_fields_in_its_order() -> None:
    assert [f.name for f in fields(BenchConfig)] == list(settings.BenchSettings.model_fields)
    assert CONFIG_KEYS == set(settings.BenchSettings.model_fields)


def test_a_default_bench_config_holds_the_plain_form_of_every_schema_default() -> None:
    config = BenchConfig().to_dict()
    assert list(config) == SCHEMA_FIELDS  # run.json's key order
    assert {k: config[k] for k in PLAIN_DEFAULTS} == PLAIN_DEFAULTS
    for name in set(SCHEMA_FIELDS) - set(PLAIN_DEFAULTS):
        assert config[name] == settings.BenchSettings.model_fields[name].get_default(call_default_factory=True), name
    one, other = BenchConfig(), BenchConfig()
    for name in ("models", "seeds", "prefixes", "plugin_modules", "recipe", "model_overrides"):
        assert getattr(other, name) is not getattr(one, name), f"{name}: a default shared between configs"


def test_a_setting_added_to_the_schema_becomes_a_field_with_its_default(monkeypatch: pytest.MonkeyPatch) -> None:
    class Wider(settings.BenchSettings):
        colour: settings.Text = "teal"
        tags: dict[str, int] = settings.Field(default_factory=dict)

    monkeypatch.setattr(settings, "BenchSettings", Wider)
    probe = dataclass(bench_config._settings_fields(type("Probe", (), {})))
    declared = {f.name: f for f in fields(probe)}
    assert list(declared) == [*SCHEMA_FIELDS, "colour", "tags"]
    assert declared["colour"].default == "teal" and declared["tags"].default is MISSING
    assert probe().tags == {} and probe().tags is not probe().tags


def test_a_list_default_in_the_schema_is_refused_at_import(monkeypatch: pytest.MonkeyPatch) -> None:
    class Shared(settings.BenchSettings):  # one list object every config would share: not a default to copy
        extra: list[int] = [1]

    monkeypatch.setattr(settings, "BenchSettings", Shared)
    with pytest.raises(ValueError, match="mutable default"):
        dataclass(bench_config._settings_fields(type("Probe", (), {})))


def test_a_config_file_knows_every_schema_key_and_no_other(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("".join(f"{key}: null\n" for key in ("root", "out", "epochs", "tracker", "recipe_name")))
    assert load_yaml_config(path) == dict.fromkeys(("root", "out", "epochs", "tracker", "recipe_name"))
    path.write_text("seeds: [0]\ncolour: teal\n")
    with pytest.raises(ConfigError, match=r"unknown key\(s\) colour; known keys: dashboard, dataset_kwargs"):
        load_yaml_config(path)


def test_null_prefixes_are_the_default_prefixes(tmp_path: Path) -> None:
    # the schema takes ``prefixes: null`` (its default); the bench reads it as the default fractions
    assert BenchConfig(prefixes=None).prefixes == list(DEFAULT_PREFIXES)
    path = tmp_path / "c.yaml"
    path.write_text("prefixes: null\n")
    assert BenchConfig(**load_yaml_config(path)).prefixes == list(DEFAULT_PREFIXES)
    with pytest.raises(ConfigError, match="--prefixes must be a comma-separated list of fractions"):
        BenchConfig(prefixes=[])
