"""Installing a distribution of ``plugins/`` for real, offline, the way a user's ``pip install`` would.

pip builds it with the test environment's setuptools (``--no-index --no-deps --no-build-isolation``) into a
temporary ``--target`` folder, which the caller puts on ``sys.path``: entry points then come from the plugin's own
``pyproject.toml`` and the code from the installed copy. The source is copied first, because building in place would
leave ``build/`` and ``*.egg-info`` in the repository.

:func:`installed_once` installs each distribution once per test run, whatever the number of modules that use it and
of xdist workers: the weight pack is 54 MB, which pip copies, zips into a wheel and unpacks again on every install.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from filelock import FileLock  # a dependency of torch


def pip_install(plugin: Path, work: Path) -> Path:
    """Install ``plugin`` (a distribution folder) under ``work``; returns the ``--target`` folder."""
    assert importlib.util.find_spec("setuptools") is not None, \
        "building the plugin offline needs setuptools in the test environment: pip install -e '.[test]'"
    source, target = work / "src", work / "site"
    shutil.copytree(plugin, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-index", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", "--no-input", "--quiet", "--target", str(target), str(source),
         # the wheel pip builds and unpacks at once is stored, not deflated: the same files installed, a CPU-second
         # less for the 54 MB weight pack
         "--config-settings=--build-option=--compression=stored"],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"pip could not install {plugin}:\n{proc.stdout}\n{proc.stderr}"
    return target


def installed_once(plugin: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``plugin`` installed by :func:`pip_install` once per test run, in the run's temporary folder (shared by the
    xdist workers, the others waiting on a lock); returns the ``--target`` folder. Callers only read it."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # the run's folder above the workers'
    work = root / f"installed-{plugin.name}"
    with FileLock(str(root / f"installed-{plugin.name}.lock")):
        done = work / "installed"
        if not done.is_file():
            shutil.rmtree(work, ignore_errors=True)  # a try that failed half way
            work.mkdir()
            pip_install(plugin, work)
            done.touch()
    return work / "site"


def only_weights_from(monkeypatch: pytest.MonkeyPatch, site: Path) -> None:
    """Let weights discovery see only the distributions installed under ``site``.

    A developer may have ``plugins/tactile-zoo-weights`` (or another pack) installed in the environment the suite runs
    in; tests that assert exactly which packs are found must not see it. Only the ``tactile_zoo.weights`` group is
    filtered: model and dataset plugins are discovered as usual.
    """
    real = importlib.metadata.entry_points
    site = site.resolve()

    def entry_points(**params: Any) -> importlib.metadata.EntryPoints:
        found = real(**params)
        if params.get("group") != "tactile_zoo.weights":
            return found
        return importlib.metadata.EntryPoints(
            ep for ep in found if ep.dist is not None and Path(ep.dist.locate_file("")).resolve() == site)

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
