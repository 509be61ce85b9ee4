"""Installed weights: distributions faked on ``sys.path`` (``tests/fake_plugins.py``) that declare
``tactile_zoo.weights`` entry points. Discovery lists without importing, in a deterministic order; a broken
distribution is skipped with a warning naming it, or is an error under the strict policy; a tag two distributions
ship needs ``dist:tag``."""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from fake_plugins import FakeSite
from weights_helpers import DATASET, MODEL, Trained, sample_table

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.engine.evaluate import predict_scores
from tactile_zoo.errors import PluginError
from tactile_zoo.weights import discovery, find_weights, list_weights, weight_sources, write_manifest

TAG = "cnn_lstm.full_sim_uskin_textures"
FAST = "cnn_lstm.fast_sim_uskin_textures"


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeSite]:
    root = tmp_path / "site"
    root.mkdir()
    fake = FakeSite(root, monkeypatch)
    yield fake
    fake.close()


def _as_dict(trained: Trained, **changes: object) -> str:
    entry = dataclasses.replace(trained.entry, file=str(trained.file.resolve()), **changes)
    return json.dumps(entry.to_dict())


def _install_two(site: FakeSite, trained: Trained) -> tuple[str, str]:
    """``zz-weights``: a manifest path relative to its module; ``aa-weights``: a callable returning WeightEntry
    objects (another recipe's tag, the same file)."""
    write_manifest([dataclasses.replace(trained.entry, file=str(trained.file.resolve()))],
                   site.root / "zz_manifest.json")
    zz = site.add("zz-weights", 'MANIFEST = "zz_manifest.json"\n', weights={"manifest": "MANIFEST"}, version="2.0")
    aa = site.add("aa-weights", f"""
        import json
        from tactile_zoo.weights import WeightEntry

        def weights():
            return [WeightEntry.from_dict(json.loads({_as_dict(trained, tag=FAST, recipe='fast')!r}))]
        """, weights={"zoo": "weights"})
    return zz, aa


def test_discovery_lists_without_loading_in_a_deterministic_order(site: FakeSite, trained: Trained) -> None:
    zz, aa = _install_two(site, trained)
    found = [(src.dist, src.name, src.value) for src, _ in discovery._discover_entry_points()]
    assert found == [("aa-weights", "zoo", f"{aa}:weights"), ("zz-weights", "manifest", f"{zz}:MANIFEST")]
    assert zz not in sys.modules and aa not in sys.modules  # listing imports nothing
    entries = list_weights()
    assert [(e.tag, e.dist) for e in entries] == [(FAST, "aa-weights"), (TAG, "zz-weights")]  # sorted by tag
    assert [(s.dist, s.status, s.count) for s in weight_sources()] == [("aa-weights", "ok", 1),
                                                                      ("zz-weights", "ok", 1)]
    assert entries[1].origin == "zz-weights 2.0" and entries[1].qualified_tag == f"zz-weights:{TAG}"
    assert [e.tag for e in list_weights(MODEL, DATASET)] == [FAST, TAG] and list_weights("sgnet") == []


def test_installed_weights_by_dataset_tag_or_qualified_tag(site: FakeSite, trained: Trained,
                                                          capsys: pytest.CaptureFixture) -> None:
    _install_two(site, trained)
    by_dataset = tz.create_model(MODEL, pretrained=DATASET)  # two recipes: the model's default one ("full") wins
    assert by_dataset.zoo_pretrained.qualified_tag == f"zz-weights:{TAG}"
    assert torch.equal(predict_scores(by_dataset, trained.test.x, trained.test.g), trained.logits)
    assert tz.create_model(MODEL, pretrained=FAST.upper()).zoo_pretrained.dist == "aa-weights"
    assert tz.create_model(MODEL, pretrained=f"aa-weights:{FAST}").zoo_pretrained.recipe == "fast"
    with pytest.raises(registry.UnknownNameError, match=r"no installed weights of model 'cnn_lstm' for dataset "
                                                        r"'sim_evtouch'; installed for 'cnn_lstm': "):
        tz.create_model(MODEL, pretrained="sim_evtouch")
    with pytest.raises(registry.UnknownNameError, match="no installed weights tagged 'cnn_lstm.source_x'"):
        tz.create_model(MODEL, pretrained="cnn_lstm.source_x")
    assert main(["weights"]) == 0
    out = capsys.readouterr().out
    assert f"zz-weights:{TAG}" in out and f"aa-weights:{FAST}" in out and "zz-weights 2.0" in out
    assert "note (cnn_lstm.full_sim_uskin_textures): trained by the test suite" in out


