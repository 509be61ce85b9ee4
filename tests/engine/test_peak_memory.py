"""Peak memory where Linux's ``/proc`` is missing: the ``resource`` fallback, and neither (Windows)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tactile_zoo.engine import runtime
from tactile_zoo.engine.runtime import PeakMemory


@pytest.fixture
def no_proc(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # paths that cannot be read or written, as on a system without /proc
    monkeypatch.setattr(runtime, "_STATUS", tmp_path / "missing" / "status")
    monkeypatch.setattr(runtime, "_CLEAR_REFS", tmp_path / "missing" / "clear_refs")


def test_without_proc_the_peak_comes_from_getrusage(no_proc: None) -> None:
    with PeakMemory() as peak:
        pass
    assert peak.source == "ru_maxrss" and peak.mb is not None and peak.mb > 0


def test_without_proc_and_resource_the_block_runs_and_the_peak_is_unknown(no_proc: None,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "resource", None)  # `import resource` now raises ImportError, as on Windows
    ran = False
    with PeakMemory() as peak:
        ran = True
    assert ran and peak.mb is None and peak.source == "unavailable"
