"""Shared test set-up: one torch thread per worker, a private cache directory, and the real-data home."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TACTILE_ZOO_SHARED_DATA", REPO.parent / "shared" / "data"))

torch.set_num_threads(1)  # pytest-xdist runs one worker per core


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Processed caches go to a throw-away folder: tests never write into ~/.cache or the shared data home."""
    os.environ["TACTILE_ZOO_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    os.environ.pop("TACTILE_ZOO_DATA", None)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The read-only data home with the real Ev-Objects / Ev-Containers zips; skips when it is absent."""
    if not (SHARED_DATA / "ev_objects" / "raw" / "Ev-Objects.zip").exists():
        pytest.skip(f"real data home not found at {SHARED_DATA} (expected ev_objects/raw/Ev-Objects.zip); "
                    f"set TACTILE_ZOO_SHARED_DATA to run the real-data tests")
    return SHARED_DATA
