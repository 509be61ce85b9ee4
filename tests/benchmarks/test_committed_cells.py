"""Committed cells describe what the current code runs: the same resolved configuration and hash.

Every committed record's stored ``config`` hashes to its ``config_hash`` with today's configuration code, and the
Table I cells of the ``full`` and ``zoo`` recipes resolve from their command-line settings alone (model, dataset,
recipe name, the declared evaluation) to the committed hashes (no data needed for either).

The cells under ``benchmarks/results/paper-table1`` were computed before cell hashes covered the code's revisions
(hash format 1) and re-keyed by ``python -m tools.check_cells --migrate`` after the check below passed; each
records its format-1 hash in ``migrated_from``. A change to a model's or dataset's code bumps its revision, and the
cells then fail here until they are rerun.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tactile_zoo.bench.config import BenchConfig, plan_cells  # noqa: E402
from tactile_zoo.bench.records import cell_files, read_cell_bytes, recipe_name_of  # noqa: E402
from tactile_zoo.engine.config import config_hash  # noqa: E402
from tools import check_cells  # noqa: E402

CELLS = cell_files(REPO / "benchmarks" / "results" / "paper-table1") + cell_files(
    REPO / "benchmarks" / "results" / "paper-table1-revision1")  # stale: older code
RESULTS = REPO / "benchmarks" / "results"
#: every committed record, in every bench folder under benchmarks/results
EVERY = cell_files(RESULTS, recursive=True)
#: the Table I folders whose every cell is resolved from its command-line settings below
TABLE1 = ("paper-table1-full", "paper-table1-zoo")


#: what a record's top-level keys needed here are (it keeps them before its predictions, most of its bytes)
HEAD = ("cell_id", "model", "dataset", "config_hash", "config")
_SPACE = re.compile(r"[ \t\n\r]*")


def read_head(path: Path, keys: tuple[str, ...] = HEAD) -> dict[str, Any]:
    """The top-level ``keys`` of the cell record at ``path``, decoded pair by pair up to the last of them (decoding
    each record whole, predictions and probabilities, was half the hash check's time); a key the record lacks is a
    KeyError."""
    text, scan = read_cell_bytes(path).decode("utf-8"), json.JSONDecoder().scan_once
    at, found = _SPACE.match(text, text.index("{") + 1).end(), {}
    while not found.keys() >= set(keys):
        if text[at] == "}":
            raise KeyError(f"{path.name}: no {sorted(set(keys) - found.keys())}")
        key, at = scan(text, at)
        at = _SPACE.match(text, at).end()
        assert text[at] == ":", (path.name, key)
        found[key], at = scan(text, _SPACE.match(text, at + 1).end())
        at = _SPACE.match(text, at).end()
        at = _SPACE.match(text, at + 1).end() if text[at] == "," else at
    return found


def test_every_committed_record_hashes_to_its_config_hash() -> None:
    assert len(EVERY) >= 480, "committed cell records went missing"
    wrong = []
    for path in EVERY:
        record = read_head(path, ("config_hash", "config"))
        stored = record["config"]
        # hash format 1 predates the revisions in the configuration (records not migrated keep it)
        form = 2 if all(k in stored for k in check_cells.REVISION_KEYS) else 1
        if config_hash(stored, hash_format=form) != record["config_hash"]:
            wrong.append(path.relative_to(RESULTS).as_posix())
    assert wrong == []
    changed = {**stored, "recipe": {**stored["recipe"], "lr": stored["recipe"]["lr"] * 2}}
    assert config_hash(changed, hash_format=form) != record["config_hash"]  # a changed setting is a new hash


def _from_cli_settings(record: dict, recipe: str | None = None, revision: int | None = None) -> str:
    """The hash ``tactile-zoo bench --models M --datasets D --recipe R --model-revision M=N`` gives the record's cell
    today (BioTac-DoS with its ``--dataset-arg validation=...``, as the Table I commands ran it; ``N``: the revision
    the record names, replayed)."""
    stored, model, dataset = record["config"], record["model"], record["dataset"]
    kwargs = {k: v for k, v in stored["dataset_kwargs"].items() if k == "validation"}
    config = BenchConfig(models=[model], datasets=[dataset], recipe_name=recipe or recipe_name_of(stored),
                         dataset_kwargs={dataset: kwargs} if kwargs else {},
                         model_revisions={model: revision or stored["model_revision"]})
    return config_hash(plan_cells(config, [model], [dataset]).configs[model, dataset])


@pytest.mark.parametrize("folder", TABLE1)
def test_table1_cells_resolve_from_their_command_line_settings(folder: str) -> None:
    records = [read_head(p) for p in cell_files(RESULTS / folder)]
    assert len(records) >= 80
    assert [r["cell_id"] for r in records if _from_cli_settings(r) != r["config_hash"]] == []
    full = next(r for r in records if recipe_name_of(r["config"]) == "full") if folder.endswith("full") else None
    if full is not None:  # another recipe's settings give another hash: the check can fail
        assert _from_cli_settings(full, recipe="zoo") != full["config_hash"]


def test_a_cell_of_an_older_revision_resolves_at_it_and_the_default_hashes_apart() -> None:
    """SGnet's Table I cells ran revision 2 (the dense products); the default is now revision 3, so today's plain
    command plans another cell (no silent pooling) and ``--model-revision sgnet=2`` plans the committed one."""
    from tactile_zoo import registry

    record = next(r for r in map(read_head, cell_files(RESULTS / "paper-table1-full")) if r["model"] == "sgnet")
    assert record["config"]["model_revision"] == 2 < registry.revision_of(registry.get_model_entry("sgnet"))
    assert _from_cli_settings(record) == record["config_hash"]
    assert _from_cli_settings(record, revision=3) != record["config_hash"]


def test_there_are_committed_cells() -> None:
    assert len(CELLS) >= 24, "the Table I folder lost cells"


@pytest.mark.real_data
@pytest.mark.parametrize("path", CELLS, ids=lambda p: p.name.rsplit("__", 1)[0])
def test_a_committed_cell_maps_to_its_configuration(path: Path, shared_data: Path) -> None:
    record = json.loads(read_cell_bytes(path))
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
    assert path.name.removesuffix(".gz").removesuffix(".json") == record["cell_id"]
    assert record["cell_id"].endswith(config_hash(current))


@pytest.mark.real_data
def test_a_newer_revision_makes_a_cell_stale_another_setting_a_mismatch(shared_data: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo import registry

    record = next(r for r in (json.loads(read_cell_bytes(p)) for p in CELLS) if r["config"]["model_revision"] == 1)
    entry = registry.get_model_entry(record["model"])
    monkeypatch.setitem(registry._TABLES["model"].builtin, registry.normalize_name(entry.name),
                        registry.Entry(entry.kind, entry.name, entry.obj, {**entry.meta, "revision": 2}))
    assert check_cells.check(record, str(shared_data))[0] == "stale"
    monkeypatch.setitem(registry._TABLES["model"].builtin, registry.normalize_name(entry.name), entry)
    record = {**record, "config": {**record["config"], "recipe": {**record["config"]["recipe"], "lr": 0.5}}}
    status, why, _ = check_cells.check(record, str(shared_data))
    assert status == "differs" and "differs in ['recipe']" in why
