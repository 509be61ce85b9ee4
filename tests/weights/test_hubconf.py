"""``hubconf.py`` at the repository root, loaded by torch.hub itself (``source="local"`` on this checkout, offline):
one entry point per built-in model, each the model ``tactile_zoo.create_model`` builds; ``pretrained=`` loads the
weight pack's weights, installed by pip as tests/weights/test_plugin_weights.py installs it; weights no installed
pack provides are one clear error; and torch.hub's ``dependencies`` list is pyproject.toml's."""

from __future__ import annotations

import importlib.util
import re
import tomllib
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest
import torch
from weights_helpers import installed_weight_pack, slip_spec

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.errors import ConfigError, UnknownNameError
from tactile_zoo.weights import WeightEntry, read_manifest, reset_weights

pytestmark = pytest.mark.xdist_group("plugin_weights")

REPO = Path(__file__).resolve().parents[2]
PLUGIN = REPO / "plugins" / "tactile-zoo-weights"
SHIPPED = read_manifest(PLUGIN / "tactile_zoo_weights" / "manifest.json")
#: import names of the distributions whose name is not their module's
IMPORT_NAMES = {"scikit-learn": "sklearn", "pyyaml": "yaml"}


def _hubconf() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hubconf", REPO / "hubconf.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _hub(model: str, **kwargs: object) -> torch.nn.Module:
    return torch.hub.load(str(REPO), model, source="local", **kwargs)


def _builtin_models() -> list[str]:
    # the zoo's own models, not the ones other test modules register in this worker
    return [name for name in registry.model_names() if registry.get_model_entry(name).dist is None
            and registry.get_model_entry(name).obj.__module__.startswith("tactile_zoo.models.")]


@pytest.fixture
def no_weight_pack(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Weights discovery sees no pack (not one the environment may have installed)."""
    from plugin_install import only_weights_from

    only_weights_from(monkeypatch, tmp_path)
    reset_weights()
    yield
    reset_weights()


def test_one_entry_point_per_builtin_model_named_as_in_the_registry() -> None:
    hub = _hubconf()
    # what torch.hub.list shows: the public callables
    entries = sorted(name for name in dir(hub) if callable(getattr(hub, name)) and not name.startswith("_"))
    assert entries == sorted(_builtin_models())
    assert "x_tacformer" in entries and len(entries) >= 8


@pytest.mark.parametrize("model", _builtin_models())
def test_an_entry_point_builds_what_create_model_builds(model: str) -> None:
    spec = slip_spec()
    torch.manual_seed(0)
    loaded = _hub(model, spec=spec)
    torch.manual_seed(0)
    built = tz.create_model(model, spec)
    assert type(loaded) is type(built) and loaded.spec == spec
    got, expected = loaded.state_dict(), built.state_dict()
    assert list(got) == list(expected)
    assert all(torch.equal(got[k], expected[k]) for k in expected)


def test_an_entry_point_without_spec_or_weights_says_what_it_needs() -> None:
    with pytest.raises(ConfigError, match=r"create_model\('sgnet'\): pass the dataset spec, or pretrained="):
        _hub("sgnet")


@pytest.fixture(scope="module")
def pack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    with installed_weight_pack(PLUGIN, tmp_path_factory) as target:
        yield target


@pytest.mark.parametrize("entry", SHIPPED, ids=[e.tag for e in SHIPPED])
def test_pretrained_loads_the_weight_packs_weights(pack: Path, entry: WeightEntry) -> None:
    loaded = _hub(entry.model, pretrained=entry.dataset)
    assert loaded.zoo_pretrained.tag == entry.tag and loaded.zoo_pretrained.dist == "tactile-zoo-weights"
    expected = tz.create_model(entry.model, pretrained=entry.dataset).state_dict()
    got = loaded.state_dict()
    assert list(got) == list(expected) and all(torch.equal(got[k], expected[k]) for k in expected)


def test_the_issues_example_loads_x_tacformer_on_ev_objects(pack: Path) -> None:
    model = torch.hub.load(str(REPO), "x_tacformer", source="local", pretrained="ev_objects")
    assert model.zoo_pretrained.tag == "x_tacformer.full_ev_objects" and model.spec.num_classes == 36


def test_weights_the_pack_lacks_are_one_error_naming_what_it_has(pack: Path) -> None:
    with pytest.raises(UnknownNameError) as info:
        _hub("x_tacformer", pretrained="sim_evtouch")
    message = str(info.value)
    assert message.startswith("torch.hub entry 'x_tacformer': pretrained='sim_evtouch': ")
    assert "Installed weights of 'x_tacformer': x_tacformer.full_biotac_dos, x_tacformer.full_ev_containers, " \
           "x_tacformer.full_ev_objects" in message
    missing = sorted(set(_builtin_models()) - {e.model for e in SHIPPED})
    assert missing, "every model has shipped weights: pick another case for the next line"
    with pytest.raises(UnknownNameError, match=rf"the weight pack \(.*\) has no weights of '{missing[0]}'"):
        _hub(missing[0], pretrained="ev_objects")


def test_without_the_pack_the_error_names_the_pip_command(no_weight_pack: None) -> None:
    with pytest.raises(UnknownNameError) as info:
        _hub("x_tacformer", pretrained="ev_objects")
    message = str(info.value)
    assert "Installed weights of 'x_tacformer': none" in message
    assert f"the weight pack (pip install {PLUGIN}) has weights of 'x_tacformer' for 'biotac_dos', " \
           "'ev_containers', 'ev_objects'" in message


def test_the_dependencies_torch_hub_checks_are_pyprojects() -> None:
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    names = [re.match(r"[A-Za-z0-9_.-]+", requirement)[0].lower() for requirement in declared]
    modules = {IMPORT_NAMES.get(name, name.replace("-", "_")) for name in names}
    assert sorted(_hubconf().dependencies) == sorted(modules)
    assert all(importlib.util.find_spec(m) is not None for m in modules)


def test_hubconf_is_in_the_sdist_manifest_and_outside_the_packages() -> None:
    assert re.search(r"^include .*\bhubconf\.py\b", (REPO / "MANIFEST.in").read_text(), re.M)
    found = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    assert found["include"] == ["tactile_zoo", "tactile_zoo.*"]  # the wheel: the package alone, not hubconf.py
