"""Reliability tests: the tiny zoo and the fault models registered around each test (see fault_zoo.py)."""

from __future__ import annotations

from collections.abc import Iterator

import fault_zoo
import pytest
import tiny_zoo


@pytest.fixture(autouse=True)
def tiny_and_faulty() -> Iterator[None]:
    tiny_zoo.register()
    fault_zoo.register()
    yield
    fault_zoo.unregister()
    tiny_zoo.unregister()


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    """The small grid (reliability_helpers.SMALL) run once, uninterrupted, in this process."""
    from reliability_helpers import quiet_bench

    tiny_zoo.register()
    fault_zoo.register()
    out = tmp_path_factory.mktemp("reliability_reference") / "run"
    outcome, _, err = quiet_bench(out)
    assert outcome.exit_code == 0, err
    return out
