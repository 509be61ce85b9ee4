"""The example plugin ``plugins/tactile-zoo-tcn``, installed for real and used exactly like a built-in model.

The module fixture builds and installs the distribution with pip (offline: ``--no-index --no-deps
--no-build-isolation``, using the setuptools of the test environment) into a temporary ``--target`` folder that goes
on ``sys.path``. So the test sees what a user's ``pip install`` produces: the entry point comes from the plugin's own
``pyproject.toml``, and the code is imported from the installed copy, not from the source tree. The source is copied
first, because building in place would leave ``build/`` and ``*.egg-info`` in the repository.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from plugin_install import installed_once

from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.data import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import (
    get_model_entry,
    get_sensor,
    instantiate_model,
    list_datasets,
    load_dataset,
    model_names,
    read_recipe_file,
)
from tactile_zoo.testing import MODEL_LEVELS, MODEL_RULES, check_model

pytestmark = pytest.mark.xdist_group("plugin_tcn")  # one worker installs it once

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "tactile-zoo-tcn"
DIST, VERSION = "tactile-zoo-tcn", "0.2.0"
#: the TCN's registered recipes as its ``zoo_meta`` dict declared them before they moved into its recipe file
RECIPE_SNAPSHOT = json.loads((Path(__file__).parent / "models" / "fixtures" / "registered_recipes.json").read_text()
                             )["plugins"]["tcn"]

# (sensor, channels, globals) of the four sensor families
FAMILIES = [("neutouch", 2, 0), ("biotac_sp", 1, 0), ("optoforce3", 4, 3), ("uskin_allegro", 3, 8)]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    target = installed_once(PLUGIN, tmp_path_factory)
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("TACTILE_ZOO_NO_PLUGINS", raising=False)
        mp.delenv("TACTILE_ZOO_STRICT_PLUGINS", raising=False)
        mp.syspath_prepend(str(target))
        registry.reset_plugins()
        yield target
        for name in [m for m in sys.modules if m == "tactile_zoo_tcn" or m.startswith("tactile_zoo_tcn.")]:
            del sys.modules[name]
    registry.reset_plugins()


def _spec(sensor: str, channels: int, globals_: int, steps: int = 12, classes: int = 3) -> DatasetSpec:
    s = get_sensor(sensor)
    return DatasetSpec(f"tcn_{sensor}", classes, tuple(f"c{i}" for i in range(classes)), steps, s.num_nodes,
                       channels, globals_, s)


def _batch(spec: DatasetSpec, batch: int = 4, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor | None]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen)
    g = torch.randn(batch, spec.num_steps, spec.num_globals, generator=gen) if spec.num_globals else None
    return x, g


def test_the_distribution_installs_only_its_package(installed):
    assert sorted(p.name for p in installed.iterdir()) == ["tactile_zoo_tcn", f"tactile_zoo_tcn-{VERSION}.dist-info"]
    entry_points = (installed / f"tactile_zoo_tcn-{VERSION}.dist-info" / "entry_points.txt").read_text()
    assert "[tactile_zoo.models]" in entry_points and "tcn = tactile_zoo_tcn:TCN" in entry_points


def test_tcn_is_discovered_with_its_metadata(installed):
    assert "tcn" in model_names() and model_names("*tcn*", tags=["temporal", "convolutional"]) == ["tcn"]
    entry = get_model_entry("TCN")
    assert (entry.dist, entry.version, entry.qualified_name) == (DIST, VERSION, f"{DIST}:tcn")
    assert Path(sys.modules["tactile_zoo_tcn"].__file__).is_relative_to(installed)  # the installed copy
    meta = entry.meta
    assert meta["year"] == 2018 and "Sequence Modeling" in meta["paper"] and meta["causal"] is True
    assert meta["tags"] == ["convolutional", "temporal"] and meta["inputs"] == ["globals"]
    assert {"loss", "optimizer", "lr", "max_epochs", "patience", "batch_size"} <= set(meta["recipe"])
    assert meta["recipe"]["loss"] == "ce" and meta["recipe"]["optimizer"] == "adam"
    # the recipe came from the installed package's recipe file, and is the one the plugin declared as a dict before
    assert (installed / "tactile_zoo_tcn" / "recipes" / "tcn.yaml").is_file()
    assert read_recipe_file(installed / "tactile_zoo_tcn" / "recipes" / "tcn.yaml")["recipes"] == meta["recipes"]
    assert {"default_recipe": meta["default_recipe"], "recipes": meta["recipes"]} == RECIPE_SNAPSHOT
    [info] = [i for i in registry.plugins() if i.dist == DIST]
    assert (info.version, info.group, info.name, info.value, info.status) == \
        (VERSION, "tactile_zoo.models", "tcn", "tactile_zoo_tcn:TCN", "ok")


@pytest.mark.parametrize("readout", ["mean", "last"])
def test_tcn_keeps_the_model_contract(installed, readout):
    """The public suite a plugin author runs, on every sensor family: forward, global inputs, batch independence,
    determinism, gradients, causal prefixes, streaming equal to forward on every prefix (after a training pass has
    moved the input BatchNorm's statistics), state_dict, and (the example plugin names its paper) the publication
    level's metadata completeness; then on the class itself, before any registration, at the default level."""
    report = check_model("tcn", hparams={"hidden": 8, "readout": readout}, level="publication")
    assert report.subject == "tcn" and sorted(report.rules) == sorted(MODEL_RULES), report
    assert len([where for rule, where in report.passed if rule == "streaming"]) == len(FAMILIES)
    tcn_class = sys.modules["tactile_zoo_tcn"].TCN
    report = check_model(tcn_class, _spec("uskin_allegro", 3, 8), hparams={"hidden": 8, "readout": readout})
    assert report.subject == "TCN" and report.rules == list(MODEL_LEVELS["plugin"]), report


@pytest.mark.parametrize("sensor, channels, globals_", FAMILIES)
def test_tcn_depth_covers_the_recording(installed, sensor, channels, globals_):
    spec = _spec(sensor, channels, globals_, steps=40)
    model = instantiate_model("tcn", spec, hidden=8)
    assert model.receptive_field >= 40  # the default depth covers the whole recording
    assert isinstance(instantiate_model(f"{DIST}:tcn", spec, hidden=8, levels=2, readout="last"), type(model))


def test_tcn_trains(installed):
    """A few Adam steps on a task where the class is which taxel patch fires, and when: the loss falls."""
    torch.manual_seed(0)
    spec = _spec("neutouch", 2, 0, steps=16)
    gen = torch.Generator().manual_seed(1)
    y = torch.arange(48) % 3
    x = (torch.rand(48, 16, 39, 2, generator=gen) < 0.02).float()  # (B, T, N, C) background events
    for i, label in enumerate(y.tolist()):
        start = int(torch.randint(0, 8, (1,), generator=gen))
        x[i, start:start + 4, 8 * label:8 * label + 8, 0] = 1.0  # an ON burst on patch `label`
    model = instantiate_model("tcn", spec, hidden=16)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(30):
        loss = torch.nn.functional.cross_entropy(model(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert sum(losses[-3:]) / 3 < 0.5 * losses[0], losses
    model.eval()
    assert (model(x).argmax(1) == y).float().mean() > 0.9


def test_tcn_rejects_bad_input_with_one_clear_error(installed):
    spec = _spec("uskin_allegro", 3, 8)
    model = instantiate_model("tcn", spec, hidden=8)
    x, g = _batch(spec)
    with pytest.raises(ConfigError, match="global features"):
        model(x)
    with pytest.raises(ConfigError, match=r"x must be \(B, T, 60, 3\)"):
        model(x[:, :, :30], g)
    with pytest.raises(ConfigError, match="readout"):
        instantiate_model("tcn", spec, readout="max")
    with pytest.raises(ConfigError, match="kernel_size"):
        instantiate_model("tcn", spec, kernel_size=1)


def test_tcn_in_the_cli(installed, capsys):
    assert main(["plugins"]) == 0
    [row] = [line for line in capsys.readouterr().out.splitlines() if line.startswith(DIST)]
    assert row.split()[:3] == [DIST, VERSION, "tactile_zoo.models"]
    assert "tcn = tactile_zoo_tcn:TCN" in row and row.endswith("[ok]")
    assert main(["list", "models"]) == 0
    [row] = [line for line in capsys.readouterr().out.splitlines() if line.split()[0] == "tcn"]
    assert "convolutional, temporal" in row and "Sequence Modeling" in row
    assert main(["info", "tcn", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "model" and info["name"] == f"{DIST}:tcn" and info["year"] == 2018
    simulated = list_datasets("sim_*")
    if simulated:  # `info` builds the model for the first simulated dataset and counts its parameters
        spec = load_dataset(simulated[0], split="train").spec
        assert info["built_for"] == simulated[0]
        assert info["parameters"] == sum(p.numel() for p in instantiate_model("tcn", spec).parameters())
