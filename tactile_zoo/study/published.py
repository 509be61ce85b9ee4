"""The published set: the zoo's committed cells as one installable, versioned file, to compare a new model with them
without retraining a baseline (``tactile-zoo study compare``, :mod:`.compare`).

A set is a gzip'd JSON file, ``<name>-v<version>.json.gz``, shipped as package data in ``tactile_zoo/published/``
(offline, with the package it was built for: a set names the config hashes of that package's code) and written by
``python -m tools.published_set`` from committed bench folders (``--check``: the committed file is what the cells
give). Per cell it holds what a comparison reads and what decides whether one may be made:

- who: model, recipe name and resolved recipe, fold, seed, config hash, the digest of the cell file it came from;
- the protocol: dataset, its revision and keywords, the protocol (``fixed``, ``objects``, ``kfold``), the
  evaluation (``final``, ``validation``), subset, refit and the early-classification prefixes;
- the figures: each test split's metrics and the prefix curve (``accuracy_at_<p>``);
- per test split, the prediction of every test sample, its probabilities where the cell stored them (rounded to
  0.001) and its *test set*: the targets and each sample's recording, stored once per set and
  named by its split identity (:func:`split_identity`, a digest of the dataset, split, targets and recordings).

The set also records each baseline's tuning (the trials of its model on each dataset under the tuning folders it
was built with), so a comparison can say what tuning each side had.

:func:`load_set` reads one by its id (``table1-v1``), ``published`` (the newest packaged set) or a path;
:meth:`PublishedSet.records` gives its cells back as cell records the bench's interval and paired-comparison
functions read as they read real ones.
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..bench.records import InvalidCell, cell_files, read_cell_bytes, read_record
from ..errors import ConfigError, ResultsError

__all__ = ["SET_FORMAT", "PUBLISHED", "PublishedSet", "split_identity", "build_set", "encode_set", "packaged_sets",
           "load_set", "set_file_name"]

SET_FORMAT = 1
#: the name that means "the newest set packaged with tactile-zoo"
PUBLISHED = "published"
_ID = re.compile(r"^(?P<name>[a-z0-9][a-z0-9_-]*?)-v(?P<version>[0-9]+)$")
#: stored probabilities are rounded to thousandths
PER_MILLE = 1000
_METRICS = ("accuracy", "balanced_accuracy", "macro_f1", "n")


def set_file_name(set_id: str) -> str:
    return f"{set_id}.json.gz"


def split_identity(dataset: str, split: str, targets: Sequence[int], groups: Sequence[Any] | None) -> str:
    """16 hex digits naming one test set: the sha256 of the dataset, the split, the targets in order and each
    sample's recording (``None``: every sample its own). Two cells share it exactly when they were scored on the same
    samples in the same order, which is what a paired comparison needs."""
    blob = json.dumps([dataset, split, [int(t) for t in targets], None if groups is None else list(groups)],
                      separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _pack_probabilities(probabilities: Sequence[Sequence[float]]) -> dict[str, Any]:
    """Per mille, rounded (0.001 apart: a third of the size of float16, whose noise near 0 does not compress)."""
    array = np.rint(np.asarray(probabilities, dtype=np.float64) * PER_MILLE).astype("<u2")
    return {"dtype": "uint16 per mille", "shape": list(array.shape),
            "base64": base64.b64encode(array.tobytes()).decode()}


def _unpack_probabilities(packed: dict[str, Any]) -> list[list[float]]:
    array = np.frombuffer(base64.b64decode(packed["base64"]), dtype="<u2").reshape(packed["shape"])
    return (array.astype(np.float64) / PER_MILLE).tolist()


def _cell_entry(rec: dict[str, Any], digest: str, source: str, test_sets: dict[str, dict[str, Any]]
                ) -> dict[str, Any]:
    cfg = rec["config"]
    splits: dict[str, Any] = {}
    for split, pred in sorted((rec.get("predictions") or {}).items()):
        groups = pred.get("groups")
        ident = split_identity(rec["dataset"], split, pred["targets"], groups)
        test_sets.setdefault(ident, {"dataset": rec["dataset"], "split": split, "n": len(pred["targets"]),
                                     "targets": [int(t) for t in pred["targets"]],
                                     "groups": None if groups is None else list(groups)})
        entry: dict[str, Any] = {"test_set": ident, "predictions": [int(p) for p in pred["predictions"]]}
        if pred.get("probabilities") is not None:
            entry["probabilities"] = _pack_probabilities(pred["probabilities"])
        splits[split] = entry
    prefix = rec.get("prefix")
    return {
        "cell_id": rec["cell_id"], "model": rec["model"], "dataset": rec["dataset"], "fold": int(rec["fold"]),
        "seed": int(rec["seed"]), "config_hash": rec["config_hash"], "source": source, "sha256": digest,
        "protocol": rec.get("protocol"), "recipe_name": cfg.get("recipe_name"), "recipe": cfg.get("recipe"),
        "hparams": cfg.get("hparams") or {}, "model_source": cfg.get("model_source", "builtin"),
        "model_revision": int(cfg.get("model_revision", 1)), "dataset_revision": int(cfg.get("dataset_revision", 1)),
        "dataset_kwargs": cfg.get("dataset_kwargs") or {}, "evaluation": cfg.get("evaluation", "validation"),
        "subset": cfg.get("subset"), "refit": bool(cfg.get("refit")), "prefixes": cfg.get("prefixes"),
        "metrics": {split: {k: m[k] for k in _METRICS if k in m}
                    for split, m in sorted((rec.get("metrics") or {}).items()) if m and split != "val"},
        "prefix": None if not prefix else {k: prefix[k] for k in ("fractions", "steps", "accuracy",
                                                                 "balanced_accuracy", "earliness") if k in prefix},
        "params": rec.get("params"), "seconds": rec.get("seconds"), "cpu": rec.get("cpu"),
        "splits": splits,
    }


def _tuning(folders: Iterable[Path], root: Path | None) -> dict[str, dict[str, dict[str, Any]]]:
    """Per model and dataset, the tuning trials found under ``folders`` (ok cells of ``evaluation: tuning``):
    configurations (distinct config hashes) and cells, in total and per folder."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    seen: dict[tuple[str, str, str], set[str]] = {}
    for folder in folders:
        name = str(folder.relative_to(root)) if root is not None and folder.is_relative_to(root) else folder.name
        for path in cell_files(folder, recursive=True):
            rec = read_record(path)
            if isinstance(rec, InvalidCell) or rec.get("status") != "ok" \
                    or (rec.get("config") or {}).get("evaluation") != "tuning":
                continue  # a trial reads no test split: a cell that did is no tuning trial
            entry = out.setdefault(rec["model"], {}).setdefault(rec["dataset"], {"configurations": 0, "cells": 0,
                                                                                 "folders": {}})
            where = entry["folders"].setdefault(name, {"configurations": 0, "cells": 0})
            hashes = seen.setdefault((rec["model"], rec["dataset"], name), set())
            if rec["config_hash"] not in hashes:
                hashes.add(rec["config_hash"])
                where["configurations"] += 1
                entry["configurations"] += 1
            where["cells"] += 1
            entry["cells"] += 1
    return {m: dict(sorted(d.items())) for m, d in sorted(out.items())}


