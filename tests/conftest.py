"""Shared test set-up: one torch thread per worker, a private cache directory, and the real-data home."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TACTILE_ZOO_SHARED_DATA", REPO.parent / "shared" / "data"))

torch.set_num_threads(1)  # pytest-xdist runs one worker per core


def _xdist_group(item: pytest.Item) -> str | None:
    """The group ``--dist loadgroup`` sends to one worker: the item's ``xdist_group`` names, sorted and joined by
    ``_`` (as pytest-xdist names them)."""
    names = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                    for m in item.iter_markers("xdist_group")})
    return "_".join(names) or None


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """``--dist loadgroup`` groups again under pytest 9.2: pytest-xdist (3.8) names a test's group by appending
    ``@group`` to its node id through the attribute ``_nodeid``, which pytest 9.2's structured node ids no longer
    read, so every ``xdist_group`` mark was silently ignored (pytest-dev/pytest-xdist#1386): a module's fixtures
    (an export, the docs site, an installed plugin) were made again on each worker that ran one of its tests, and the
    blocks of a documentation page ran on either worker, in any order. A worker's test whose id has no group yet gets
    it here, in the structured id; with a pytest whose ``_nodeid`` still works, pytest-xdist has added it already."""
    if not getattr(config.option, "loadgroup", False):
        return
    for item in items:
        group = _xdist_group(item)
        if group and "@" not in item.nodeid.rpartition("]")[2] and hasattr(item, "_id"):
            item._id = type(item._id).parse(f"{item.nodeid}@{group}")


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Processed caches go to a throw-away folder: tests never write into ~/.cache or the shared data home."""
    os.environ["TACTILE_ZOO_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    os.environ.pop("TACTILE_ZOO_DATA", None)


#: (path, digest of the plain bytes) of every cell file read_record found valid in this process
_VALID_CELLS: set[tuple[str, bytes]] = set()


@pytest.fixture
def cells_checked_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``read_record`` checks each cell file's contents once per worker: tests that run a results generator several
    times over the committed cells (hundreds of files, most of its time in the schema check, which reads the record
    alone) skip re-checking bytes already found valid at that path; changed bytes are read and checked again."""
    from tactile_zoo.bench import records

    real = records.read_record

    def read_record(path: str | os.PathLike) -> object:
        path = Path(path)
        try:
            data = records.read_cell_bytes(path) if path.is_file() else None
        except Exception:  # unreadable or damaged: the real reader says why
            data = None
        key = None if data is None else (str(path.resolve()), hashlib.blake2b(data).digest())
        if key in _VALID_CELLS:
            return json.loads(data.decode("utf-8"))
        result = real(path)
        if key is not None and isinstance(result, dict):
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
