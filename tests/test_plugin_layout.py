"""The plugin layout docs/plugins.md recommends builds quietly: the example distributions under ``plugins/`` build a
wheel without setuptools' "Package would be ignored" warning (the TCN's recipes folder, data inside the package, was
left out of ``packages``), and the wheel still carries the recipe file (issue 49, item 15)."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PLUGINS = sorted(p.parent for p in (REPO / "plugins").glob("*/pyproject.toml"))


def _build_wheel(plugin: Path, work: Path) -> tuple[Path, str]:
    """Build ``plugin``'s wheel offline from a copy (building in place would leave build/ and *.egg-info behind);
    returns the wheel and everything the build printed."""
    if importlib.util.find_spec("build") is None or importlib.util.find_spec("setuptools") is None:
        pytest.skip("needs build and setuptools (the test extras): pip install -e '.[test]'")
    source = work / "src"
    shutil.copytree(plugin, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    proc = subprocess.run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(work / "dist"),
                           str(source)], capture_output=True, text=True, timeout=600)
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output
    [wheel] = (work / "dist").glob("*.whl")
    return wheel, output


@pytest.mark.parametrize("plugin", PLUGINS, ids=[p.name for p in PLUGINS])
def test_the_example_plugins_build_without_package_warnings(plugin: Path, tmp_path: Path) -> None:
    wheel, output = _build_wheel(plugin, tmp_path)
    assert "Package would be ignored" not in output
    assert "is absent from the `packages` configuration" not in output
    names = zipfile.ZipFile(wheel).namelist()
    project = tomllib.loads((plugin / "pyproject.toml").read_text())
    for package, patterns in project["tool"]["setuptools"].get("package-data", {}).items():
        for pattern in patterns:  # every package-data file in the source is in the wheel
            for path in (plugin / package.replace(".", "/")).glob(pattern):
                assert path.relative_to(plugin).as_posix() in names, path


def test_the_documented_layout_is_the_examples() -> None:
    """docs/plugins.md shows the TCN's [tool.setuptools] tables: they must be the ones that build quietly."""
    [block] = [b for b in re.findall(r"```toml\n(.*?)```", (REPO / "docs" / "plugins.md").read_text(), flags=re.S)
               if "[tool.setuptools]" in b]
    shown = tomllib.loads(block)["tool"]["setuptools"]
    real = tomllib.loads((REPO / "plugins" / "tactile-zoo-tcn" / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert shown["packages"] == real["packages"]
    assert shown["package-data"] == real["package-data"]