def build_set(folders: Sequence[Path], name: str, version: int, *, recipes: Sequence[str] | None = None,
              tuning: Sequence[Path] = (), root: Path | None = None, about: str = "",
              tuning_note: str = "") -> dict[str, Any]:
    """The set of the ok cells under ``folders`` (of ``recipes``, default all), with the tuning trials found under
    ``tuning``; paths are written relative to ``root``. Two cells of one id (the same cell in two folders) are an
    error unless their files are the same bytes."""
    if not _ID.match(f"{name}-v{version}"):
        raise ConfigError(f"published set name {name!r}: lower-case letters, digits, _ and - only")
    test_sets: dict[str, dict[str, Any]] = {}
    cells: dict[str, dict[str, Any]] = {}
    sources = []
    for folder in folders:
        label = str(folder.relative_to(root)) if root is not None and folder.is_relative_to(root) else folder.name
        count = 0
        for path in cell_files(folder):
            rec = read_record(path)
            if isinstance(rec, InvalidCell):
                raise ResultsError(f"{rec}: a published set is built from valid cells only")
            if rec.get("status") != "ok" or (recipes and rec["config"].get("recipe_name") not in recipes):
                continue
            digest = hashlib.sha256(read_cell_bytes(path)).hexdigest()
            if rec["cell_id"] in cells:
                if cells[rec["cell_id"]]["sha256"] != digest:
                    raise ResultsError(f"{path}: cell {rec['cell_id']} is also in {cells[rec['cell_id']]['source']}"
                                       f" with other contents")
                continue
            cells[rec["cell_id"]] = _cell_entry(rec, digest, label, test_sets)
            count += 1
        sources.append({"folder": label, "cells": count})
    if not cells:
        raise ResultsError(f"no ok cell under {', '.join(map(str, folders))}: nothing to publish")
    return {"format": SET_FORMAT, "set": f"{name}-v{version}", "name": name, "version": version, "about": about,
            "built_from": sources, "tuning_note": tuning_note,
            "tuning": _tuning(tuning, root), "test_sets": dict(sorted(test_sets.items())),
            "cells": [cells[k] for k in sorted(cells)]}


