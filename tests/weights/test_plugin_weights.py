"""The weights distribution ``plugins/tactile-zoo-weights``, installed for real with pip (offline, into a temporary
``--target``, as tests/test_plugin_tcn.py does): the installed copy holds every file the manifest lists and the
expected logits (package data), tactile-zoo finds its entry point and its entries, and ``tactile-zoo weights`` lists
them. (That the entries are their cells' weights is tests/weights/test_shipped_weights.py's subject.)"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from weights_helpers import installed_weight_pack

from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.weights import MANIFEST_FORMAT, list_weights, read_manifest, weight_sources

pytestmark = pytest.mark.xdist_group("plugin_weights")

PLUGIN = Path(__file__).resolve().parents[2] / "plugins" / "tactile-zoo-weights"
SOURCE = read_manifest(PLUGIN / "tactile_zoo_weights" / "manifest.json")
VERSION = re.search(r'__version__ = "([^"]+)"', (PLUGIN / "tactile_zoo_weights" / "__init__.py").read_text())[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    with installed_weight_pack(PLUGIN, tmp_path_factory) as target:
        yield target


def test_the_installed_pack_holds_its_files_and_lists_its_entries(installed: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    folder = installed / "tactile_zoo_weights"
    manifest = folder / "manifest.json"
    assert json.loads(manifest.read_text())["format"] == MANIFEST_FORMAT
    assert read_manifest(manifest) == SOURCE  # the same entries (where they were read aside)
    shipped = {p.name for p in folder.iterdir() if p.is_file()}
    assert {e.file for e in SOURCE} | {"manifest.json", "expected_logits.json", "__init__.py"} <= shipped
    for entry in SOURCE:  # package data: byte for byte what the checkout holds
        assert (folder / entry.file).read_bytes() == (PLUGIN / "tactile_zoo_weights" / entry.file).read_bytes()
    (source,) = [s for s in weight_sources() if s.dist == "tactile-zoo-weights"]
    assert (source.version, source.name, source.value, source.status, source.count) == (
        VERSION, "manifest", "tactile_zoo_weights:manifest", "ok", len(SOURCE))
    installed_entries = list_weights()
    assert sorted(e.tag for e in installed_entries) == sorted(e.tag for e in SOURCE)
    assert {e.dist for e in installed_entries} == {"tactile-zoo-weights"}
    assert all(e.local_path().parent == folder.resolve() for e in installed_entries)
    registry.set_plugin_policy(strict=True)  # nothing in it is broken
    try:
        assert main(["weights"]) == 0
    finally:
        registry.set_plugin_policy()
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["tag", "model", "dataset"]
    rows = {line.split()[0]: line.split() for line in lines[1:] if line.startswith("tactile-zoo-weights:")}
    assert set(rows) == {f"tactile-zoo-weights:{e.tag}" for e in SOURCE}
    for entry in SOURCE:
        assert rows[f"tactile-zoo-weights:{entry.tag}"][1:4] == [entry.model, entry.dataset, f"{entry.accuracy:.4f}"]
    assert main(["plugins"]) == 0
    [row] = [line for line in capsys.readouterr().out.splitlines() if line.startswith("tactile-zoo-weights")]
    assert row.split()[:3] == ["tactile-zoo-weights", VERSION, "tactile_zoo.weights"]
    assert row.endswith(f"manifest = tactile_zoo_weights:manifest (entries: {len(SOURCE)})  [ok]")
