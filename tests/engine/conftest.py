"""The tiny zoo (tests/tiny_zoo.py) is registered for each engine test and removed afterwards."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import tiny_zoo


@pytest.fixture(autouse=True)
def tiny() -> Iterator[None]:
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()
