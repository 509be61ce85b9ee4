"""``--dist loadgroup`` (``make test``) sends the tests of one ``xdist_group`` to one worker: tests/conftest.py
names the group in the node id where pytest-xdist's own way no longer reaches pytest 9.2's structured ids
(pytest-dev/pytest-xdist#1386). Without it every group mark was silently ignored: module fixtures were made on both
workers, and a documentation page's blocks ran on either worker in any order."""

from __future__ import annotations

import copy
import types
from pathlib import Path

import pytest
from xdist.scheduler.loadgroup import LoadGroupScheduling

CONFTEST = Path(__file__).resolve().parent / "conftest.py"


def _scope(nodeid: str) -> str:
    """The work unit pytest-xdist's loadgroup scheduler puts ``nodeid`` in."""
    return LoadGroupScheduling._split_scope(None, nodeid)  # type: ignore[arg-type]  # reads only the nodeid


def _grouped(request: pytest.FixtureRequest, *groups: str, loadgroup: bool = True) -> pytest.Item:
    """A copy of this test's item with ``groups`` marked, after the root conftest's collection hook."""
    item = copy.copy(request.node)
    item.own_markers = [*item.own_markers, *(pytest.mark.xdist_group(g).mark for g in groups)]
    config = types.SimpleNamespace(option=types.SimpleNamespace(loadgroup=loadgroup))
    request.config.pluginmanager.get_plugin(str(CONFTEST)).pytest_collection_modifyitems(config, [item])
    return item


def test_a_marked_test_is_scheduled_in_its_group(request: pytest.FixtureRequest) -> None:
    item = _grouped(request, "docs")
    assert _scope(item.nodeid) == "docs", item.nodeid
    assert _scope(_grouped(request, "b", "a").nodeid) == "a_b"  # several marks: one group, as pytest-xdist joins them
    assert _scope(request.node.nodeid.split("@")[0]) == request.node.nodeid.split("@")[0]  # unmarked: alone
    assert _scope(_grouped(request, "docs", loadgroup=False).nodeid) != "docs"  # other --dist modes: ids untouched
    again = _grouped(request, "docs")
    request.config.pluginmanager.get_plugin(str(CONFTEST)).pytest_collection_modifyitems(
        types.SimpleNamespace(option=types.SimpleNamespace(loadgroup=True)), [again])
    assert again.nodeid.count("@docs") == 1  # named once, whoever named it first
