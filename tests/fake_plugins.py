"""Fake plugin distributions for the registry and CLI tests.

A distribution is what ``importlib.metadata`` finds on ``sys.path``: a ``<name>-<version>.dist-info`` folder holding
``METADATA`` and ``entry_points.txt``, next to the module its entry points name. :class:`FakeSite` writes such
distributions into a temporary folder that the test puts on ``sys.path``, and forgets discovered plugins so the next
registry call discovers them. Module names get a random suffix, so no two tests share a cached module.
"""

from __future__ import annotations

import importlib
import re
import sys
import textwrap
import uuid
from pathlib import Path

import pytest
from plugin_install import only_weights_from

from tactile_zoo import registry
from tactile_zoo.weights import reset_weights

#: Prefix of every name the tests register, so a fixture can remove their local registrations afterwards.
PREFIX = "zt_"


def unique(stem: str) -> str:
    """A fresh snake_case name ``zt_<stem>_<8 hex>``."""
    return f"{PREFIX}{stem}_{uuid.uuid4().hex[:8]}"


class FakeSite:
    """A folder on ``sys.path`` into which tests install fake plugin distributions."""

    def __init__(self, root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        self.root = root
        self.modules: list[str] = []
        monkeypatch.delenv("TACTILE_ZOO_NO_PLUGINS", raising=False)
        monkeypatch.delenv("TACTILE_ZOO_STRICT_PLUGINS", raising=False)
        monkeypatch.syspath_prepend(str(root))
        only_weights_from(monkeypatch, root)  # weight packs installed in the environment stay out of sight
        registry.set_plugin_policy()
        registry.reset_plugins()
        reset_weights()

    def add(self, dist: str, source: str, *, models: dict[str, str] | None = None,
            datasets: dict[str, str] | None = None, weights: dict[str, str] | None = None, version: str = "1.0"
            ) -> str:
        """Install distribution ``dist`` whose module holds ``source``; ``models``/``datasets``/``weights`` map
        entry-point names to attributes of that module. Returns the module's name."""
        module = f"{PREFIX}mod_{re.sub(r'[^a-z0-9]', '_', dist.lower())}_{uuid.uuid4().hex[:8]}"
        (self.root / f"{module}.py").write_text(textwrap.dedent(source))
        info = self.root / f"{re.sub(r'[-.]+', '_', dist)}-{version}.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
        lines = []
        for group, entries in (("tactile_zoo.models", models), ("tactile_zoo.datasets", datasets),
                               ("tactile_zoo.weights", weights)):
            if entries:
                lines += [f"[{group}]"] + [f"{name} = {module}:{attr}" for name, attr in entries.items()] + [""]
        (info / "entry_points.txt").write_text("\n".join(lines))
        self.modules.append(module)
        importlib.invalidate_caches()
        registry.reset_plugins()
        reset_weights()
        return module

    def close(self) -> None:
        for module in self.modules:
            sys.modules.pop(module, None)
        registry.set_plugin_policy()
        registry.reset_plugins()  # the folder leaves sys.path with monkeypatch; the next lookup discovers again
        reset_weights()


def forget_test_registrations(before: dict[str, set[str]]) -> None:
    """Remove the ``zt_`` names registered locally since ``before`` (a :func:`snapshot`)."""
    for kind, keys in snapshot().items():
        for key in keys - before[kind]:
            if key.startswith(registry.normalize_name(PREFIX)):
                registry._unregister(kind, key)


def snapshot() -> dict[str, set[str]]:
    """The normalised names of the local (non-plugin) registrations of every kind."""
    return {kind: set(table.builtin) for kind, table in registry._TABLES.items()}


#: A plugin module with one model class and one model factory, both usable on any spec.
GOOD_MODULE = """
    import torch

    class Net(torch.nn.Module):
        zoo_meta = {"paper": "A fake paper", "year": 2024, "tags": ["convolutional"], "inputs": [],
                    "recipe": {"loss": "ce", "optimizer": "adam", "lr": 0.001}}

        def __init__(self, spec, width=4):
            super().__init__()
            self.width = width
            self.origin = __name__
            self.lin = torch.nn.Linear(spec.num_nodes * spec.num_channels, spec.num_classes)

        def forward(self, x, g=None):
            return self.lin(x.mean(1).flatten(1))

    def dataset(root=None, split=None, fold=0, download=False, **kwargs):
        return None
"""
