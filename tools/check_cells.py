"""Do committed cells still describe what the current code would run? Check, and re-key them to the current hash.

For every cell record in a bench folder this rebuilds the cell through the harness's own grid
(:func:`tactile_zoo.bench.build_grid`) with the record's settings, then checks:

1. the resolved configuration is the record's, key for key (the computational revisions aside when the record
   predates them);
2. the record's hash is the hash of that configuration in the record's hash format (format 1 hashed it without the
   revisions, format 2 with them).

A cell that passes was computed by what the current code computes (revision 1 is the code that produced
hash-format-1 cells); a cell of an older model revision that the model still builds (registry metadata
``revisions``) is rebuilt at that revision, so it passes too. A cell whose model or dataset has since been bumped to
a newer revision that no longer builds its own is reported as ``stale``: computed by older code, to be rerun
(``report.md`` flags it too); any other mismatch is a failure.
``--migrate`` then rewrites such a format-1 record in place under the current format: new hash and file name, the
revisions in its ``config``, and ``migrated_from`` naming the old hash, so a resumed bench command reuses the cell
instead of recomputing it.

``--add-groups`` (needs the data, ``--root``) writes into records from before cells kept them the recording of every
test window (``predictions[split]["groups"]``), so their intervals resample recordings rather than windows. The
recordings are read from the dataset split the cell was evaluated on, and written only when that split's targets equal
the record's, in order; the numbers are not touched.

``--compare OTHER`` checks that the cells of another folder (a rerun of some of the same cells) computed the same
numbers, bit for bit: metrics, predictions and probabilities of every split, the training curve (timings aside), the
selected epoch and the early-classification prefixes.

    python -m tools.check_cells benchmarks/results/paper-table1 --root ../shared/data [--migrate]
    python -m tools.check_cells benchmarks/results/paper-table1 --compare /tmp/rerun
    python -m tools.check_cells benchmarks/results/convlstm-biotac/e2-source --root ../shared/data --add-groups
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from tactile_zoo import registry
from tactile_zoo.bench import BenchConfig, build_grid
from tactile_zoo.bench.grid import cell_id
from tactile_zoo.bench.records import COMPACT_SUFFIX, InvalidCell, cell_files, read_record, run_records
from tactile_zoo.bench.rundir import atomic_write_json
from tactile_zoo.engine.config import HASH_FORMAT, config_hash
from tactile_zoo.recipe import recipe_name_of

REVISION_KEYS = ("model_revision", "dataset_revision")


def _without(config: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    """``config`` without ``keys``, its recipe name made explicit (records from before named recipes have none)."""
    return {**{k: v for k, v in config.items() if k not in keys}, "recipe_name": recipe_name_of(config)}


def _replayed_revision(record: dict[str, Any]) -> dict[str, int]:
    """``--model-revision MODEL=N`` for the record's revision where its model still builds it, else nothing (the
    default: a record of a revision whose code is gone is then ``stale``)."""
    recorded = record["config"].get("model_revision")
    known = registry.model_revisions(registry.get_model_entry(record["model"]))
    return {record["model"]: recorded} if recorded in known else {}


def _rebuilt(record: dict[str, Any], root: str | None) -> dict[str, Any]:
    """The record's cell as the current grid resolves it (the registered recipe of its name, its stored settings),
    at the model revision the record names where the model still builds it (``registry.model_revisions``): the
    path that trained the cell is replayed, not the model's default."""
    stored = record["config"]
    bench = BenchConfig(models=[record["model"]], datasets=[record["dataset"]], root=root, seeds=[record["seed"]],
                        recipe_name=recipe_name_of(stored),
                        refit=bool(stored.get("refit")), quick=stored.get("subset") is not None,
                        prefixes=list(stored.get("prefixes") or []), hparams=dict(stored.get("hparams") or {}),
                        dataset_kwargs={record["dataset"]: dict(stored.get("dataset_kwargs") or {})},
                        model_revisions=_replayed_revision(record))
    cells = [c for c in build_grid(bench).cells if c.fold == record["fold"]]
    if len(cells) != 1:
        raise LookupError(f"the grid has {len(cells)} cells for fold {record['fold']}")
    return cells[0].config.to_dict()


def check(record: dict[str, Any], root: str | None) -> tuple[str, str, dict[str, Any]]:
    """(status, explanation, the current configuration) for one record; status ``maps``, ``stale`` (computed by an
    older revision of its model's or dataset's code: rerun it) or ``differs`` (anything else: a real mismatch)."""
    stored = record["config"]
    current = _rebuilt(record, root)
    old_format = 2 if all(k in stored for k in REVISION_KEYS) else 1  # format 1 predates the revisions
    comparable = REVISION_KEYS if old_format == 1 else ()
    recorded = {k: stored.get(k, 1) for k in REVISION_KEYS}
    older = [f"{k} {recorded[k]} < {current[k]}" for k in REVISION_KEYS if recorded[k] < current[k]]
    if older:
        return "stale", f"computed by older code ({', '.join(older)}): rerun it", current
    a, b = _without(current, comparable), _without(stored, comparable)
    if a != b:
        differing = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        return "differs", f"configuration differs in {differing}", current
    expected = config_hash(_without(current, comparable), hash_format=old_format)
    if expected != record["config_hash"]:
        return "differs", f"hash {record['config_hash']} != {expected} recomputed in format {old_format}", current
    return "maps", f"maps (format {old_format})", current


