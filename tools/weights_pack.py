"""The weight pack ``plugins/tactile-zoo-weights``: built from committed benchmark cells, and checked against them.

    python -m tools.weights_pack            # (re)build the pack from every source cell that has weights
    python -m tools.weights_pack --list     # which model x dataset has a source cell with weights; which not, why
    python -m tools.weights_pack --check    # exit 1, naming each mismatch, if the pack is not what the cells give
    python -m tools.weights_pack --cells benchmarks/results/rerun-x    # another folder of reruns

Nothing is trained here. For each model on Ev-Objects, Ev-Containers and BioTac-DoS the weights are those of one cell of
the Table I folder of the model's default recipe (:data:`TABLES`: ``benchmarks/results/paper-table1`` holds ``source``,
``paper-table1-zoo`` ``zoo`` and ``paper-table1-full`` ``full``): status ok, seed 0, fold 0, the model's default recipe,
honest (``evaluation`` validation, selected on validation, or final, declared epochs with nothing selected: a
``reference`` cell chooses its epoch on the test set, a ``tuning`` cell has no test figure), the whole data (no
``--quick`` subset), computed by the current revision of the model's and the dataset's code. Two such cells with
different config hashes are an error: one entry, one configuration. The entry's accuracy is that cell's test accuracy,
the figure its leaderboard row shows.

The file is the one that cell's own run saved (``bench --save-weights``: the record's ``weights`` names it and its
sha256). A Table I cell run without ``--save-weights`` gets its weights from a rerun of the same cell with
``--save-weights`` into another folder, by convention ``benchmarks/results/weights-<name>/`` (read by default) or any
``--cells DIR``. A rerun is accepted only when it reproduces the Table I cell exactly: the same cell id (model,
dataset, fold, seed and config hash) and the same test accuracy, targets and predictions, sample for sample. Training
is deterministic, so a rerun that differs was not the same computation, and its weights are refused.

Building writes, under ``plugins/tactile-zoo-weights/tactile_zoo_weights/``:

- ``<tag>.safetensors``: each file copied byte for byte (float32; its sha256 checked against the record's), from
  the run's folder, or kept from the pack when that folder's files are not on this machine (they are not committed:
  any checkout can rebuild the pack as long as no new weights are needed);
- ``manifest.json``: one entry per file, made by :func:`tactile_zoo.weights.entry_from_record` from the record that
  saved it (spec, dataset options and resolved preprocessing, recipe and config hash, test accuracy, commit, sha256,
  licences), with a note where users need one (Ev class names unverified; BioTac-DoS input units);
- ``expected_logits.json``: each shipped model's logits on seeded random inputs shaped like its dataset's samples
  (:func:`probe_inputs`), which ``tests/weights/test_shipped_weights.py`` reproduces without any real data;

and the table of shipped weights in the plugin's README, between its markers. The distribution must stay within
:data:`LIMIT_BYTES` (32 MB); the build stops, listing the sizes, before writing anything larger. Every entry,
D-CNN's Ev checkpoints (7.8 and 9.9 MB) included, fits in float32 (about 28 MB in all), so no half-precision copy is
made.

``--check`` reads only committed files (cell records, the pack, the README; never the uncommitted
``benchmarks/results/**/weights/*.safetensors``), so it runs in CI; ``tests/weights/test_shipped_weights.py`` runs it.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_zoo import registry
from tactile_zoo._files import replace_block
from tactile_zoo.bench.records import CELLS_DIR, cell_file, revision_gaps, run_records
from tactile_zoo.bench.tables import leaderboard_rows
from tactile_zoo.data.base import file_sha256
from tactile_zoo.errors import ConfigError
from tactile_zoo.recipe import recipe_name_of
from tactile_zoo.study.publish import study_folder
from tactile_zoo.weights import WeightEntry, entry_from_record, make_tag, read_manifest, write_manifest

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
STUDIES = REPO / "benchmarks" / "studies"  # each Table I recipe's cells: its study's folder
TABLE = study_folder(STUDIES, "table1-source")
#: the Table I folder of each recipe: a model's entries come from the folder of its default recipe
TABLES = {"source": TABLE, "zoo": study_folder(STUDIES, "table1-zoo"),
          "full": study_folder(STUDIES, "table1-full-r3")}
#: folders of reruns with ``--save-weights`` that are read by default (``benchmarks/results/weights-<name>/``)
RERUNS = "weights-*"
PLUGIN = REPO / "plugins" / "tactile-zoo-weights"
PACK = PLUGIN / "tactile_zoo_weights"
README = PLUGIN / "README.md"
MANIFEST, LOGITS = "manifest.json", "expected_logits.json"
#: the whole distribution (weights, manifest, logits, code, README): 32 MB, counted in decimal megabytes (the project's
#: rule for committed weights)
LIMIT_BYTES = 32_000_000
#: pairs whose weights are deliberately not shipped, by recipe, and why (shown instead of "awaiting a rerun"). A cell's
#: saved file is not committed, so one that is gone can only come back from a rerun that reproduces the cell exactly,
#: and training is reproducible only on the CPU type that ran it
_XEON = "its Table I cell was trained on another CPU type (a 2-core Intel Xeon, {date})"
DECLINED = {
    **{("source", "dcnn", dataset): _XEON.format(date="2026-11-22")
       + " before `--save-weights` existed, so a rerun here trains other weights"
       for dataset in ("ev_objects", "ev_containers")},
    **{("zoo", "dcnn", dataset): _XEON.format(date="2026-12-02")
       + "; the file it saved was not kept, and a rerun here trains other weights"
       for dataset in ("ev_objects", "ev_containers")},
}
MODELS = ("sgnet", "dcnn", "convlstm", "cnn_lstm", "tacformer", "x_tacformer")
DATASETS = ("ev_objects", "ev_containers", "biotac_dos")
BEGIN, END = "<!-- shipped weights: begin (python -m tools.weights_pack) -->", "<!-- shipped weights: end -->"
DESCRIPTION = ("Pretrained weights of tactile-zoo's models: each file is the trained model of one committed seed-0, "
               "fold-0 benchmark cell (tactile-zoo bench --save-weights); built by python -m tools.weights_pack.")
LOGITS_FORMAT = "tactile-zoo-expected-logits/1"
#: probe inputs: samples per entry, the seed of their generator, and the share of 1s in event data
PROBE_SAMPLES, PROBE_SEED, PROBE_EVENT_RATE = 4, 0, 0.1
EV_NOTE = ("{name} class names are unverified: the release has none; tactile-zoo takes them from the VT-SNN "
           "preprocessing of the same recordings (clear-nus/VT_SNN), whose object order is very likely, not certainly, "
           "the label order.")


# ----------------------------------------------------------------------------------------------- selection
@dataclass(frozen=True)
class Source:
    """Where one entry comes from: the Table I cell (its accuracy is the leaderboard's) and the record whose run saved
    the file (the cell itself, or a rerun that reproduced it), with that run's folder and the cell's Table I folder."""

    cell: dict[str, Any]
    saved: dict[str, Any]
    run_dir: Path
    table: Path

    @property
    def file(self) -> Path:
        """The ``.safetensors`` file the run saved (absent from a checkout: these files are not committed)."""
        return self.run_dir / self.saved["weights"]["file"]


@dataclass(frozen=True)
class Slot:
    """One model x dataset: its source, or why it has none (``reason`` reads only records, never local files, so
    ``--check`` says the same in CI as here)."""

    model: str
    dataset: str
    source: Source | None
    reason: str = ""


def read_cells(folder: Path) -> list[dict[str, Any]]:
    """The cell records of a bench folder (``cells/*.json``, ``cells/*.json.gz``), in file-name order."""
    return run_records(folder)


def default_recipe(model: str) -> str:
    """The recipe a model trains with when none is named (the weights of record are that recipe's)."""
    return registry.model_recipe(registry.get_model_entry(model).meta)[0]


def _stale(record: dict[str, Any]) -> str | None:
    """Why the record was computed by older code than the registered one, or ``None`` when it is current."""
    gaps = revision_gaps(record)
    if gaps is None:
        return f"model {record['model']!r} or dataset {record['dataset']!r} is not registered"
    return f"stale: {gaps[0]}" if gaps else None


def _excluded(record: dict[str, Any]) -> str | None:
    """Why a record of the right model, dataset, fold 0 and seed 0 cannot be the cell of record, or ``None``."""
    config = record.get("config") or {}
    if record.get("status") != "ok":
        return f"status {record.get('status')}"
    recipe, default = recipe_name_of(config), default_recipe(record["model"])
    if recipe != default:
        return f"recipe {recipe!r}, not the default {default!r}"
    evaluation = config.get("evaluation", "validation")
    if evaluation not in ("validation", "final"):
        return f"evaluation {evaluation!r} (only honest cells count: selected on validation, or final)"
    if config.get("subset"):
        return "ran on a subset (--quick)"
    return _stale(record)


def reproduces(rerun: dict[str, Any], cell: dict[str, Any]) -> str | None:
    """Why ``rerun`` does not reproduce the Table I ``cell`` exactly, or ``None`` when it does (see the module
    docstring: same cell id, same test accuracy, targets and predictions)."""
    if rerun.get("status") != "ok":
        return f"status {rerun.get('status')}"
    if rerun.get("config_hash") != cell.get("config_hash"):
        return f"config hash {rerun.get('config_hash')}, the Table I cell's is {cell.get('config_hash')}"
    ours, theirs = (rerun.get("metrics") or {}).get("test") or {}, (cell.get("metrics") or {}).get("test") or {}
    if ours.get("accuracy") != theirs.get("accuracy"):
        return f"test accuracy {ours.get('accuracy')!r}, the Table I cell's is {theirs.get('accuracy')!r}"
    mine, base = (rerun.get("predictions") or {}).get("test") or {}, (cell.get("predictions") or {}).get("test") or {}
    for key in ("targets", "predictions"):
        if mine.get(key) is None or mine.get(key) != base.get(key):
            differ = sum(a != b for a, b in zip(mine.get(key) or [], base.get(key) or []))
            return f"test {key} differ from the Table I cell's ({differ} of {len(base.get(key) or [])} samples)"
    return None


def _default_cells(records: list[dict[str, Any]], model: str, dataset: str) -> tuple[list[dict[str, Any]], list[str]]:
    """The fold-0, seed-0 records of a model on a dataset that qualify, and why the others do not."""
    mine = [r for r in records if r["model"] == model and r["dataset"] == dataset and r["fold"] == 0
            and r["seed"] == 0]
    ok, why = [], []
    for record in mine:
        reason = _excluded(record)
        (why.append(f"{record['cell_id']}: {reason}") if reason else ok.append(record))
    return ok, why


def table_of(model: str) -> Path | None:
    """The Table I folder of the model's default recipe (:data:`TABLES`); ``None`` when that recipe has none."""
    return TABLES.get(default_recipe(model))


def select(reruns: Sequence[Path] = (), table: Path | None = None) -> list[Slot]:
    """The source of every model x dataset (:data:`MODELS` x :data:`DATASETS`, and any other pair whose Table I cell
    has weights), or why it has none. ``reruns``: folders whose cells may give a Table I cell its weights; ``table``:
    one Table I folder for every model (default: each model's :func:`table_of`)."""
    def folder_of(model: str) -> Path | None:
        return table if table is not None else table_of(model)

    read: dict[Path, list[dict[str, Any]]] = {}
    for folder in [table] if table is not None else sorted(set(TABLES.values())):
        read[folder] = read_cells(folder) if (folder / "cells").is_dir() else []
    rerun_records = [(folder, r) for folder in reruns for r in read_cells(folder)]
    pairs = [(m, d) for d in DATASETS for m in MODELS]
    pairs += sorted({(r["model"], r["dataset"]) for folder, records in read.items() for r in records
                     if r.get("weights") and folder_of(r["model"]) == folder} - set(pairs))
    slots = []
    for model, dataset in pairs:
        home = folder_of(model)
        if home is None:
            slots.append(Slot(model, dataset, None, f"its default recipe {default_recipe(model)!r} has no Table I "
                                                    f"folder (weights_pack.TABLES)"))
            continue
        cells, why = _default_cells(read[home], model, dataset)
        hashes = sorted({c["config_hash"] for c in cells})
        if not cells:
            reason = "; ".join(why) if why else f"no seed-0 fold-0 cell in {home.name} yet"
            slots.append(Slot(model, dataset, None, reason))
            continue
        if len(hashes) > 1:
            slots.append(Slot(model, dataset, None, f"several configurations ({', '.join(hashes)}): one entry must "
                                                    f"be one configuration; move the others out of {home.name}"))
            continue
        cell = cells[0]
        declined = DECLINED.get((default_recipe(model), model, dataset))
        if declined:
            slots.append(Slot(model, dataset, None, declined))
            continue
        if cell.get("weights"):
            slots.append(Slot(model, dataset, Source(cell, cell, home, home)))
            continue
        refused, found = [], None
        for folder, rerun in rerun_records:
            if rerun.get("cell_id") != cell["cell_id"] or not rerun.get("weights"):
                continue
            reason = reproduces(rerun, cell)
            if reason is None:
                found = Source(cell, rerun, folder, home)
                break
            refused.append(f"the rerun in {_rel(folder)} is refused: {reason}")
        if found is not None:
            slots.append(Slot(model, dataset, found))
        else:
            hint = (f"{cell['cell_id']} was run without --save-weights; rerun it with --save-weights into "
                    f"benchmarks/results/weights-<name>/")
            slots.append(Slot(model, dataset, None, "; ".join([hint, *refused])))
    return slots


def _rel(path: Path) -> str:
    return str(path.resolve().relative_to(REPO)) if path.resolve().is_relative_to(REPO) else str(path)


def rerun_folders(extra: Iterable[Path] = ()) -> list[Path]:
    """``benchmarks/results/weights-*`` and the ``--cells`` folders, each once, in that order."""
    out: list[Path] = []
    for folder in [*sorted(p for p in RESULTS.glob(RERUNS) if p.is_dir()), *extra]:
        if not (folder / "cells").is_dir():
            raise SystemExit(f"{folder} has no cells/ folder: not a bench output")
        if folder.resolve() not in {p.resolve() for p in out} | {t.resolve() for t in TABLES.values()}:
            out.append(folder)
    return out


# ----------------------------------------------------------------------------------------------- entries
def note_for(entry: WeightEntry) -> str:
    """What a user must know beyond the entry's fields: unverified class names (Ev), the input units (BioTac-DoS)."""
    parts = []
    if entry.dataset in ("ev_objects", "ev_containers"):
        parts.append(EV_NOTE.format(name={"ev_objects": "Ev-Objects", "ev_containers": "Ev-Containers"}[entry.dataset]))
    options = (entry.preprocessing or {}).get("dataset_options") or {}
    if entry.dataset == "biotac_dos" and options.get("normalize") == "baseline":
        parts.append(f"Inputs are windows of {options['window']} BioTac SP readings at 100 Hz, each electrode as "
                     f"(baseline - reading) / {options['scale']:g} raw units, the baseline being the mean of the "
                     f"recording's first {options['baseline']} readings (tactile-zoo's BioTac-DoS loading).")
    elif entry.dataset == "biotac_dos" and options.get("normalize") == "none":
        parts.append(f"Inputs are windows of {options['window']} BioTac SP readings at 100 Hz in raw electrode "
                     f"units, as recorded (the loader does not normalise them; the model's hparams say what it "
                     f"does itself).")
    return " ".join(parts)


def planned_entry(source: Source) -> WeightEntry:
    """The manifest entry of one source: the saving record's, its file named ``<tag>.safetensors`` in the pack."""
    entry = entry_from_record(source.saved, None)
    return dataclasses.replace(entry, note=note_for(entry), file=f"{entry.tag}.safetensors")


def _leaderboard_accuracy(cell: dict[str, Any]) -> float | None:
    """The accuracy the harness's leaderboard shows for the cell (the same function writes leaderboard.csv)."""
    rows, _ = leaderboard_rows([cell])
    return rows[0].get("accuracy")


def _leaderboard_csv(table: Path) -> dict[str, float | None]:
    """``config hash / fold / seed / model / dataset`` -> accuracy in the folder's leaderboard.csv (when present; the
    file shows only the last bench command's grid, so a cell may be missing from it)."""
    path = table / "leaderboard.csv"
    if not path.is_file():
        return {}
    with path.open(newline="") as fh:
        return {"/".join((r["config_hash"], r["fold"], r["seed"], r["model"], r["dataset"])):
                float(r["accuracy"]) if r.get("accuracy") else None for r in csv.DictReader(fh)}


# ----------------------------------------------------------------------------------------------- expected logits
def probe_inputs(spec: Mapping[str, Any], dataset: str, samples: int = PROBE_SAMPLES, seed: int = PROBE_SEED
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Seeded inputs shaped like ``dataset``'s samples: ``x (S, T, N, C)``, ``g (S, T, G)``, float32.

    Values: 0/1 events (a share :data:`PROBE_EVENT_RATE` of ones) for event data (the dataset class's ``binary``),
    else uniform in [-1, 1). NumPy's PCG64 stream and its ``random()`` doubles are stable across NumPy versions, so
    the inputs, hence the logits, do not depend on the installed libraries; ``expected_logits.json`` also stores the
    sha256 of the inputs, so a change here reads as such and not as a change of the weights.
    """
    t, n, c, g = (int(spec[k]) for k in ("num_steps", "num_nodes", "num_channels", "num_globals"))
    table = np.random.default_rng(seed).random((samples, t, n * c + g))  # float64 in [0, 1): the recordings layout
    binary = bool(getattr(registry.get_dataset_entry(dataset).obj, "binary", False))
    values = (table < PROBE_EVENT_RATE) if binary else (2.0 * table - 1.0)
    data = torch.from_numpy(values.astype(np.float32))
    return data[..., : n * c].reshape(samples, t, n, c).contiguous(), data[..., n * c:].contiguous()


def inputs_sha256(x: torch.Tensor, g: torch.Tensor) -> str:
    return hashlib.sha256(x.numpy().tobytes() + g.numpy().tobytes()).hexdigest()


def model_logits(entry: WeightEntry, x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """The pretrained model's scores on ``x, g`` through the path :func:`tactile_zoo.evaluate` takes."""
    from tactile_zoo import create_model
    from tactile_zoo.engine.evaluate import predict_scores
    from tactile_zoo.engine.runtime import flush_denormals

    model = create_model(entry.model, pretrained=entry)
    with flush_denormals():
        return predict_scores(model, x, g)  # (S, K)


def expected_logits(entries: Sequence[WeightEntry]) -> dict[str, Any]:
    """The ``expected_logits.json`` document of ``entries`` (files as the pack holds them)."""
    out: dict[str, Any] = {}
    for entry in entries:
        x, g = probe_inputs(entry.spec, entry.dataset)
        logits = model_logits(entry, x, g)
        out[entry.tag] = {"model": entry.model, "dataset": entry.dataset, "sha256": entry.sha256,
                          "inputs": {"x_shape": list(x.shape), "g_shape": list(g.shape),
                                     "sha256": inputs_sha256(x, g)},
                          # a float32 value is exact as a double, and JSON writes doubles exactly: no rounding here
                          "logits": [[float(v) for v in row] for row in logits.tolist()]}
    return {"format": LOGITS_FORMAT,
            "description": f"Logits of each shipped model on {PROBE_SAMPLES} seeded inputs shaped like its dataset's "
                           f"samples (tools.weights_pack.probe_inputs, seed {PROBE_SEED}), one torch thread; "
                           f"tests/weights/test_shipped_weights.py reproduces them.",
            "samples": PROBE_SAMPLES, "seed": PROBE_SEED, "entries": out}


# ----------------------------------------------------------------------------------------------- the README table
def _mb(size: int | None) -> str:
    return "?" if size is None else f"{size / 1e6:.2f} MB"


def readme_table(entries: Sequence[WeightEntry], slots: Sequence[Slot]) -> str:
    """The README block: one row per shipped entry, the total, and the pairs not shipped with the reason."""
    if not entries:
        lines = ["**This release ships no weights yet**: no Table I cell has weights, and the manifest is empty."]
    else:
        lines = ["| tag | test accuracy | size | recipe, config hash | cell | trained by commit |",
                 "|---|---|---|---|---|---|"]
        for e in entries:
            commit = "-" if not e.commit else e.commit[:12] + ("+dirty" if e.commit.endswith("+dirty") else "")
            accuracy = "-" if e.accuracy is None else f"{e.accuracy:.4f}"
            lines.append(f"| `{e.tag}` | {accuracy} | {_mb(e.bytes)} | {e.recipe}, `{e.config_hash}` | "
                         f"`{e.cell_id}` | `{commit}` |")
        total = sum(e.bytes or 0 for e in entries)
        lines += ["", f"{len(entries)} entries, {_mb(total)} of weights (float32). Test accuracy: the cell's, on its "
                      "dataset's test split (BioTac-DoS: fold 0 of `validation=object`, all seven unseen objects)."]
    by_reason: dict[str, dict[str, list[str]]] = {}  # reason -> dataset -> models, in the order of the slots
    for slot in slots:
        if slot.source is None:
            by_reason.setdefault(_short(slot.reason), {}).setdefault(slot.dataset, []).append(f"`{slot.model}`")
    if by_reason:
        lines += ["", "Not shipped yet (`python -m tools.weights_pack --list` says why in full):", ""]
        for reason, where in by_reason.items():
            pairs = "; ".join(", ".join(models) + f" on `{dataset}`" for dataset, models in where.items())
            lines.append(f"- {pairs}: {reason}")
    return "\n".join(lines)


def _short(reason: str) -> str:
    """The README's form of a reason: its first clause (``--list`` gives the whole of it)."""
    if "without --save-weights" in reason:
        return "the Table I cell was run without `--save-weights`; awaiting a rerun that reproduces it"
    return reason.split("; ")[0]


def render_readme(text: str, entries: Sequence[WeightEntry], slots: Sequence[Slot]) -> str:
    return replace_block(text, BEGIN, END, readme_table(entries, slots), README, error=SystemExit)


# ----------------------------------------------------------------------------------------------- size
def distribution_bytes(plugin: Path = PLUGIN) -> int:
    """Bytes of everything the distribution would ship: the plugin folder, build leftovers and caches aside."""
    def shipped(parts: tuple[str, ...]) -> bool:
        return not any(part in ("build", "dist", "__pycache__") or part.endswith(".egg-info") for part in parts)

    return sum(p.stat().st_size for p in plugin.rglob("*") if p.is_file() and shipped(p.relative_to(plugin).parts))


def _too_big(sizes: Mapping[str, int], others: int) -> str:
    listed = "\n".join(f"  {tag}: {_mb(size)}" for tag, size in sorted(sizes.items(), key=lambda kv: -kv[1]))
    return (f"the weight pack would hold {_mb(sum(sizes.values()) + others)}, over the limit of {_mb(LIMIT_BYTES)}:\n"
            f"{listed}\n  other files: {_mb(others)}\nShip fewer entries, or add half-precision copies whose accuracy "
            f"is measured on the stored weights (not implemented).")


# ----------------------------------------------------------------------------------------------- build
def build(reruns: Sequence[Path] = (), pack: Path = PACK, readme: Path = README) -> int:
    """Rebuild the pack from the sources (see the module docstring); returns the exit status."""
    torch.set_num_threads(1)  # the logits are written as the test suite (one thread per worker) recomputes them
    slots = select(reruns)
    chosen = [(s.source, planned_entry(s.source)) for s in slots if s.source is not None]
    found = {entry.tag: _copy_from(src, entry, pack) for src, entry in chosen}
    absent = [f"  {entry.tag}: {_rel(src.file)}" for src, entry in chosen if found[entry.tag] is None]
    files = {tag: path for tag, path in found.items() if path is not None}
    if absent:
        raise SystemExit("the records say these weights were saved, but the files are neither here nor in the pack "
                         "(.safetensors files are not committed; build where the cells ran):\n" + "\n".join(absent))
    targets = {entry.tag: pack / entry.file for _, entry in chosen}
    others = distribution_bytes(pack.parent) - sum(p.stat().st_size for p in pack.glob("*.safetensors"))
    sizes = {tag: path.stat().st_size for tag, path in files.items()}
    if sum(sizes.values()) + others > LIMIT_BYTES:
        raise SystemExit(_too_big(sizes, others))
    for _, entry in chosen:
        target, source = targets[entry.tag], files[entry.tag]
        if source.resolve() != target.resolve():
            tmp = target.with_name(f".{target.name}.tmp")
            shutil.copyfile(source, tmp)
            os.replace(tmp, target)
    for old in sorted(set(pack.glob("*.safetensors")) - set(targets.values())):
        print(f"removed {_rel(old)} (no current Table I cell gives it)")
        old.unlink()
    write_manifest([dataclasses.replace(e, file=str(targets[e.tag])) for _, e in chosen], pack / MANIFEST,
                   description=DESCRIPTION)
    shipped = read_manifest(pack / MANIFEST)  # the logits are those of the files as users will load them
    _write_json(pack / LOGITS, expected_logits(shipped))
    readme.write_text(render_readme(readme.read_text(), shipped, slots))
    total = distribution_bytes(pack.parent)
    if total > LIMIT_BYTES:  # the estimate above missed something: say so rather than ship it
        raise SystemExit(f"{_rel(pack.parent)} holds {_mb(total)}, over {_mb(LIMIT_BYTES)}")
    for (src, _), entry in zip(chosen, shipped):
        via = "" if src.saved is src.cell else f" (weights from the rerun in {_rel(src.run_dir)})"
        print(f"{entry.tag:<34} accuracy {entry.accuracy:.4f}  {_mb(entry.bytes):>8}  {entry.cell_id}{via}")
    print(f"wrote {len(shipped)} entries to {_rel(pack)}: {_mb(total)} in the distribution (limit "
          f"{_mb(LIMIT_BYTES)}); {sum(s.source is None for s in slots)} model x dataset pairs not shipped "
          f"(python -m tools.weights_pack --list)")
    _warn_uncommitted([src for src, _ in chosen])
    return 0


def _copy_from(source: Source, entry: WeightEntry, pack: Path) -> Path | None:
    """The file to ship for ``entry``: the run's own, or else the pack's copy of it, when it is the same file (the
    record's sha256). The runs' files are not committed, so the pack's copy lets any checkout rebuild the pack (when
    only the README's list of missing weights changed, say) as long as no new weights are needed. ``None``: neither
    is here. A file that is here with another sha256 stops the build."""
    for path in (source.file, pack / entry.file):
        if path.is_file():
            if file_sha256(path) != entry.sha256:
                raise SystemExit(f"{_rel(path)} does not have the sha256 its record {source.saved['cell_id']} states "
                                 f"({entry.sha256}): the file was overwritten after the cell ran")
            return path
    return None


def _write_json(path: Path, document: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(document, indent=1) + "\n")
    os.replace(tmp, path)


def _warn_uncommitted(sources: Sequence[Source]) -> None:
    """Name the source cell records git does not track yet: CI checks the pack against committed records only."""
    try:
        listing = subprocess.run(["git", "-C", str(REPO), "ls-files", "-z", "--", "benchmarks/results"],
                                 capture_output=True, text=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return  # not a git checkout: nothing to say
    tracked = set(listing.split("\0"))
    for src in sources:
        for path in sorted({cell_file(src.table / CELLS_DIR, src.cell["cell_id"]),
                            cell_file(src.run_dir / CELLS_DIR, src.saved["cell_id"])}):
            if _rel(path) not in tracked:
                print(f"note: {_rel(path)} is not committed yet; commit it with the pack (--check reads it)")


# ----------------------------------------------------------------------------------------------- check
def check(reruns: Sequence[Path] = (), pack: Path = PACK, readme: Path = README) -> list[str]:
    """Every way the pack differs from what the sources give, one line each (empty: it matches). Reads committed
    files only: records, the pack's manifest, files and expected logits, and the README."""
    problems: list[str] = []
    slots = select(reruns)
    planned = [(s.source, planned_entry(s.source)) for s in slots if s.source is not None]
    expected = {entry.tag: entry for _, entry in planned}
    origin = {entry.tag: source for source, entry in planned}
    try:
        shipped = {e.tag: e for e in read_manifest(pack / MANIFEST)}
    except ConfigError as exc:
        return [str(exc)]
    for tag in sorted(set(expected) - set(shipped)):
        problems.append(f"{tag}: cell {expected[tag].cell_id} has weights, but the pack does not ship them "
                        f"(run python -m tools.weights_pack)")
    for tag in sorted(set(shipped) - set(expected)):
        why = next((s.reason for s in slots if make_tag(s.model, s.dataset, default_recipe(s.model)) == tag
                    and s.source is None), "no source cell gives it")
        problems.append(f"{tag}: shipped, but no current Table I cell gives it ({why})")
    boards = {folder: _leaderboard_csv(folder) for folder in {source.table for source in origin.values()}}
    for tag in sorted(set(expected) & set(shipped)):
        want, have, cell = expected[tag].to_dict(), shipped[tag].to_dict(), origin[tag].cell
        for key in sorted(k for k in want if k != "file" and want[k] != have[k]):
            problems.append(f"{tag}: {key} is {_brief(have[key])} in the pack, {_brief(want[key])} from cell "
                            f"{cell['cell_id']}")
        accuracy = shipped[tag].accuracy
        if _leaderboard_accuracy(cell) != accuracy:
            problems.append(f"{tag}: accuracy {accuracy!r}, the cell's leaderboard row says "
                            f"{_leaderboard_accuracy(cell)!r}")
        row = "/".join(str(cell[k]) for k in ("config_hash", "fold", "seed", "model", "dataset"))
        board = boards[origin[tag].table]
        if row in board and board[row] != accuracy:
            problems.append(f"{tag}: accuracy {accuracy!r}, {_rel(origin[tag].table / 'leaderboard.csv')} says "
                            f"{board[row]!r}")
        problems += _file_problems(shipped[tag], origin[tag].saved)
    listed = {e.local_path().resolve() for e in shipped.values() if e.local_path() is not None}
    for stray in sorted(set(p.resolve() for p in pack.glob("*.safetensors")) - listed):
        problems.append(f"{_rel(stray)}: in the pack, but no manifest entry lists it")
    problems += _logits_problems(pack / LOGITS, list(shipped.values()))
    if readme.is_file():
        try:
            current = render_readme(readme.read_text(), list(shipped.values()), slots)
        except SystemExit as exc:
            problems.append(str(exc))
        else:
            if current != readme.read_text():
                problems.append(f"{_rel(readme)}: the table of shipped weights is out of date (run python -m "
                                f"tools.weights_pack)")
    total = distribution_bytes(pack.parent)
    if total > LIMIT_BYTES:
        problems.append(f"{_rel(pack.parent)} holds {_mb(total)}, over the limit of {_mb(LIMIT_BYTES)}")
    return problems


def _brief(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _file_problems(entry: WeightEntry, saved: dict[str, Any]) -> list[str]:
    path = entry.local_path()
    if path is None or not path.is_file():
        return [f"{entry.tag}: file {path} is missing from the pack"]
    problems = []
    sha = file_sha256(path)
    if sha != saved["weights"]["sha256"]:
        problems.append(f"{entry.tag}: {_rel(path)} has sha256 {sha}, the cell record {saved['cell_id']} says "
                        f"{saved['weights']['sha256']}")
    if path.stat().st_size != entry.bytes:
        problems.append(f"{entry.tag}: {_rel(path)} holds {path.stat().st_size} bytes, the manifest says {entry.bytes}")
    return problems


def _logits_problems(path: Path, entries: Sequence[WeightEntry]) -> list[str]:
    try:
        document = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        return [f"{_rel(path)}: cannot be read ({exc})"] if entries or path.exists() else []
    if document.get("format") != LOGITS_FORMAT:
        return [f"{_rel(path)}: format {document.get('format')!r}, expected {LOGITS_FORMAT!r}"]
    stored, problems = document.get("entries") or {}, []
    for entry in entries:
        item = stored.get(entry.tag)
        if item is None:
            problems.append(f"{_rel(path)}: no logits for {entry.tag}")
        elif item.get("sha256") != entry.sha256:
            problems.append(f"{_rel(path)}: the logits of {entry.tag} were computed from other weights (sha256 "
                            f"{item.get('sha256')})")
        elif np.shape(item.get("logits")) != (document.get("samples"), entry.num_classes):
            problems.append(f"{_rel(path)}: the logits of {entry.tag} have shape {np.shape(item.get('logits'))}")
    problems += [f"{_rel(path)}: logits of {tag}, which the manifest does not list"
                 for tag in sorted(set(stored) - {e.tag for e in entries})]
    return problems


# ----------------------------------------------------------------------------------------------- list
def list_slots(reruns: Sequence[Path] = ()) -> str:
    """A table: every model x dataset, its source cell with weights (and accuracy, size) or why it has none."""
    lines = [f"{'model':<12} {'dataset':<14} {'status':<8} {'accuracy':>8} {'size':>8}  source or reason"]
    for slot in select(reruns):
        if slot.source is None:
            lines.append(f"{slot.model:<12} {slot.dataset:<14} {'missing':<8} {'':>8} {'':>8}  {slot.reason}")
            continue
        src = slot.source
        where = _rel(cell_file(src.run_dir / CELLS_DIR, src.saved["cell_id"]))
        here = "" if src.file.is_file() else " (its .safetensors file is not on this machine)"
        accuracy = src.cell["metrics"]["test"]["accuracy"]
        lines.append(f"{slot.model:<12} {slot.dataset:<14} {'weights':<8} {accuracy:>8.4f} "
                     f"{_mb(src.saved['weights'].get('bytes')):>8}  {where}{here}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.weights_pack", description=__doc__.split("\n")[0])
    p.add_argument("--cells", action="append", type=Path, default=[], metavar="DIR",
                   help="a bench folder of reruns (with --save-weights) of Table I cells; benchmarks/results/weights-* "
                        "are read without it")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="exit 1, naming each mismatch, if the pack is not what the "
                                                           "cells give (writes nothing)")
    mode.add_argument("--list", action="store_true", help="list every model x dataset with its source cell or why it "
                                                          "has none")
    args = p.parse_args(argv)
    reruns = rerun_folders(args.cells)
    if args.list:
        print(list_slots(reruns))
        return 0
    if args.check:
        problems = check(reruns)
        for line in problems:
            print(f"mismatch: {line}", file=sys.stderr)
        if problems:
            print(f"{len(problems)} mismatch(es): the weight pack is not what the committed cells give",
                  file=sys.stderr)
            return 1
        print(f"the weight pack matches the committed cells ({len(read_manifest(PACK / MANIFEST))} entries)")
        return 0
    return build(reruns)


if __name__ == "__main__":
    sys.exit(main())
