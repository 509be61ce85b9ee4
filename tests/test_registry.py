"""The registry: decorators, normalised lookups, listing, metadata checks, and entry-point plugin discovery.

Plugins are real distributions as ``importlib.metadata`` sees them (a ``*.dist-info`` with ``entry_points.txt`` on
``sys.path``, see ``fake_plugins.py``). Every name a test registers starts with ``zt_`` and is removed afterwards, and
nothing here depends on which built-in models or datasets exist.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch
from fake_plugins import GOOD_MODULE, FakeSite, forget_test_registrations, snapshot, unique

from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.data import DatasetSpec
from tactile_zoo.errors import ConfigError, PluginError, TactileZooError, UnknownNameError
from tactile_zoo.registry import (
    PluginWarning,
    get_dataset_entry,
    get_model_entry,
    get_sensor,
    instantiate_model,
    list_datasets,
    list_sensors,
    load_dataset,
    model_names,
    plugins,
    register_dataset,
    register_model,
)

SENSORS = {"neutouch", "biotac_sp", "optoforce3", "uskin_allegro"}


@pytest.fixture(autouse=True)
def _clean_registry():
    before = snapshot()
    yield
    forget_test_registrations(before)
    registry.set_plugin_policy()
    registry.reset_plugins()


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    root = tmp_path / "site"
    root.mkdir()
    fake = FakeSite(root, monkeypatch)
    yield fake
    fake.close()


@pytest.fixture(scope="module")
def spec() -> DatasetSpec:
    return DatasetSpec("zt_spec", 3, ("a", "b", "c"), 5, 39, 2, 0, get_sensor("neutouch"))


class _Tiny(torch.nn.Module):
    def __init__(self, spec: DatasetSpec, width: int = 2) -> None:
        super().__init__()
        self.width = width
        self.lin = torch.nn.Linear(spec.num_channels, spec.num_classes)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.lin(x.mean(dim=(1, 2)))


def _ours(infos: list[registry.PluginInfo], prefix: str = "zt-") -> list[registry.PluginInfo]:
    return [i for i in infos if i.dist.startswith(prefix)]


# ----------------------------------------------------------------------------------------------- decorators
def test_register_model_bare_and_with_arguments(spec):
    @register_model
    class ZtBareNet(_Tiny):
        pass

    name = unique("args_net")

    @register_model(name, paper="P", year=2021, tags=["graph", "spiking"], inputs=["graph"], causal=True,
                    recipe={"loss": "mse_rate", "optimizer": "adamw", "lr": 1e-3, "schedule": {"type": "cosine"},
                            "patience": None, "batch_size": 8, "max_epochs": 3})
    def build(spec: DatasetSpec, **hparams):
        return _Tiny(spec, **hparams)

    assert "zt_bare_net" in model_names()  # the class name, snake_cased
    assert ZtBareNet.zoo_meta == {}
    assert isinstance(instantiate_model("zt_bare_net", spec), ZtBareNet)
    entry = get_model_entry(name)
    assert entry.name == name and entry.obj is build and entry.dist is None and not entry.is_plugin
    assert entry.meta["year"] == 2021 and entry.meta["recipe"]["loss"] == "mse_rate"
    assert build.zoo_meta == dict(entry.meta)  # the metadata travels with the object (for entry points to it)
    model = instantiate_model(name, spec, width=7)
    assert isinstance(model, _Tiny) and model.width == 7  # hyper-parameters reach the factory
    with pytest.raises(TypeError):
        entry.meta["year"] = 1999  # read-only


def test_register_dataset_and_load_dataset_passes_arguments(spec):
    calls = []

    @register_dataset
    class ZtSmallSet:
        num_folds = 3

        def __init__(self, root=None, split=None, fold=0, download=False, **kw):
            calls.append((root, split, fold, download, kw))
            self.spec = spec

    name = unique("noattr_set")
    register_dataset(name, num_classes=3)(lambda **kw: object())

    ds = load_dataset("ZtSmallSet", root="/nowhere", split="val", fold=2, seed=5)
    assert isinstance(ds, ZtSmallSet) and ds.num_folds == 3
    assert calls == [("/nowhere", "val", 2, False, {"seed": 5})]
    assert get_dataset_entry("zt-small-set").meta == {}
    with pytest.raises(PluginError, match=r"without \.spec"):
        load_dataset(name)


def test_lookups_are_normalised(spec):
    name = unique("q_tacformer")  # zt_q_tacformer_<hex>
    register_model(name)(lambda spec: _Tiny(spec))
    stem = name[len("zt_q_tacformer_"):]
    forms = [name, name.upper(), name.replace("_", "-"), f"Zt-Q-Tacformer-{stem}", f"ZtQTacformer{stem.upper()}",
             f"zt q tacformer {stem}"]
    entries = {id(get_model_entry(form)) for form in forms}
    assert len(entries) == 1
    if model_names("x_tacformer"):  # the paper's model, once it is registered
        assert get_model_entry("X-Tacformer") is get_model_entry("x-tacformer") is get_model_entry("XTacformer")
    # a different object under a name that normalises the same is refused, not silently replaced
    with pytest.raises(TactileZooError, match="already registered"):
        register_model(name.replace("_", "").upper())(lambda spec: _Tiny(spec))
    assert get_sensor("NeuTouch") is get_sensor("neu_touch") is get_sensor("neutouch")


def test_unknown_name_lists_close_matches_and_every_known_name():
    name = unique("q_tacformer")
    register_model(name)(lambda spec: _Tiny(spec))
    typo = name.replace("tacformer", "tacfromer")
    with pytest.raises(UnknownNameError) as err:
        get_model_entry(typo)
    message = str(err.value)
    assert isinstance(err.value, KeyError) and isinstance(err.value, TactileZooError)
    assert f"Did you mean '{name}'" in message
    known = message.split("Known models:")[1]
    assert all(n in known for n in model_names())
    with pytest.raises(UnknownNameError, match="Did you mean 'neutouch'") as err:
        get_sensor("neutuch")
    assert all(s in str(err.value) for s in SENSORS)
    for call in (lambda: instantiate_model(typo, None), lambda: load_dataset(unique("nothing")),
                 lambda: get_sensor("")):
        with pytest.raises(UnknownNameError):
            call()


def test_list_patterns_wildcards_and_tags():
    alpha, beta, gamma = unique("alpha_graph"), unique("beta_graph"), unique("gamma")
    for name, tags in ((gamma, ["convolutional"]), (alpha, ["graph", "spiking"]), (beta, ["graph"])):
        register_model(name, tags=tags)(lambda spec: _Tiny(spec))
    assert model_names("zt_*") == sorted([alpha, beta, gamma])
    assert model_names("ZT-*-GRAPH*") == [alpha, beta]  # patterns are normalised like names
    assert model_names("zt_?eta*") == [beta]
    assert model_names(["zt_a*", "zt_g*"]) == [alpha, gamma]
    assert model_names("zt_*", tags=["graph"]) == [alpha, beta]
    assert model_names("zt_*", tags="graph") == [alpha, beta]  # one tag as a string, not its characters
    assert model_names("zt_*", tags=["graph", "spiking"]) == [alpha]
    assert model_names("zt_*", tags=["attention"]) == []
    assert model_names("zt_nothing_*") == []
    everything = model_names()
    assert everything == sorted(everything) and {alpha, beta, gamma} <= set(everything)
    assert SENSORS <= set(list_sensors()) and list_sensors() == sorted(list_sensors())
    assert list_sensors("*touch") == ["neutouch"]
    assert list_datasets() == sorted(list_datasets())


@pytest.mark.parametrize("meta, culprit", [
    ({"pape": "typo"}, "pape"),
    ({"tags": "graph"}, "tags"),
    ({"inputs": ["image"]}, "inputs"),
    ({"causal": "yes"}, "causal"),
    ({"year": "2020"}, "year"),
    ({"recipe": ["ce"]}, "recipe"),
    ({"recipe": {"los": "ce"}}, "los"),
    ({"recipe": {"loss": "nll"}}, "recipe 'default': loss"),
    ({"recipe": {"optimizer": "lbfgs"}}, "recipe 'default': optimizer"),
    ({"recipe": {"lr": -0.1}}, "recipe 'default': lr"),
    ({"recipe": {"batch_size": 0}}, "recipe 'default': batch_size"),
    ({"recipe": {"schedule": {"type": "sawtooth"}}}, "recipe 'default': schedule.type"),
])
def test_bad_model_metadata_is_a_config_error(meta, culprit):
    name = unique("bad_meta")
    with pytest.raises(ConfigError, match=culprit):
        register_model(name, **meta)(lambda spec: _Tiny(spec))
    assert model_names(name) == []  # nothing half-registered


def test_bad_dataset_metadata_is_a_config_error():
    name = unique("bad_set")
    with pytest.raises(ConfigError, match="num_clases"):
        register_dataset(name, num_clases=3)(lambda **kw: None)
    assert list_datasets(name) == []


# ----------------------------------------------------------------------------------------------- plugins
def test_entry_point_plugin_is_listed_and_created_like_a_builtin(site, spec):
    name = unique("plug")
    module = site.add("zt-good", GOOD_MODULE, models={name: "Net"}, version="1.2")
    assert name in model_names() and name in model_names("zt_plug*", tags=["convolutional"])
    entry = get_model_entry(name)
    assert (entry.dist, entry.version, entry.qualified_name) == ("zt-good", "1.2", f"zt-good:{name}")
    assert entry.meta["paper"] == "A fake paper" and entry.meta["recipe"]["optimizer"] == "adam"
    model = instantiate_model(name, spec, width=9)
    assert model.origin == module and model.width == 9
    assert model(torch.zeros(2, 5, 39, 2)).shape == (2, 3)
    assert get_model_entry(f"ZT_Good:{name}") is entry  # dist:name, normalised too
    [info] = _ours(plugins())
    assert (info.dist, info.version, info.group, info.name, info.value, info.status, info.error) == \
        ("zt-good", "1.2", "tactile_zoo.models", name, f"{module}:Net", "ok", None)


def test_dataset_plugins_register_through_their_group(site, spec):
    good, bad = unique("plugset"), unique("plugset_noattr")
    site.add("zt-sets", f"""
        import torch
        from tactile_zoo.registry import get_sensor
        from tactile_zoo.data import DatasetSpec

        class Set(torch.utils.data.Dataset):
            zoo_meta = {{"sensor": "neutouch", "num_classes": 3}}
            num_folds = 1

            def __init__(self, root=None, split=None, fold=0, download=False, size=4):
                self.spec = DatasetSpec("{good}", 3, ("a", "b", "c"), 5, 39, 2, 0, get_sensor("neutouch"))
                self.size = size

            def __len__(self):
                return self.size

        def broken(**kwargs):
            return [1, 2, 3]
    """, datasets={good: "Set", bad: "broken"})
    assert {good, bad} <= set(list_datasets("zt_plugset*"))
    assert get_dataset_entry(good).meta == {"sensor": "neutouch", "num_classes": 3}
    assert len(load_dataset(good, split="train", size=6)) == 6
    with pytest.raises(PluginError, match=r"'zt-sets'.*without \.spec"):
        load_dataset(bad)


def test_discovery_is_lazy_and_cached(site, monkeypatch):
    name = unique("lazy")
    module = site.add("zt-lazy", GOOD_MODULE, models={name: "Net"})
    calls = []
    real = registry.discovery._discover_entry_points
    monkeypatch.setattr(registry.discovery, "_discover_entry_points", lambda: calls.append(1) or real())
    list_sensors()
    get_sensor("neutouch")
    assert module not in sys.modules and calls == []  # sensors never need plugins
    assert name in model_names()
    assert module in sys.modules and calls == [1]
    del sys.modules[module]
    model_names()
    list_datasets()
    plugins()
    get_model_entry(name)
    assert module not in sys.modules and calls == [1]  # cached: neither found again nor imported again
    registry.reset_plugins()
    assert name in model_names() and calls == [1, 1]


def test_importing_tactile_zoo_imports_no_plugin(site):
    name = unique("lazy_sub")
    module = site.add("zt-lazy-sub", GOOD_MODULE, models={name: "Net"})
    script = (f"import sys, tactile_zoo; assert {module!r} not in sys.modules, 'imported too early'; "
              f"names = tactile_zoo.list_models(); assert {module!r} in sys.modules; assert {name!r} in names")
    path = [str(site.root)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path)}
    env.pop("TACTILE_ZOO_NO_PLUGINS", None)
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_same_object_met_twice_is_one_registration(site, spec):
    name = unique("twice")
    source = f"""
        import torch
        from tactile_zoo.registry import register_model

        @register_model("{name}", tags=["recurrent"])
        class Twice(torch.nn.Module):
            def __init__(self, spec):
                super().__init__()
                self.lin = torch.nn.Linear(1, spec.num_classes)
    """
    module = site.add("zt-twice", source, models={name: "Twice"})
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginWarning)  # neither shadowed nor a clash
        assert model_names("zt_twice*") == [name]
    entry = get_model_entry(name)
    assert entry.dist == "zt-twice" and entry.meta["tags"] == ["recurrent"]
    assert [i.status for i in _ours(plugins())] == ["ok"]
    assert isinstance(instantiate_model(name, spec), sys.modules[module].Twice)


def test_plugin_module_imported_before_discovery_is_still_one_registration(site, spec):
    name = unique("early")
    module = site.add("zt-early", f"""
        import torch
        from tactile_zoo.registry import register_model

        @register_model("{name}", tags=["recurrent"])
        def build(spec):
            return torch.nn.Linear(1, spec.num_classes)
    """, models={name: "build"})
    importlib.import_module(module)  # a user script importing the plugin package directly, before any lookup
    assert registry.normalize_name(name) in registry._TABLES["model"].builtin  # filed as a local registration
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginWarning)  # the plugin is not "shadowed" by itself
        assert model_names("zt_early*") == [name]
    entry = get_model_entry(name)
    assert entry.dist == "zt-early" and entry.meta["tags"] == ["recurrent"]
    assert [i.status for i in _ours(plugins())] == ["ok"]
    assert isinstance(instantiate_model(name, spec), torch.nn.Linear)


def test_builtin_wins_a_clash_and_the_plugin_stays_reachable(site, spec):
    name = unique("shadow")
    register_model(name)(lambda spec: _Tiny(spec))
    module = site.add("zt-shadower", GOOD_MODULE, models={name: "Net"})
    with pytest.warns(PluginWarning, match=f"zt-shadower:{name}.*shadowed"):
        names = model_names("zt_shadow*")
    assert names == sorted([name, f"zt-shadower:{name}"])
    assert get_model_entry(name).dist is None and isinstance(instantiate_model(name, spec), _Tiny)
    assert instantiate_model(f"zt-shadower:{name}", spec).origin == module
    [info] = _ours(plugins())
    assert info.status == "shadowed" and f"zt-shadower:{name}" in info.error


def test_clash_between_two_plugins_names_both_and_both_stay_reachable(site, spec, monkeypatch):
    name = unique("clash")
    mod_b = site.add("zt-beta", GOOD_MODULE, models={name: "Net"})
    mod_a = site.add("zt-alpha", GOOD_MODULE, models={name: "Net"})
    with pytest.warns(PluginWarning, match="zt-alpha.*zt-beta"):
        assert model_names("zt_clash*") == [f"zt-alpha:{name}", f"zt-beta:{name}"]
    with pytest.raises(PluginError, match="zt-alpha.*zt-beta"):
        get_model_entry(name)
    with pytest.raises(PluginError, match="zt-alpha.*zt-beta"):
        instantiate_model(name, spec)
    assert instantiate_model(f"zt-alpha:{name}", spec).origin == mod_a
    assert instantiate_model(f"zt-beta:{name}", spec).origin == mod_b
    assert [(i.dist, i.status) for i in _ours(plugins())] == [("zt-alpha", "clash"), ("zt-beta", "clash")]
    monkeypatch.setenv("TACTILE_ZOO_STRICT_PLUGINS", "1")
    with pytest.raises(PluginError, match="zt-alpha.*zt-beta"):
        model_names()


BROKEN_SOURCES = {
    "import": "import zt_no_such_dependency_xyz\n",
    "runtime": "raise RuntimeError('boom at import')\n",
    "syntax": "def broken(:\n",
}
BROKEN_CAUSES = {"import": "ModuleNotFoundError.*zt_no_such_dependency_xyz", "runtime": "RuntimeError: boom at import",
                 "syntax": "SyntaxError"}


@pytest.mark.parametrize("how", sorted(BROKEN_SOURCES))
def test_broken_plugin_is_skipped_with_a_warning_and_listed_as_failed(site, spec, how):
    good, broken = unique("fine"), unique("broken")
    local = unique("local")
    register_model(local)(lambda spec: _Tiny(spec))  # stands in for the built-ins
    site.add("zt-fine", GOOD_MODULE, models={good: "Net"})
    site.add("zt-broken", BROKEN_SOURCES[how], models={broken: "Net"})
    with pytest.warns(PluginWarning, match=f"zt-broken.*{BROKEN_CAUSES[how]}"):
        names = model_names()
    assert good in names and local in names and broken not in names and not model_names(f"*{broken}*")
    assert isinstance(instantiate_model(local, spec), _Tiny)
    assert isinstance(instantiate_model(good, spec), torch.nn.Module)
    status = {i.dist: (i.status, i.error) for i in _ours(plugins())}
    assert status["zt-fine"] == ("ok", None)
    assert status["zt-broken"][0] == "failed"
    assert status["zt-broken"][1].startswith(BROKEN_CAUSES[how].split(".*")[0])


def test_strict_plugins_makes_a_broken_plugin_fatal(site, monkeypatch):
    fine = unique("fine")
    site.add("zt-fine", GOOD_MODULE, models={fine: "Net"})
    site.add("zt-broken", BROKEN_SOURCES["import"], models={unique("broken"): "Net"})
    with pytest.warns(PluginWarning, match="zt-broken"):
        assert model_names("zt_fine*") == [fine]
    monkeypatch.setenv("TACTILE_ZOO_STRICT_PLUGINS", "1")  # the policy changed: discovered again, strictly
    with pytest.raises(PluginError, match="'zt-broken'.*ModuleNotFoundError.*zt_no_such_dependency_xyz"):
        model_names()
    with pytest.raises(PluginError, match="'zt-broken'"):  # an error, not a half-filled cache, the second time too
        get_model_entry(fine)
    monkeypatch.delenv("TACTILE_ZOO_STRICT_PLUGINS")
    with pytest.warns(PluginWarning, match="zt-broken"):  # lenient again: every good plugin is back
        assert model_names("zt_fine*") == [fine]
    assert [(i.dist, i.status) for i in _ours(plugins())] == [("zt-broken", "failed"), ("zt-fine", "ok")]


def test_strict_plugins_cli_flag(site, capsys):
    good = unique("fine")
    site.add("zt-fine", GOOD_MODULE, models={good: "Net"})
    site.add("zt-broken", BROKEN_SOURCES["import"], models={unique("broken"): "Net"})
    assert main(["--strict-plugins", "list", "models"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert err.startswith("tactile-zoo: error:") and "zt-broken" in err and "zt_no_such_dependency_xyz" in err
    assert main(["list", "models", "zt_fine*"]) == 0  # without the flag: a warning, and the rest works
    out, err = capsys.readouterr()
    assert out.startswith(good) and "warning" in err and "zt-broken" in err


def test_no_plugins_turns_discovery_off(site, monkeypatch, capsys):
    name = unique("off")
    module = site.add("zt-off", GOOD_MODULE, models={name: "Net"})
    monkeypatch.setenv("TACTILE_ZOO_NO_PLUGINS", "1")
    assert name not in model_names() and plugins() == [] and module not in sys.modules
    with pytest.raises(UnknownNameError):
        get_model_entry(name)
    monkeypatch.delenv("TACTILE_ZOO_NO_PLUGINS")
    assert name in model_names()  # on again: discovered under the new policy
    assert main(["--no-plugins", "list", "models", "zt_off*"]) == 0
    assert capsys.readouterr().out == ""
    assert main(["list", "models", "zt_off*"]) == 0
    assert capsys.readouterr().out.startswith(name)


def test_wrong_types_are_plugin_errors(site, spec, monkeypatch):
    not_callable, not_module, bad_meta = unique("notcallable"), unique("notmodule"), unique("badmeta")
    site.add("zt-wrong", """
        VALUE = 42

        def make(spec):
            return {"not": "a module"}

        def meta_typo(spec):
            return None

        meta_typo.zoo_meta = {"papr": "typo"}
    """, models={not_callable: "VALUE", not_module: "make", bad_meta: "meta_typo"})
    with pytest.warns(PluginWarning) as record:
        names = model_names("zt_*")
    messages = " ".join(str(w.message) for w in record)
    assert "not a class or callable" in messages and "papr" in messages
    assert not_module in names and not_callable not in names and bad_meta not in names
    status = {i.name: (i.status, i.error) for i in _ours(plugins())}
    assert status[not_callable][0] == "failed" and status[not_callable][1].startswith("PluginError")
    assert status[bad_meta][0] == "failed" and status[bad_meta][1].startswith("ConfigError")
    with pytest.raises(PluginError, match=r"'zt-wrong'.*dict, not a torch\.nn\.Module"):
        instantiate_model(not_module, spec)
    monkeypatch.setenv("TACTILE_ZOO_STRICT_PLUGINS", "1")
    with pytest.raises(PluginError, match="'zt-wrong'.*failed to load"):
        model_names()


def test_discovery_order_is_deterministic(site):
    z1, z2, a1 = unique("zulu_b"), unique("zulu_a"), unique("alpha")
    mod_z = site.add("zt-zulu", GOOD_MODULE, models={z1: "Net", z2: "Net"})
    site.add("zt-alpha", GOOD_MODULE, models={a1: "Net"}, datasets={unique("set"): "dataset"})
    first = [(i.dist, i.group, i.name) for i in _ours(plugins())]
    assert first == sorted(first) and [d for d, _, _ in first] == ["zt-alpha", "zt-alpha", "zt-zulu", "zt-zulu"]
    assert [n for d, g, n in first if d == "zt-zulu"] == sorted([z1, z2])
    assert model_names() == sorted(model_names())
    registry.reset_plugins()
    sys.modules.pop(mod_z)
    assert [(i.dist, i.group, i.name) for i in _ours(plugins())] == first
