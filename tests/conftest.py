"""Shared test set-up: one torch thread per worker, a private cache directory, and the real-data home."""

from __future__ import annotations

import json
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


#: (path, mtime, size, inode) of every cell file read_record found valid in this process
_VALID_CELLS: set[tuple[str, int, int, int]] = set()


@pytest.fixture
def cells_checked_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``read_record`` checks each unchanged cell file once per worker: tests that run a results generator several
    times over the committed cells (hundreds of files, most of its time in the schema check) skip re-checking a file
    already found valid; a changed file (new mtime, size or inode) is read and checked again."""
    from tactile_zoo.bench import records

    real = records.read_record

    def read_record(path: str | os.PathLike) -> object:
        path = Path(path)
        try:
            stat = path.stat()
        except OSError:
            return real(path)
        key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size, stat.st_ino)
        if key in _VALID_CELLS and path.is_file():
            return json.loads(records.read_cell_bytes(path).decode("utf-8"))
        result = real(path)
        if isinstance(result, dict):
            _VALID_CELLS.add(key)
        return result

    monkeypatch.setattr(records, "read_record", read_record)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The read-only data home with the real Ev-Objects / Ev-Containers zips; skips when it is absent."""
    if not (SHARED_DATA / "ev_objects" / "raw" / "Ev-Objects.zip").exists():
        pytest.skip(f"real data home not found at {SHARED_DATA} (expected ev_objects/raw/Ev-Objects.zip); "
                    f"set TACTILE_ZOO_SHARED_DATA to run the real-data tests")
    return SHARED_DATA
