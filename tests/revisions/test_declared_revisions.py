"""Every built-in model and dataset declares its computational ``revision`` in its registry metadata, rather than
falling back on ``registry.DEFAULT_REVISION`` (issue 49, item 15: ``deeptactile`` declared none).

The declared value is the one its committed cells were hashed with: a cell's ``model_revision`` is part of its config
hash, so declaring another value would orphan every committed cell of the model (``test_committed_cells.py`` checks
the hashes themselves; ``test_revisions.py`` that the recorded outputs belong to the revision).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import regenerate as rg  # tests/revisions is on sys.path, as every test folder's own helpers are (no __init__.py)

import tactile_zoo
from tactile_zoo import registry

REPO = Path(__file__).resolve().parents[2]
BUILTIN_MODELS = rg.builtin_models()
BUILTIN_DATASETS = [name for name in tactile_zoo.list_datasets()
                    if getattr(registry.get_dataset_entry(name).obj, "__module__", "").startswith("tactile_zoo.")]


@pytest.mark.parametrize("name", BUILTIN_MODELS)
def test_every_builtin_model_declares_its_revision(name: str) -> None:
    assert "revision" in registry.get_model_entry(name).meta, f"{name}: add revision=N to its register_model call"


@pytest.mark.parametrize("name", BUILTIN_DATASETS)
def test_every_builtin_dataset_declares_its_revision(name: str) -> None:
    assert "revision" in registry.get_dataset_entry(name).meta, f"{name}: add revision=N to its register_dataset call"


def test_deeptactiles_declared_revision_is_the_one_its_committed_cells_carry() -> None:
    from tactile_zoo.bench.records import cell_files, read_cell_bytes

    folder = REPO / "benchmarks" / "results" / "deeptactile"
    cells = [p for p in cell_files(folder) if p.name.startswith("deeptactile__")]
    assert cells
    carried = {json.loads(read_cell_bytes(path))["config"]["model_revision"] for path in cells}
    assert carried == {registry.get_model_entry("deeptactile").meta["revision"]}
    assert rg.load_expected()["models"]["deeptactile"]["revision"] == registry.revision_of(
        registry.get_model_entry("deeptactile"))