def encode_set(data: dict[str, Any]) -> bytes:
    """The set's canonical JSON bytes (sorted keys, no spaces): what ``--check`` compares and the digest covers."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


@dataclass
class PublishedSet:
    """A loaded set: its id, where it came from, its sha256 (of the canonical JSON) and its data."""

    set_id: str
    where: str
    sha256: str
    data: dict[str, Any]

    @property
    def cells(self) -> list[dict[str, Any]]:
        return list(self.data["cells"])

    def tuning(self, model: str, dataset: str) -> dict[str, Any] | None:
        return (self.data.get("tuning") or {}).get(model, {}).get(dataset)

    def record(self, cell: dict[str, Any]) -> dict[str, Any]:
        """``cell`` as a cell record: what :func:`~tactile_zoo.bench.intervals.records_interval` and
        :func:`~tactile_zoo.bench.paired.records_paired` read (predictions with their targets and recordings)."""
        predictions = {}
        for split, entry in cell["splits"].items():
            test_set = self.data["test_sets"][entry["test_set"]]
            pred: dict[str, Any] = {"targets": test_set["targets"], "predictions": entry["predictions"]}
            if test_set["groups"] is not None:
                pred["groups"] = test_set["groups"]
            if "probabilities" in entry:
                pred["probabilities"] = _unpack_probabilities(entry["probabilities"])
            predictions[split] = pred
        config = {k: cell[k] for k in ("recipe_name", "recipe", "hparams", "model_source", "model_revision",
                                       "dataset_revision", "dataset_kwargs", "evaluation", "subset", "refit",
                                       "prefixes")}
        return {"cell_id": cell["cell_id"], "model": cell["model"], "dataset": cell["dataset"], "fold": cell["fold"],
                "seed": cell["seed"], "config_hash": cell["config_hash"], "protocol": cell["protocol"],
                "status": "ok", "config": {"model": cell["model"], "dataset": cell["dataset"], **config},
                "metrics": cell["metrics"], "prefix": cell["prefix"], "predictions": predictions,
                "params": cell.get("params"), "seconds": cell.get("seconds")}

    def records(self, *, model: str | None = None, dataset: str | None = None, recipe: str | None = None
                ) -> list[dict[str, Any]]:
        return [self.record(c) for c in self.data["cells"] if (model is None or c["model"] == model)
                and (dataset is None or c["dataset"] == dataset) and (recipe is None or c["recipe_name"] == recipe)]


def _packaged() -> Any:
    return resources.files("tactile_zoo").joinpath("published")


def packaged_sets() -> list[str]:
    """The ids of the sets packaged with tactile-zoo, oldest version first."""
    folder = _packaged()
    found = []
    for entry in folder.iterdir() if folder.is_dir() else ():  # not a bench folder
        match = _ID.match(entry.name.removesuffix(".json.gz")) if entry.name.endswith(".json.gz") else None
        if match:
            found.append((match["name"], int(match["version"]), entry.name.removesuffix(".json.gz")))
    return [ident for *_, ident in sorted(found)]


def _parse(raw: bytes, where: str) -> dict[str, Any]:
    try:
        data = json.loads(gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw)
    except (OSError, EOFError, ValueError) as exc:
        raise ResultsError(f"{where}: not a published set ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("format"), int) or "cells" not in data:
        raise ResultsError(f"{where}: not a published set (no format and cells)")
    if data["format"] > SET_FORMAT:
        raise ResultsError(f"{where}: a published set of format {data['format']}, written by a newer tactile-zoo "
                           f"(this one reads format {SET_FORMAT}): upgrade tactile-zoo")
    for ident, test_set in data.get("test_sets", {}).items():  # a pairing trusts these names: each is checked
        if split_identity(test_set["dataset"], test_set["split"], test_set["targets"], test_set["groups"]) != ident:
            raise ResultsError(f"{where}: test set {ident} ({test_set['dataset']}, {test_set['split']}) is not the "
                               f"test set its split identity names: the set is damaged")
    for cell in data["cells"]:
        for split, entry in cell["splits"].items():
            test_set = data["test_sets"].get(entry["test_set"])
            if test_set is None or len(entry["predictions"]) != test_set["n"]:
                raise ResultsError(f"{where}: cell {cell['cell_id']}, split {split}: its predictions do not match "
                                   f"its test set {entry['test_set']}: the set is damaged")
    return data


def load_set(ref: str | Path, *, base: Path | None = None, key: str = "against.set") -> PublishedSet:
    """The set ``ref`` names: ``published`` (the newest packaged set), a packaged set's id (``table1-v1``), or the
    path of a set file (relative to ``base``). An unknown one is a :class:`ConfigError` naming ``key``, the value and
    the sets there are."""
    text = str(ref)
    packaged = packaged_sets()
    if text == PUBLISHED:
        if not packaged:
            # a checkout builds its sets from the committed cells: they are results, committed once, as cells
            raise ConfigError(f"{key}: {PUBLISHED!r}: no published set is packaged with this tactile-zoo (in a git "
                              "checkout, `make install` or `python -m tools.published_set` builds it)")
        text = packaged[-1]
    if text in packaged:
        raw = _packaged().joinpath(set_file_name(text)).read_bytes()
        where = f"published set {text}"
    else:
        path = Path(text).expanduser()
        path = path if path.is_absolute() or base is None else base / path
        if not path.is_file():
            raise ConfigError(f"{key}: {text!r} is neither a published set packaged with tactile-zoo "
                              f"({', '.join(packaged) or 'none'}; {PUBLISHED!r}: the newest) nor a set file")
        raw, where = path.read_bytes(), str(path)
    data = _parse(raw, where)
    return PublishedSet(str(data.get("set")), where, hashlib.sha256(encode_set(data)).hexdigest(), data)
