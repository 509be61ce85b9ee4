"""The weights distribution ``plugins/tactile-zoo-weights``, installed for real with pip (offline, into a temporary
``--target``, as tests/test_plugin_tcn.py does): tactile-zoo finds its entry point and its (empty) manifest, and
``tactile-zoo weights`` says that no weights are shipped yet."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from plugin_install import pip_install

from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.weights import MANIFEST_FORMAT, list_weights, read_manifest, reset_weights, weight_sources

pytestmark = pytest.mark.xdist_group("plugin_weights")

PLUGIN = Path(__file__).resolve().parents[2] / "plugins" / "tactile-zoo-weights"


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    target = pip_install(PLUGIN, tmp_path_factory.mktemp("weights_plugin"))
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("TACTILE_ZOO_NO_PLUGINS", raising=False)
        mp.delenv("TACTILE_ZOO_STRICT_PLUGINS", raising=False)
        mp.syspath_prepend(str(target))
        reset_weights()
        yield target
        sys.modules.pop("tactile_zoo_weights", None)
    reset_weights()


def test_the_installed_skeleton_is_found_and_ships_an_empty_manifest(installed: Path,
                                                                     capsys: pytest.CaptureFixture) -> None:
    manifest = installed / "tactile_zoo_weights" / "manifest.json"
    assert json.loads(manifest.read_text())["format"] == MANIFEST_FORMAT and read_manifest(manifest) == []
    (source,) = [s for s in weight_sources() if s.dist == "tactile-zoo-weights"]
    assert (source.version, source.name, source.value, source.status, source.count) == (
        "0.1.0", "manifest", "tactile_zoo_weights:manifest", "ok", 0)
    assert list_weights() == []
    registry.set_plugin_policy(strict=True)  # nothing in it is broken
    try:
        assert main(["weights"]) == 0
    finally:
        registry.set_plugin_policy()
    out = capsys.readouterr().out
    assert out.startswith("no pretrained weights yet: tactile-zoo-weights 0.1.0 is installed, but its manifest lists "
                          "none")
    assert main(["plugins"]) == 0
    [row] = [line for line in capsys.readouterr().out.splitlines() if line.startswith("tactile-zoo-weights")]
    assert row.split()[:3] == ["tactile-zoo-weights", "0.1.0", "tactile_zoo.weights"]
    assert row.endswith("manifest = tactile_zoo_weights:manifest (entries: 0)  [ok]")
