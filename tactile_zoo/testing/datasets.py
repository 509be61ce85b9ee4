"""The dataset contract as named rules, and :func:`check_dataset`, which runs them on a registered name or a class.

The rules, in the order they run:

- ``metadata``: the metadata passes ``register_dataset``'s checks and names the sensor (registered, with the
  metadata's taxel count), the counts (classes, steps, taxels, channels, globals), the folds, the splits and the
  protocol.
- ``loads``: every split of fold ``fold`` loads as a non-empty dataset with ``.spec`` and ``.num_folds`` (the
  metadata's folds, when no loader keywords are given).
- ``spec``: every split has the same spec, and it agrees with the metadata (the sensor object included).
- ``samples``: every sample (up to ``max_samples`` a split) is ``x float32 (T, N, C)``, ``g float32 (T, G)`` of the
  spec's sizes, finite, with an integer label in ``[0, num_classes)``.
- ``labels``: every class occurs in the training split.
- ``disjoint``: no sample of one split is also in another (same ``x`` and ``g``): the train/test separation every
  built-in protocol promises. Skip it for a protocol that shares samples on purpose.
- ``deterministic``: loading a split again gives the same samples in the same order (the validation split is carved
  deterministically per fold).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import torch

from .. import registry
from ..registry.entries import _check_meta
from ._contract import ContractReport, Runner, Skipped, expect

__all__ = ["DATASET_RULES", "check_dataset"]

#: The dataset rules, in the order :func:`check_dataset` runs them (the module docstring says what each checks).
DATASET_RULES = ("metadata", "loads", "spec", "samples", "labels", "disjoint", "deterministic")
REQUIRED_META = ("sensor", "num_classes", "num_steps", "num_nodes", "num_channels", "num_globals", "folds", "splits",
                 "protocol")
COUNTS = ("num_classes", "num_steps", "num_nodes", "num_channels", "num_globals")


class _Subject:
    """The dataset under check: its name, its loader and its metadata (registered, or the class's ``zoo_meta``)."""

    def __init__(self, dataset: str | Callable[..., Any], meta: Mapping[str, Any] | None) -> None:
        if isinstance(dataset, str):
            entry = registry.get_dataset_entry(dataset)
            self.name, self.loader = registry.listed_name(entry), entry.obj
            self.meta: Mapping[str, Any] = entry.meta if meta is None else meta
        else:
            self.name = getattr(dataset, "name", None) or getattr(dataset, "__name__", type(dataset).__name__)
            self.loader = dataset
            self.meta = (getattr(dataset, "zoo_meta", None) or {}) if meta is None else meta

    def load(self, split: str, root: Any, fold: int, download: bool, kwargs: Mapping[str, Any]) -> Any:
        return self.loader(root=root, split=split, fold=fold, download=download, **kwargs)


def _metadata(subject: _Subject) -> None:
    meta = _check_meta("dataset", subject.name, subject.meta)
    missing = [key for key in REQUIRED_META if key not in meta]
    expect(not missing, f"metadata lacks {missing}")
    sensor = registry.get_sensor(meta["sensor"])
    expect(sensor.num_nodes == meta["num_nodes"], f"metadata num_nodes={meta['num_nodes']}, but sensor "
                                                  f"{sensor.name!r} has {sensor.num_nodes} taxels")
    if "class_names" in meta:
        expect(len(meta["class_names"]) == meta["num_classes"],
               f"{len(meta['class_names'])} class names for num_classes={meta['num_classes']}")
    expect(int(meta["folds"]) >= 1 and meta["splits"] and "train" in meta["splits"] and "test" in meta["splits"],
           f"metadata folds={meta['folds']!r}, splits={meta['splits']!r}: need folds >= 1 and train and test splits")


def _loads(subject: _Subject, split: str, root: Any, fold: int, download: bool, kwargs: Mapping[str, Any],
           validate: bool) -> Any:
    data = subject.load(split, root, fold, download, kwargs)
    if not validate:
        return data
    for attr in ("spec", "num_folds"):
        expect(hasattr(data, attr), f"the {split!r} split has no .{attr}")
    expect(len(data) > 0, f"the {split!r} split is empty")
    folds = subject.meta.get("folds")
    if folds is not None and not kwargs:
        expect(data.num_folds == folds, f"num_folds is {data.num_folds}, the metadata says {folds}")
    return data


def _spec(subject: _Subject, loaded: Mapping[str, Any], kwargs: Mapping[str, Any]) -> None:
    specs = {split: data.spec for split, data in loaded.items()}
    first_split, spec = next(iter(specs.items()))
    for split, other in specs.items():
        expect(other == spec, f"the {split!r} split's spec differs from the {first_split!r} split's")
    meta = subject.meta
    for key in COUNTS:
        if key in meta and key not in kwargs:  # a loader keyword (num_steps=24) may change a count on purpose
            expect(getattr(spec, key) == meta[key], f"spec {key}={getattr(spec, key)}, the metadata says {meta[key]}")
    if "class_names" in meta:
        expect(tuple(spec.class_names) == tuple(meta["class_names"]), "the spec's class names differ from the "
                                                                      "metadata's")
    if "sensor" in meta:
        expect(spec.sensor is registry.get_sensor(meta["sensor"]),
               f"the spec's sensor {spec.sensor.name!r} is not the registered sensor {meta['sensor']!r}")


def _digest(x: torch.Tensor, g: torch.Tensor) -> str:
    h = hashlib.sha1(usedforsecurity=False)
    for t in (x, g):
        h.update(str(tuple(t.shape)).encode())
        h.update(t.detach().contiguous().cpu().numpy().tobytes())
    return h.hexdigest()


def _samples(data: Any, split: str, max_samples: int, validate: bool) -> list[tuple[str, int]]:
    """Check the samples of one split (unless ``validate`` is off); return their (digest, label)."""
    spec = data.spec
    out = []
    for i in range(min(len(data), max_samples)):
        x, g, y = data[i]
        if not validate:
            out.append((_digest(x, g), y))
            continue
        where = f"sample {i} of the {split!r} split"
        expect(isinstance(x, torch.Tensor) and x.dtype == torch.float32, f"{where}: x is not a float32 tensor")
        expect(isinstance(g, torch.Tensor) and g.dtype == torch.float32, f"{where}: g is not a float32 tensor")
        shape = (spec.num_steps, spec.num_nodes, spec.num_channels)
        expect(tuple(x.shape) == shape, f"{where}: x has shape {tuple(x.shape)}, the spec says (T, N, C) = {shape}")
        expect(tuple(g.shape) == (spec.num_steps, spec.num_globals),
               f"{where}: g has shape {tuple(g.shape)}, the spec says (T, G) = {(spec.num_steps, spec.num_globals)}")
        expect(torch.isfinite(x).all() and torch.isfinite(g).all(), f"{where}: non-finite values")
        expect(isinstance(y, int) and not isinstance(y, bool), f"{where}: label {y!r} is not an int")
        expect(0 <= y < spec.num_classes, f"{where}: label {y} outside [0, {spec.num_classes})")
        out.append((_digest(x, g), y))
    return out


def _labels(samples: Mapping[str, list[tuple[str, int]]], num_classes: int) -> None:
    if "train" not in samples:
        raise Skipped("no training split checked")
    missing = sorted(set(range(num_classes)) - {y for _, y in samples["train"]})
    expect(not missing, f"classes {missing[:10]} never occur in the training split")


def _disjoint(samples: Mapping[str, list[tuple[str, int]]]) -> None:
    seen: dict[str, str] = {}
    for split, rows in samples.items():
        for digest in {d for d, _ in rows}:
            expect(digest not in seen, f"a sample of the {split!r} split is also in the {seen.get(digest)!r} split")
            seen[digest] = split


def _deterministic(subject: _Subject, split: str, rows: list[tuple[str, int]], root: Any, fold: int,
                   kwargs: Mapping[str, Any]) -> None:
    again = subject.load(split, root, fold, False, kwargs)
    expect(len(again) >= len(rows), f"loading the {split!r} split again gives {len(again)} samples, not {len(rows)}")
    for i, (digest, y) in enumerate(rows):
        x, g, label = again[i]
        expect(_digest(x, g) == digest and label == y, f"loading the {split!r} split again gives another sample {i}")


def check_dataset(dataset: str | Callable[..., Any], *, root: Any = None, splits: Sequence[str] | None = None,
                  fold: int = 0, download: bool = False, meta: Mapping[str, Any] | None = None,
                  rules: Iterable[str] | None = None, skip: Iterable[str] = (), max_samples: int = 2000,
                  **kwargs: Any) -> ContractReport:
    """Check a dataset against the dataset contract; raise one :class:`~tactile_zoo.testing.ContractError` on the
    first rule it breaks.

    Args:
        dataset: a registered dataset name, or the class or loader ``f(root, split, fold, download, **kw)`` itself
            (its metadata is then its ``zoo_meta`` attribute, or ``meta``).
        root: the data home (default: as :func:`~tactile_zoo.registry.load_dataset`).
        splits: the splits to check (default: the metadata's ``splits``, else train, val and test).
        fold: the fold to check.
        download: let the loader fetch missing raw files.
        meta: metadata to check instead of the registered (or ``zoo_meta``) one.
        rules: run only these rules (default: all of :data:`DATASET_RULES`).
        skip: rules not to run (``disjoint`` for a protocol that shares samples between splits on purpose). The
            splits are loaded and read whatever is skipped: skipping ``loads`` or ``samples`` drops their checks.
        max_samples: samples read per split (the ``disjoint`` rule compares only those).
        **kwargs: loader keywords (a simulator's ``n_train_per_class=3`` keeps the check small).

    Returns:
        The report: every rule that held, and every rule that did not apply, with the split.

    Raises:
        ContractError: the rule broken, the dataset, the split and what was wrong.
    """
    subject = _Subject(dataset, meta)
    run = Runner(subject.name, "dataset", DATASET_RULES, rules, skip)
    run.run("metadata", _metadata, subject)
    splits = list(splits or subject.meta.get("splits") or ("train", "val", "test"))
    # the other rules read what these two load: they always load, and skipping them drops only their checks
    checks = run.wants("loads")
    loaded = {split: run.guard("loads", _loads, subject, split, root, fold, download, kwargs, checks, where=split)
              for split in splits}
    run.report.passed += [("loads", split) for split in splits if checks]
    run.run("spec", _spec, subject, loaded, kwargs)
    checks = run.wants("samples")
    samples = {split: run.guard("samples", _samples, data, split, max_samples, checks, where=split)
               for split, data in loaded.items()}
    run.report.passed += [("samples", split) for split in splits if checks]
    num_classes = next(iter(loaded.values())).spec.num_classes
    run.run("labels", _labels, samples, num_classes, where="train")
    run.run("disjoint", _disjoint, samples)
    for split in splits:
        run.run("deterministic", _deterministic, subject, split, samples[split], root, fold, kwargs, where=split)
    return run.report
