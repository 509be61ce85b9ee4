"""The shape of the tree, checked: no import circle (function-level imports included), so every module can be read
and tested below the ones that use it."""

from __future__ import annotations

import re
from pathlib import Path

import grimp
import networkx as nx
import pytest


def import_cycles(*packages: str) -> list[list[str]]:
    """Every set of modules that import each other, directly or around a loop (strongly connected components of the
    import graph, ``import`` statements inside functions included)."""
    graph = grimp.build_graph(*packages, include_external_packages=False)
    edges = nx.DiGraph((m, n) for m in graph.modules for n in graph.find_modules_directly_imported_by(m))
    return sorted(sorted(c) for c in nx.strongly_connected_components(edges) if len(c) > 1)


@pytest.mark.parametrize("packages", [("tactile_zoo",), ("benchmarks", "tools")])
def test_no_import_circle(packages: tuple[str, ...]) -> None:
    assert import_cycles(*packages) == []


def test_a_circle_is_found(tmp_path, monkeypatch) -> None:
    """The check itself: two modules that import each other inside functions form a circle."""
    pkg = tmp_path / "zt_circle"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from . import b\n    return b\n")
    (pkg / "b.py").write_text("def g():\n    from .a import f\n    return f\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert import_cycles("zt_circle") == [["zt_circle.a", "zt_circle.b"]]


#: the longest a module of the package may grow: past it, a module holds more than one concept
MAX_MODULE_LINES = 450
PACKAGE = Path(__file__).resolve().parents[1] / "tactile_zoo"


def long_modules(root: Path, limit: int = MAX_MODULE_LINES) -> list[str]:
    return sorted(f"{p.relative_to(root)}: {n} lines" for p in root.rglob("*.py")
                  if (n := len(p.read_text().splitlines())) > limit)


def test_no_module_of_the_package_is_over_450_lines() -> None:
    assert long_modules(PACKAGE) == []


def test_a_long_module_is_found(tmp_path: Path) -> None:
    (tmp_path / "short.py").write_text("x = 1\n" * 450)
    (tmp_path / "long.py").write_text("x = 1\n" * 451)
    assert long_modules(tmp_path) == ["long.py: 451 lines"]


#: the one module that knows where a bench folder keeps its cell files
RECORDS = PACKAGE / "bench" / "records.py"


def cell_globs(*roots: Path) -> list[str]:
    """Every line outside the records module that globs for cell files (a ``glob``/``rglob`` call on a line that
    names ``cells``): each such line is a second reader of the records, which ``tactile_zoo.bench.records`` is for."""
    hits = []
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            if path.resolve() == RECORDS.resolve():
                continue
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if re.search(r"\br?glob\(", line) and "cells" in line:
                    hits.append(f"{path.relative_to(root.parent)}:{number}")
    return hits


def test_cell_files_are_read_through_the_records_module_only() -> None:
    repo = PACKAGE.parent
    assert cell_globs(PACKAGE, repo / "benchmarks", repo / "tools") == []


def test_a_cell_glob_is_found(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "ok.py").write_text('progress = sorted(folder.glob("*.json"))\n')
    (tmp_path / "pkg" / "reader.py").write_text('records = sorted((run / "cells").glob("*.json"))\n')
    assert cell_globs(tmp_path / "pkg") == ["pkg/reader.py:1"]