def migrate(path: Path, record: dict[str, Any], current: dict[str, Any]) -> Path:
    """Rewrite a format-1 record under the current hash format; returns the new file (the old one is removed)."""
    new_hash = config_hash(current)
    new_id = cell_id(record["model"], record["dataset"], record["fold"], record["seed"], new_hash)
    migrated = {**record, "config": current, "config_hash": new_hash, "cell_id": new_id, "hash_format": HASH_FORMAT,
                "migrated_from": {"config_hash": record["config_hash"], "hash_format": 1}}
    target = path.with_name(new_id + (COMPACT_SUFFIX if path.name.endswith(COMPACT_SUFFIX) else ".json"))  # same form
    atomic_write_json(target, migrated)
    if target != path:
        path.unlink()
    return target


#: What a cell computed (its numbers); timings, hosts, versions and hashes are not compared.
COMPUTED = ("metrics", "predictions", "best_epoch", "epochs_run", "prefix", "params", "n_train", "n_val", "n_test")
CURVE_KEYS = ("epoch", "train_loss", "val_loss", "val_accuracy", "lr")


def _computed(record: dict[str, Any]) -> dict[str, Any]:
    out = {key: record.get(key) for key in COMPUTED}
    out["curve"] = [{k: row.get(k) for k in CURVE_KEYS} for row in record.get("curve") or []]
    out["refit_curve"] = [{k: row.get(k) for k in CURVE_KEYS} for row in record.get("refit_curve") or []]
    return out


def compare(folder: Path, other: Path) -> int:
    """Compare the numbers of the cells ``other`` shares with ``folder`` (same model, dataset, fold and seed)."""
    def key(record: dict[str, Any]) -> tuple[str, str, int, int]:
        return record["model"], record["dataset"], record["fold"], record["seed"]

    ours = {key(r): r for r in run_records(folder)}
    theirs = run_records(other)
    differing = 0
    for record in theirs:
        base = ours.get(key(record))
        if base is None:
            print(f"--   {record['cell_id']}: not in {folder}")
            continue
        a, b = _computed(base), _computed(record)
        diffs = [k for k in a if a[k] != b[k]]
        differing += bool(diffs)
        acc = record["metrics"]["test"]["accuracy"]
        print(f"{'same' if not diffs else 'DIFF'} {record['cell_id']}: test accuracy {acc:.4f} "
              f"({len(b['curve'])} epochs, best {b['best_epoch']})" + (f"; differs in {diffs}" if diffs else ""))
    print(f"{len(theirs) - differing} of {len(theirs)} cells computed the same numbers bit for bit")
    return 1 if differing else 0


def add_groups(path: Path, record: dict[str, Any], root: str | None) -> str:
    """Write the recording of every stored test sample into ``record`` (see the module docstring)."""
    from tactile_zoo.engine.build import load_splits
    from tactile_zoo.engine.tensors import as_split

    if record.get("status") != "ok":
        return "not ok: left alone"
    cfg = record["config"]
    stored = record.get("predictions") or {}
    splits = load_splits(record["dataset"], root, record["fold"], False, cfg.get("dataset_kwargs") or {},
                         tuple(stored))
    added = []
    for name, pred in stored.items():
        split = as_split(splits[name])
        if split.y.tolist() != pred["targets"]:
            raise SystemExit(f"{path}: the {name} split's targets differ from the record's; not the same split")
        units = split.unit_ids()
        if len(set(units)) < len(units) and pred.get("groups") != units:
            pred["groups"] = units
            added.append(name)
    if added:
        atomic_write_json(path, record)
    return f"groups added to {', '.join(added)}" if added else "nothing to add (each sample its own unit)"


def _read(path: Path) -> dict[str, Any]:
    """The record in ``path``; a file that fails the cell schema (.schema) stops the tool, named."""
    record = read_record(path)
    if isinstance(record, InvalidCell):
        raise SystemExit(f"error: damaged cell file {record}")
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a bench output folder (its cells/ holds the records)")
    parser.add_argument("--root", default=None, help="the data home the cells were run with")
    parser.add_argument("--migrate", action="store_true", help="re-key format-1 cells that map to the current format")
    parser.add_argument("--compare", type=Path, default=None, metavar="OTHER",
                        help="compare the numbers of OTHER's cells with this folder's instead")
    parser.add_argument("--add-groups", action="store_true",
                        help="write each stored test sample's recording into older records (needs --root)")
    args = parser.parse_args(argv)
    if args.compare is not None:
        return compare(args.folder, args.compare)
    paths = cell_files(args.folder)
    if not paths:
        print(f"no cell records under {args.folder / 'cells'}", file=sys.stderr)
        return 2
    if args.add_groups:
        for path in paths:
            print(f"{path.name}: {add_groups(path, _read(path), args.root)}")
        return 0
    counts = {"maps": 0, "stale": 0, "differs": 0}
    for path in paths:
        record = _read(path)
        status, why, current = check(record, args.root)
        counts[status] += 1
        line = f"{status:<7} {path.name}: {why}"
        if status == "maps" and args.migrate and not all(k in record["config"] for k in REVISION_KEYS):
            line += f" -> {migrate(path, record, current).name}"
        print(line)
    print(f"{counts['maps']} of {len(paths)} cells map to their configuration under the current code; "
          f"{counts['stale']} stale (older code, to rerun), {counts['differs']} differ")
    return 1 if counts["differs"] else 0


if __name__ == "__main__":
    sys.exit(main())
