"""One set of pretrained weights: :class:`WeightEntry`, its manifest form, and the tag scheme.

A weight entry says what a ``.safetensors`` file holds and what it expects: the model and the hyper-parameters that
rebuild it, the dataset it was trained on with the spec (classes, taxels, channels, globals, steps) and the loading
options (``dataset_kwargs``: windows, normalisation) its inputs went through, the resolved preprocessing
(``preprocessing``: every loading option with its default filled in, the frame period, and how many input frames the
model sums or averages into one step), the recipe and the cell's config hash, the test accuracy, the commit that
trained it, the licences, a note, and where the file is (a path, a URL, or both) with its sha256.

Tags follow timm's ``model.tag`` style::

    <model>.<recipe>_<dataset>[_f<fold>][_s<seed>]        e.g. x_tacformer.source_ev_objects

the fold and seed parts only when they are not 0 (the shipped weights are fold 0, seed 0). Tags compare normalised
(case, ``-`` and ``_`` in the model part ignored, like registry names), and a distribution's entry is also reachable as
``<distribution>:<tag>``.

Manifest (JSON), the format a distribution ships and :func:`~tactile_zoo.weights.manifest.read_manifest` reads::

    {"format": "tactile-zoo-weights/1",
     "weights": [{"tag": "x_tacformer.source_ev_objects", "model": "x_tacformer", "dataset": "ev_objects",
                  "spec": {"name": "ev_objects", "num_classes": 36, "class_names": [...], "num_steps": 250,
                           "num_nodes": 39, "num_channels": 2, "num_globals": 0, "sensor": "neutouch"},
                  "hparams": {}, "dataset_kwargs": {},
                  "preprocessing": {"dataset_options": {"verify_checksum": true}, "frame_period_s": null,
                                    "frame_bin_size": 5},
                  "recipe": "source", "loss": "ce",
                  "config_hash": "bcbb8a08732c9ba1", "cell_id": "x_tacformer__ev_objects__f0__s0__bcbb8a08732c9ba1",
                  "seed": 0, "fold": 0, "model_revision": 2, "dataset_revision": 1, "accuracy": 0.8819,
                  "commit": "f17f027...", "file": "x_tacformer.source_ev_objects.safetensors", "url": null,
                  "sha256": "<64 hex>", "bytes": 1234567, "licence": "MIT", "dataset_licence": "...",
                  "note": "Ev-Objects class names are unverified"}]}

Required: ``tag``, ``model``, ``dataset``, ``spec``, ``sha256`` and ``file`` or ``url``; a relative ``file`` is
relative to the manifest's folder. An unknown key is an error (a typo must not pass silently). ``preprocessing`` is
descriptive (loading never reads it: ``dataset_kwargs`` and ``hparams`` rebuild the inputs and the model); a manifest
written before it existed reads as ``{}``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..registry import normalize_name

__all__ = ["WeightEntry", "MANIFEST_FORMAT", "ENTRY_KEYS", "make_tag", "tag_key"]

MANIFEST_FORMAT = "tactile-zoo-weights/1"
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_SPEC_KEYS = ("name", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals", "sensor")


def _bare(model: str) -> str:
    """A model name without its ``distribution:`` qualifier."""
    return str(model).rpartition(":")[2]


def make_tag(model: str, dataset: str, recipe: str = "source", *, fold: int = 0, seed: int = 0) -> str:
    """The tag of weights of ``model`` trained on ``dataset`` with ``recipe`` (see the module docstring).

    Example: ``make_tag("x_tacformer", "ev_objects")`` is ``"x_tacformer.source_ev_objects"``.
    """
    suffix = f"{recipe}_{_bare(dataset)}" + (f"_f{fold}" if fold else "") + (f"_s{seed}" if seed else "")
    return f"{_bare(model)}.{suffix}"


def tag_key(tag: str) -> str:
    """The comparison key of a tag: the model part normalised like a registry name, the rest lower case with ``-``
    read as ``_`` (``X-Tacformer.Source_Ev-Objects`` -> ``xtacformer.source_ev_objects``)."""
    model, dot, rest = str(tag).strip().partition(".")
    return f"{normalize_name(model)}{dot}{rest.lower().replace('-', '_')}"


@dataclass(frozen=True)
class WeightEntry:
    """One set of pretrained weights and everything needed to use it (the manifest keys of the module docstring).

    Args:
        tag: ``<model>.<recipe>_<dataset>[...]`` (see :func:`make_tag`).
        model: the registry name of the model.
        dataset: the registry name of the dataset the weights were trained on.
        spec: that dataset's :class:`~tactile_zoo.data.spec.DatasetSpec` as a dict (``to_dict``).
        sha256: the sha256 of the ``.safetensors`` file.
        file: where the file is: absolute, or relative to ``base_dir`` (the manifest's folder).
        url: where to download it from (http or https) when ``file`` is absent.
        bytes: the file's size.
        hparams: the model's constructor keywords (``max_frames``, ``bin_size``, ...).
        dataset_kwargs: the dataset's keyword arguments the inputs were prepared with (``window``, ``normalize``...).
        preprocessing: what the inputs went through, resolved (:func:`~.manifest.preprocessing_of`):
            ``dataset_options`` (``dataset_kwargs`` with every default filled in), ``frame_period_s`` (seconds
            between time steps, ``None`` when not known) and ``frame_bin_size`` (input frames the model sums or
            averages into one of its steps; ``None``: the model reads every frame as is).
        recipe, loss: the training recipe's name and its loss (``"ce"``, or ``"mse_rate"``: scores are spike rates).
        config_hash, cell_id, seed, fold: the harness cell that trained the weights.
        model_revision, dataset_revision: the computational revisions the weights were trained under; loading
            refuses weights whose model revision differs from the installed model's.
        accuracy: the cell's test accuracy.
        commit: the tactile-zoo commit that trained them.
        licence, dataset_licence: the weights' licence, and the terms of the data they were trained on.
        note: anything a user must know (e.g. unverified class names).
        origin: where the entry was read (a distribution and version, or a manifest path); not in the manifest.
        base_dir: the folder a relative ``file`` is relative to; not in the manifest.
        dist: the distribution that ships the entry (``None`` for a local manifest); not in the manifest.
    """

    tag: str
    model: str
    dataset: str
    spec: Mapping[str, Any]
    sha256: str
    file: str | None = None
    url: str | None = None
    bytes: int | None = None
    hparams: Mapping[str, Any] = field(default_factory=dict)
    dataset_kwargs: Mapping[str, Any] = field(default_factory=dict)
    preprocessing: Mapping[str, Any] = field(default_factory=dict)
    recipe: str = "source"
    loss: str = "ce"
    config_hash: str | None = None
    cell_id: str | None = None
    seed: int | None = None
    fold: int = 0
    model_revision: int | None = None
    dataset_revision: int | None = None
    accuracy: float | None = None
    commit: str | None = None
    licence: str = ""
    dataset_licence: str = ""
    note: str = ""
    origin: str = field(default="", compare=False)
    base_dir: str | None = field(default=None, compare=False)
    dist: str | None = field(default=None, compare=False)

    @property
    def qualified_tag(self) -> str:
        """``<distribution>:<tag>`` for an installed entry, the tag otherwise."""
        return f"{self.dist}:{self.tag}" if self.dist else self.tag

    @property
    def num_classes(self) -> int:
        return int(self.spec["num_classes"])

    @property
    def class_names(self) -> tuple[str, ...]:
        return tuple(str(c) for c in self.spec["class_names"])

    def local_path(self) -> Path | None:
        """``file`` resolved against ``base_dir`` (``None`` when the entry has no file)."""
        if not self.file:
            return None
        path = Path(self.file).expanduser()
        return path if path.is_absolute() or self.base_dir is None else Path(self.base_dir) / path

    def dataset_spec(self) -> Any:
        """The :class:`~tactile_zoo.data.spec.DatasetSpec` the weights were trained for (sensor from the registry)."""
        from ..data.spec import DatasetSpec

        return DatasetSpec.from_dict(self.spec, where=f"weights {self.tag!r}")

    def to_dict(self) -> dict[str, Any]:
        """The manifest form (every key of the module docstring; ``origin``, ``base_dir``, ``dist`` left out)."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self) if f.name not in _RUNTIME}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], where: str = "manifest entry", *, base_dir: str | Path | None = None,
                  origin: str = "", dist: str | None = None) -> WeightEntry:
        """Check a manifest entry and build the :class:`WeightEntry`; every problem is a :class:`ConfigError` that
        starts with ``where``."""
        if not isinstance(values, Mapping):
            raise ConfigError(f"{where}: an entry must be a JSON object, got {type(values).__name__}")
        label = f"{where} ({values.get('tag')!r})" if isinstance(values.get("tag"), str) else where
        unknown = sorted(set(values) - ENTRY_KEYS)
        if unknown:
            raise ConfigError(f"{label}: unknown key(s) {unknown}; known: {sorted(ENTRY_KEYS)}")
        missing = [k for k in ("tag", "model", "dataset", "spec", "sha256") if values.get(k) in (None, "")]
        if missing:
            raise ConfigError(f"{label}: missing {', '.join(missing)}")
        for key in ("tag", "model", "dataset", "sha256", "recipe", "loss", "licence", "dataset_licence", "note"):
            if key in values and not isinstance(values[key], str):
                raise ConfigError(f"{label}: {key} must be a string, got {values[key]!r}")
        for key in ("file", "url", "config_hash", "cell_id", "commit"):
            if values.get(key) is not None and not isinstance(values[key], str):
                raise ConfigError(f"{label}: {key} must be a string or null, got {values[key]!r}")
        for key in ("bytes", "seed", "fold", "model_revision", "dataset_revision"):
            value = values.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise ConfigError(f"{label}: {key} must be a non-negative integer, got {value!r}")
        accuracy = values.get("accuracy")
        if accuracy is not None and (isinstance(accuracy, bool) or not isinstance(accuracy, int | float)):
            raise ConfigError(f"{label}: accuracy must be a number or null, got {accuracy!r}")
        for key in ("hparams", "dataset_kwargs", "preprocessing", "spec"):
            if key in values and not isinstance(values[key], Mapping):
                raise ConfigError(f"{label}: {key} must be a JSON object, got {values[key]!r}")
        absent = [k for k in _SPEC_KEYS if k not in values["spec"]]
        if absent:
            raise ConfigError(f"{label}: spec lacks {', '.join(absent)}")
        tag, model = values["tag"].strip(), values["model"].strip()
        if not re.fullmatch(r"[^\s:.]+\.[^\s:]+", tag) or normalize_name(tag.partition(".")[0]) != normalize_name(
                _bare(model)):
            raise ConfigError(f"{label}: tag must read <model>.<name> with the entry's model {_bare(model)!r} before "
                              f"the dot (e.g. {make_tag(model, values['dataset'])!r}), got {tag!r}")
        sha = values["sha256"].strip().lower()
        if not _SHA256.match(sha):
            raise ConfigError(f"{label}: sha256 must be 64 hexadecimal digits, got {values['sha256']!r}")
        if not values.get("file") and not values.get("url"):
            raise ConfigError(f"{label}: give file (a path), url (http/https), or both")
        url = values.get("url")
        if url and not re.match(r"^https?://", url, re.IGNORECASE):
            raise ConfigError(f"{label}: url must be an http(s) URL, got {url!r}")
        kwargs = {k: v for k, v in values.items() if k not in ("tag", "model", "sha256")}
        kwargs.update(hparams=dict(values.get("hparams") or {}), spec=dict(values["spec"]),
                      dataset_kwargs=dict(values.get("dataset_kwargs") or {}),
                      preprocessing=dict(values.get("preprocessing") or {}), fold=int(values.get("fold") or 0))
        if accuracy is not None:
            kwargs["accuracy"] = float(accuracy)
        return cls(tag=tag, model=model, sha256=sha, origin=origin, dist=dist,
                   base_dir=None if base_dir is None else str(base_dir), **kwargs)


_RUNTIME = frozenset({"origin", "base_dir", "dist"})
#: The keys a manifest entry may have.
ENTRY_KEYS = frozenset(f.name for f in fields(WeightEntry)) - _RUNTIME


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value
