"""A plugin whose entry point is named like a built-in is reached as ``dist:name``, and the harness runs that plugin.

The tiny zoo's ``tiny_mlp`` stands in for the built-in; the fake distribution ``zt-clash`` registers an entry point of
the same name whose model has another class and another parameter count (issue 38, item 1).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest
from conftest import run_cli
from fake_plugins import GOOD_MODULE, FakeSite

from tactile_zoo import registry
from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.grid import build_grid, resolve_models

PLUGIN = "zt-clash:tiny_mlp"


@pytest.fixture
def clash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    root = tmp_path / "site"
    root.mkdir()
    site = FakeSite(root, monkeypatch)
    module = site.add("zt-clash", GOOD_MODULE, models={"tiny_mlp": "Net"})
    warnings.simplefilter("ignore", registry.PluginWarning)  # "shadowed by the built-in": expected here
    yield module
    site.close()


def test_a_qualified_plugin_name_stays_qualified_through_the_grid(clash: str) -> None:
    assert resolve_models([PLUGIN]) == [PLUGIN]
    assert resolve_models(["tiny_mlp", PLUGIN]) == ["tiny_mlp", PLUGIN]
    grid = build_grid(BenchConfig(models=["tiny_mlp", PLUGIN], datasets=["tiny_blobs"]))
    cells = {c.model: c for c in grid.cells}
    assert cells[PLUGIN].config.model_source == "zt-clash"
    assert cells["tiny_mlp"].config.model_source == "builtin"
    assert cells[PLUGIN].config_hash != cells["tiny_mlp"].config_hash


def test_bench_trains_the_plugin_not_the_builtin(clash: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", PLUGIN, "--datasets", "tiny_blobs", "--epochs", "1", "--out", str(out), "-q",
                    "--no-plots"]) == 0
    (path,) = (out / "cells").glob("*.json")
    record = json.loads(path.read_text())
    assert record["model"] == PLUGIN and record["config"]["model_source"] == "zt-clash"
    # GOOD_MODULE's Net: one Linear of (3 taxels x 4 channels) -> 3 classes; tiny_mlp would have 307
    assert record["params"] == 12 * 3 + 3


def test_a_bare_scoped_override_does_not_reach_the_shadowed_plugin(clash: str) -> None:
    config = BenchConfig(models=["tiny_mlp", PLUGIN], datasets=["tiny_blobs"],
                         model_overrides={"tiny_mlp": {"hparams": {"hidden": 8}},
                                          PLUGIN: {"hparams": {"width": 3}}})
    cells = {c.model: c for c in build_grid(config).cells}
    assert cells["tiny_mlp"].config.hparams == {"hidden": 8}
    assert cells[PLUGIN].config.hparams == {"width": 3}
