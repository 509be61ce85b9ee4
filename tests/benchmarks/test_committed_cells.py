"""Committed Table I cells describe what the current code runs: the same resolved configuration and hash.

The cells under ``benchmarks/results/paper-table1`` were computed before cell hashes covered the code's revisions
(hash format 1) and re-keyed by ``python -m tools.check_cells --migrate`` after the check below passed; each
records its format-1 hash in ``migrated_from``. A change to a model's or dataset's code bumps its revision, and the
cells then fail here until they are rerun.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tactile_zoo.bench.grid import config_hash  # noqa: E402
from tools import check_cells  # noqa: E402

CELLS = sorted((REPO / "benchmarks" / "results" / "paper-table1" / "cells").glob("*.json")) + sorted(
    (REPO / "benchmarks" / "results" / "paper-table1-revision1" / "cells").glob("*.json"))  # stale: older code

pytestmark = pytest.mark.real_data


def test_there_are_committed_cells() -> None:
    assert len(CELLS) >= 24, "the Table I folder lost cells"


@pytest.mark.parametrize("path", CELLS, ids=lambda p: p.stem.rsplit("__", 1)[0])
def test_a_committed_cell_maps_to_its_configuration(path: Path, shared_data: Path) -> None:
    record = json.loads(path.read_text())
    status, why, current = check_cells.check(record, str(shared_data))
    assert status in ("maps", "stale"), f"{path.name}: {why}"
    if status == "stale":  # computed by an older revision of its model's code: reported, never taken as current
        assert any(record["config"][k] < current[k] for k in check_cells.REVISION_KEYS)
        assert record["config_hash"] != config_hash(current)
        return
    assert check_cells._without(current, ()) == check_cells._without(record["config"], ())  # key for key
    legacy = {k: v for k, v in current.items() if k not in (*check_cells.REVISION_KEYS, "recipe_name")}
    if "migrated_from" in record:  # computed before hash format 2 and re-keyed after this check
        assert record["migrated_from"]["config_hash"] == config_hash(legacy, hash_format=1)
    assert path.stem == record["cell_id"] and record["cell_id"].endswith(config_hash(current))


def test_a_newer_revision_makes_a_cell_stale_another_setting_a_mismatch(shared_data: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo import registry

    record = next(r for r in (json.loads(p.read_text()) for p in CELLS) if r["config"]["model_revision"] == 1)
    entry = registry.get_model_entry(record["model"])
    monkeypatch.setitem(registry._TABLES["model"].builtin, registry.normalize_name(entry.name),
                        registry.Entry(entry.kind, entry.name, entry.obj, {**entry.meta, "revision": 2}))
    assert check_cells.check(record, str(shared_data))[0] == "stale"
    monkeypatch.setitem(registry._TABLES["model"].builtin, registry.normalize_name(entry.name), entry)
    record = {**record, "config": {**record["config"], "recipe": {**record["config"]["recipe"], "lr": 0.5}}}
    status, why, _ = check_cells.check(record, str(shared_data))
    assert status == "differs" and "differs in ['recipe']" in why