def test_predict_and_stream_with_installed_weights(site: FakeSite, trained: Trained, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture) -> None:
    import numpy as np

    _install_two(site, trained)
    expected = tz.evaluate(trained.model, trained.test).predictions
    files = []
    for i in (0, 1, 2):
        np.save(tmp_path / f"s{i}.npy", sample_table(trained.test, i))
        files.append(str(tmp_path / f"s{i}.npy"))
    capsys.readouterr()
    assert main(["predict", MODEL, "--pretrained", DATASET, *files, "--json", "--top-k", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["weights"] == f"zz-weights:{TAG}" and out["dataset"] == DATASET
    assert [p["index"] for p in out["predictions"]] == expected[:3]
    assert all(len(p["top_k"]) == 2 for p in out["predictions"])
    assert main(["stream", MODEL, "--pretrained", TAG, "--index", "4", "--json"]) == 0  # the entry's dataset options
    trace = json.loads(capsys.readouterr().out)
    assert trace["weights"] == f"zz-weights:{TAG}" and trace["num_steps"] == 12
    assert trace["true_class"] == trained.test.spec.class_names[int(trained.test.y[4])]
    assert torch.allclose(torch.tensor(trace["final_scores"]), trained.logits[4], atol=1e-5)


def test_a_broken_distribution_is_skipped_with_a_warning_naming_it(site: FakeSite, trained: Trained,
                                                                   capsys: pytest.CaptureFixture) -> None:
    _install_two(site, trained)
    site.add("bb-broken", 'raise ImportError("the weights module is broken")\n', weights={"w": "WEIGHTS"})
    site.add("cc-bad-entry", f"WEIGHTS = [{{**__import__('json').loads({_as_dict(trained)!r}), 'sha256': 'no'}}]\n",
             weights={"w": "WEIGHTS"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        entries = list_weights()
    messages = [str(w.message) for w in caught if issubclass(w.category, registry.PluginWarning)]
    assert any("'bb-broken'" in m and "the weights module is broken" in m for m in messages)
    assert any("'cc-bad-entry'" in m and "sha256 must be 64 hexadecimal digits" in m for m in messages)
    assert [e.dist for e in entries] == ["aa-weights", "zz-weights"]  # the others still load (sorted by tag)
    status = {s.dist: s.status for s in weight_sources()}
    assert status == {"aa-weights": "ok", "bb-broken": "failed", "cc-bad-entry": "failed", "zz-weights": "ok"}
    registry.set_plugin_policy(strict=True)
    with pytest.raises(PluginError, match=r"weights distribution 'bb-broken' \(tactile_zoo.weights entry 'w' = "
                                          r".*\) failed to load: ImportError: the weights module is broken"):
        list_weights()
    registry.set_plugin_policy()
    capsys.readouterr()
    assert main(["--strict-plugins", "weights"]) == 2
    assert "weights distribution 'bb-broken'" in capsys.readouterr().err
    assert main(["weights"]) == 0
    assert "weights distribution bb-broken 1.0 failed to load" in capsys.readouterr().err
    assert main(["plugins"]) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()}
    assert rows["bb-broken"].split()[:3] == ["bb-broken", "1.0", "tactile_zoo.weights"]
    assert "[failed]  ImportError: the weights module is broken" in rows["bb-broken"]
    assert rows["zz-weights"].endswith("(entries: 1)  [ok]")


def test_a_tag_shipped_twice_needs_its_distribution_and_discovery_can_be_off(site: FakeSite, trained: Trained,
                                                                             capsys: pytest.CaptureFixture) -> None:
    for dist in ("dd-dup", "ee-dup"):
        site.add(dist, f"import json\nWEIGHTS = [json.loads({_as_dict(trained)!r})]\n", weights={"w": "WEIGHTS"})
    with pytest.raises(PluginError, match=f"shipped by several distributions; choose one of 'dd-dup:{TAG}', "
                                          f"'ee-dup:{TAG}'"):
        find_weights(TAG)
    assert find_weights(f"ee-dup:{TAG}").dist == "ee-dup"
    registry.set_plugin_policy(enabled=False)
    assert list_weights() == []
    assert main(["--no-plugins", "weights"]) == 0
    assert "weights discovery is disabled" in capsys.readouterr().out


def test_nothing_installed_says_so(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setattr(discovery, "_discover_entry_points", lambda: [])
    discovery.reset_weights()
    try:
        assert main(["weights"]) == 0
        out = capsys.readouterr().out
        assert out.startswith("no pretrained weights installed") and "pip install ./plugins/tactile-zoo-weights" in out
        missing = rf"no installed weights of model 'cnn_lstm' \(tag '{TAG}'\)"  # the default recipe's tag
        with pytest.raises(registry.UnknownNameError, match=missing):
            tz.create_model(MODEL, pretrained=DATASET)
    finally:
        discovery.reset_weights()


def test_an_installed_distribution_with_an_empty_manifest_says_it_ships_none(site: FakeSite,
                                                                             capsys: pytest.CaptureFixture) -> None:
    # what tactile-zoo-weights 0.1.0 was (plugins/tactile-zoo-weights now ships weights, tested in test_plugin_weights)
    write_manifest([], site.root / "empty_manifest.json")
    site.add("empty-weights", 'MANIFEST = "empty_manifest.json"\n', weights={"manifest": "MANIFEST"}, version="0.1.0")
    assert list_weights() == [] and [(s.dist, s.status, s.count) for s in weight_sources()] == [
        ("empty-weights", "ok", 0)]
    assert main(["weights"]) == 0
    assert capsys.readouterr().out.startswith("no pretrained weights yet: empty-weights 0.1.0 is installed, but its "
                                              "manifest lists none")


def test_one_finder_serves_the_plugins_and_the_weights(site: FakeSite, recwarn: pytest.WarningsRecorder) -> None:
    """The model/dataset plugins and the weights distributions are found by one finder: sorted by distribution
    (case and separators ignored), then group, then name, whatever order the groups are asked in; nothing imported;
    a failure to load names the distribution and its entry point in either group."""
    both = site.add("Bb-Both", "raise ImportError('broken on purpose')\n", models={"net": "X"}, weights={"w": "X"})
    other = site.add("aa-data", "def Y(**kwargs):\n    return None\n", datasets={"d": "Y"})
    groups = ["tactile_zoo.weights", "tactile_zoo.models", "tactile_zoo.datasets"]
    found = [(f.dist, f.group, f.name) for f in registry.find_entry_points(groups)
             if f.dist in {"Bb-Both", "aa-data"}]
    assert found == [("aa-data", "tactile_zoo.datasets", "d"), ("Bb-Both", "tactile_zoo.models", "net"),
                     ("Bb-Both", "tactile_zoo.weights", "w")]
    assert both not in sys.modules and other not in sys.modules
    assert [(s.dist, s.name) for s, _ in discovery._discover_entry_points()] == [("Bb-Both", "w")]
    registry.set_plugin_policy(strict=True)
    with pytest.raises(PluginError, match=r"^weights distribution 'Bb-Both' \(tactile_zoo.weights entry 'w' = "):
        list_weights()
    with pytest.raises(PluginError, match=r"^plugin distribution 'Bb-Both' \(tactile_zoo.models entry 'net' = "):
        registry.model_names()
    registry.set_plugin_policy()
