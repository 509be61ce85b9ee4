"""Manifest files: reading and writing them, and turning a harness cell record into an entry.

A manifest is a JSON file ``{"format": "tactile-zoo-weights/1", "weights": [entry, ...]}`` (the entry keys are in
:mod:`tactile_zoo.weights.entry`). A relative ``file`` in it is relative to the manifest's own folder, so a folder
holding the manifest and its ``.safetensors`` files can be moved or shipped inside a distribution as is.

:func:`entry_from_record` is the bridge from ``tactile-zoo bench --save-weights``: the cell record (``cells/<id>.json``)
already holds the model, hyper-parameters, recipe, dataset options, spec, config hash, commit, test accuracy and the
weights file's sha256; the entry copies them, so published weights are exactly a committed cell's. It adds what the
record leaves implicit (:func:`preprocessing_of`): the dataset options with their defaults, the frame period and the
model's frame binning, so a user feeding a robot's readings sees every step the training inputs went through.
"""

from __future__ import annotations

import functools
import inspect
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .._files import atomic_write_text
from ..data.preprocess import RecordingPreprocessing
from ..errors import ConfigError, UnknownNameError
from .entry import MANIFEST_FORMAT, WeightEntry, make_tag, tag_key

__all__ = ["read_manifest", "parse_manifest", "write_manifest", "entry_from_record", "unpublishable",
           "preprocessing_of", "dataset_options", "entry_preprocessing", "checkpoint_preprocessing", "DEFAULT_LICENCE",
           "CUSTOM_RECIPE", "recipe_changes"]

#: The licence of weights trained by tactile-zoo (the project's own); the data they were trained on keep their terms.
DEFAULT_LICENCE = "MIT (the weights, like tactile-zoo); the training data keep their own terms (dataset_licence)"


def parse_manifest(document: Any, where: str, *, base_dir: str | Path | None = None, origin: str = "",
                   dist: str | None = None) -> list[WeightEntry]:
    """The entries of a loaded manifest ``document``; ``where`` names it in every error (a :class:`ConfigError`)."""
    if isinstance(document, list):  # a bare list of entries is accepted too
        document = {"format": MANIFEST_FORMAT, "weights": document}
    if not isinstance(document, Mapping):
        raise ConfigError(f"{where}: a weights manifest must be a JSON object with 'format' and 'weights', got "
                          f"{type(document).__name__}")
    if document.get("format") != MANIFEST_FORMAT:
        raise ConfigError(f"{where}: format must be {MANIFEST_FORMAT!r}, got {document.get('format')!r}")
    unknown = sorted(set(document) - {"format", "weights", "description"})
    if unknown:
        raise ConfigError(f"{where}: unknown top-level key(s) {unknown}; expected format, weights (and description)")
    items = document.get("weights")
    if not isinstance(items, list):
        raise ConfigError(f"{where}: 'weights' must be a list of entries, got {type(items).__name__}")
    entries = [WeightEntry.from_dict(item, f"{where}: entry {i}", base_dir=base_dir, origin=origin or where,
                                     dist=dist) for i, item in enumerate(items)]
    seen: dict[str, str] = {}
    for entry in entries:
        key = tag_key(entry.tag)
        if key in seen:
            raise ConfigError(f"{where}: tag {entry.tag!r} appears twice (also as {seen[key]!r})")
        seen[key] = entry.tag
    return entries


def read_manifest(path: str | os.PathLike, *, origin: str = "", dist: str | None = None) -> list[WeightEntry]:
    """The entries of the manifest file ``path`` (relative files resolve against its folder)."""
    path = Path(path).expanduser()
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"weights manifest {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"weights manifest {path} cannot be read: {exc}") from None
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"weights manifest {path} is not valid JSON: {exc}") from None
    return parse_manifest(document, f"weights manifest {path}", base_dir=path.resolve().parent,
                          origin=origin or str(path), dist=dist)


def write_manifest(entries: Iterable[WeightEntry], path: str | os.PathLike, description: str | None = None) -> Path:
    """Write ``entries`` as a manifest at ``path`` (atomically). A file inside the manifest's folder is written
    relative to it, so the folder can move; any other file keeps its absolute path."""
    path = Path(path).expanduser()
    folder = path.resolve().parent
    items = []
    for entry in entries:
        item = entry.to_dict()
        local = entry.local_path()
        if local is not None:
            resolved = local.resolve()
            item["file"] = str(resolved.relative_to(folder)) if resolved.is_relative_to(folder) else str(resolved)
        items.append(item)
    document: dict[str, Any] = {"format": MANIFEST_FORMAT, **({"description": description} if description else {}),
                                "weights": items}
    parse_manifest(document, f"weights manifest {path}")  # what is written must read back
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(document, indent=2) + "\n")
    return path


#: The base dataset's keywords: how a split is augmented or wrapped, never how its samples are made.
#: a user's own functions (``transform``, ``pre_transform``) are hooks, not a dataset option a weight entry can record
_NOT_PREPROCESSING = frozenset({"root", "split", "fold", "download", "transform", "pre_transform", "augment",
                                "augment_factor", "augment_seed"})


def _json_value(value: Any) -> Any:
    """``value`` as JSON holds it (tuples as lists); anything else as its ``repr``, so the manifest still says it."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _json_value(v) for k, v in value.items()}
    return repr(value)


def dataset_options(cls: type, dataset_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword options of dataset class ``cls`` (its constructor's keyword-only parameters, defaults filled in)
    with ``dataset_kwargs`` applied: what loading the dataset with those keywords used."""
    options: dict[str, Any] = {}
    for param in inspect.signature(cls.__init__).parameters.values():
        if param.kind is param.KEYWORD_ONLY and param.name not in _NOT_PREPROCESSING:
            options[param.name] = _json_value(param.default) if param.default is not param.empty else None
    options.update({str(k): _json_value(v) for k, v in dataset_kwargs.items()})
    return options


@functools.lru_cache(maxsize=64)
def _frame_bin_size(model: str, spec_json: str, hparams_json: str) -> int | None:
    """``bin_size`` of model ``model`` built for the spec (input frames per model step), ``None`` when the model has
    none or cannot be built here. Cached: a report describes many cells of one configuration."""
    import torch

    from .. import registry
    from ..data.spec import DatasetSpec

    try:
        spec = DatasetSpec.from_dict(json.loads(spec_json))
        with torch.random.fork_rng(devices=[]):  # building initialises weights: the caller's RNG stream stays put
            built = registry.instantiate_model(model, spec, **json.loads(hparams_json))
    except Exception:  # noqa: BLE001 - an unregistered plugin model: the entry is still valid without the figure
        return None
    size = getattr(built, "bin_size", None)
    return int(size) if isinstance(size, int) and not isinstance(size, bool) else None


def preprocessing_of(model: str, dataset: str, spec: Mapping[str, Any], hparams: Mapping[str, Any] | None = None,
                     dataset_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What inputs of ``dataset`` went through before ``model`` (built with ``hparams``) read them.

    Returns:
        ``{"dataset_options": ..., "frame_period_s": ..., "frame_bin_size": ...}``: the dataset's keyword options
        with ``dataset_kwargs`` applied and every default filled in (BioTac-DoS: ``window``, ``normalize``,
        ``baseline``, ``scale``...; ``None`` where the default is computed, e.g. ``stride`` = ``window``), the
        seconds between two time steps (``None`` when the dataset does not say), and the input frames the model
        sums or averages into one step (``None``: it reads every frame). A dataset or model that is not registered
        here leaves its part empty rather than failing: the entry is still usable.
    """
    from .. import registry

    hparams, dataset_kwargs = dict(hparams or {}), dict(dataset_kwargs or {})
    try:
        cls = registry.get_dataset_entry(dataset).obj
    except Exception:  # noqa: BLE001 - a dataset plugin that is not installed
        cls = None
    options = dataset_options(cls, dataset_kwargs) if isinstance(cls, type) else _json_value(dataset_kwargs)
    period = getattr(cls, "frame_period", None)
    return {"dataset_options": options, "frame_period_s": None if period is None else float(period),
            "frame_bin_size": _frame_bin_size(model, json.dumps(dict(spec), sort_keys=True),
                                              json.dumps(_json_value(hparams), sort_keys=True))}


def unpublishable(config: Mapping[str, Any]) -> str | None:
    """Why the weights of a cell with configuration ``config`` (a cell record's ``config``) cannot be published, or
    ``None``: the one rule, which ``bench --save-weights`` checks before training anything and
    :func:`entry_from_record` after."""
    if config.get("subset"):
        return f"trained on a subset of the data ({dict(config['subset'])}, --quick)"
    return None


def entry_preprocessing(entry: WeightEntry) -> RecordingPreprocessing | None:
    """The preprocessing ``entry``'s weights expect on a raw recording, as timm's pretrained configs carry their
    transforms: what their dataset's loader does to one recording with the entry's ``dataset_kwargs`` (defaults filled
    in; ``preprocessing`` says the same, for people). ``None``: the dataset feeds recordings as they are.

    Raises:
        ConfigError: the weights' dataset is not installed here, so its preprocessing is unknown.
    """
    return _dataset_preprocessing(f"weights {entry.qualified_tag}", entry.dataset, entry.dataset_kwargs)


def checkpoint_preprocessing(config: Mapping[str, Any], where: str = "the checkpoint"
                             ) -> RecordingPreprocessing | None:
    """The preprocessing a ``tactile-zoo train --save`` checkpoint (its ``config``) expects on a raw recording, as
    :func:`entry_preprocessing` gives a weight entry's: its dataset's transform with the loading options recorded in
    the checkpoint (``preprocessing.dataset_options``; a checkpoint written before they were recorded: its
    ``dataset_kwargs`` with today's defaults). ``None``: the dataset feeds recordings as they are.

    Raises:
        ConfigError: the checkpoint names no dataset, or one not installed here (``where`` names the checkpoint).
    """
    dataset = config.get("dataset")
    if not isinstance(dataset, str) or not dataset:
        raise ConfigError(f"{where} does not name the dataset it was trained on, so the preprocessing it expects is "
                          f"unknown: feed values already preprocessed with raw=True (--raw)")
    recorded = (config.get("preprocessing") or {}).get("dataset_options")
    return _dataset_preprocessing(where, dataset, config.get("dataset_kwargs") or {},
                                  recorded if isinstance(recorded, Mapping) else None)


def _dataset_preprocessing(what: str, dataset: str, dataset_kwargs: Mapping[str, Any],
                           options: Mapping[str, Any] | None = None) -> RecordingPreprocessing | None:
    """Dataset ``dataset``'s transform of one raw recording with ``options`` (default: ``dataset_kwargs`` with every
    default filled in); ``what`` (weights, a checkpoint) names the trained model in the error."""
    from .. import registry

    try:
        cls = registry.get_dataset_entry(dataset).obj
    except UnknownNameError:
        raise ConfigError(f"{what}: trained on dataset {dataset!r}, which is not installed here, so the "
                          f"preprocessing it expects is unknown: install it, or feed values already preprocessed "
                          f"with raw=True (--raw)") from None
    hook = getattr(cls, "recording_preprocessing", None)
    if hook is None or not isinstance(cls, type):
        return None
    return hook(dict(options) if options is not None else dataset_options(cls, dataset_kwargs))


#: the recipe label (and tag part) of weights whose cell did not run its named recipe as the recipe declares it
CUSTOM_RECIPE = "custom"


def recipe_changes(model: str, dataset: str, config: Mapping[str, Any]) -> str:
    """What a cell's stored ``config`` changed of its named recipe (``recipe_name``) on ``dataset``: the training keys
    (``max_epochs`` from ``--epochs``, ``--set``), the evaluation, ``--refit`` and constructor keywords it declares,
    as ``"max_epochs 1 (the recipe: 15)"``; ``""`` when it ran the recipe as declared, or when the model or dataset
    is not registered here (nothing to compare with)."""
    from ..engine.config import resolve_cell
    from ..recipe import recipe_name_of

    try:
        declared = resolve_cell(model, dataset, recipe_name=recipe_name_of(config)).to_dict()
    except Exception:  # noqa: BLE001 - a plugin that is not installed, a recipe renamed since: nothing to compare
        return ""
    changes = []

    def compare(what: str, ran: Any, wanted: Any) -> None:
        if ran != wanted:
            changes.append(f"{what} {ran!r} (the recipe: {wanted!r})")

    # only what the record stores is compared (a hand-made or older record may leave a part out)
    if isinstance(config.get("recipe"), Mapping):
        ran_recipe, wanted_recipe = dict(config["recipe"]), declared["recipe"]
        for key in sorted(set(ran_recipe) | set(wanted_recipe)):
            compare(key, ran_recipe.get(key), wanted_recipe.get(key))
    compare("evaluation", config.get("evaluation", "validation"), declared.get("evaluation", "validation"))
    compare("refit", bool(config.get("refit")), bool(declared["refit"]))
    if isinstance(config.get("hparams"), Mapping):
        ran_hparams, wanted_hparams = dict(config["hparams"]), declared["hparams"]
        for key in sorted(set(ran_hparams) | set(wanted_hparams)):
            compare(f"hparam {key}", ran_hparams.get(key), wanted_hparams.get(key))
    return "; ".join(changes)


def entry_from_record(record: Mapping[str, Any], run_dir: str | os.PathLike | None = None, *,
                      tag: str | None = None, licence: str = DEFAULT_LICENCE, dataset_licence: str | None = None,
                      note: str = "", url: str | None = None) -> WeightEntry:
    """The :class:`WeightEntry` of a finished cell whose weights ``bench --save-weights`` wrote.

    Args:
        record: the cell record (``<run>/cells/<cell id>.json``, parsed), with ``status`` ok and ``weights``.
        run_dir: the run folder (``--out``); the record's ``weights.file`` is relative to it. ``None``: leave
            ``file`` relative (to be placed next to the manifest).
        tag: default :func:`~tactile_zoo.weights.entry.make_tag` of the cell's model, recipe, dataset, fold, seed.
            The recipe is the cell's named recipe only if the cell ran it as declared; a cell that changed it
            (:func:`recipe_changes`: ``--epochs 1``, ``--set lr=...``, ``--hparam``) is tagged and labelled
            :data:`CUSTOM_RECIPE`, and the note says what changed.
        licence: the weights' licence (default: the project's, :data:`DEFAULT_LICENCE`).
        dataset_licence: the training data's terms (default: the dataset's registry metadata ``licence``).
        note: anything users must know (e.g. that a dataset's class names are unverified).
        url: where the file will be downloadable from, if anywhere.
    """
    cell = record.get("cell_id", "?")
    if record.get("status") != "ok":
        raise ConfigError(f"cell {cell}: status {record.get('status')!r}; only a finished (ok) cell has weights")
    weights = record.get("weights")
    if not isinstance(weights, Mapping) or not weights.get("file") or not weights.get("sha256"):
        raise ConfigError(f"cell {cell}: the record has no weights (run the bench with --save-weights)")
    config = record.get("config") or {}
    reason = unpublishable(config)
    if reason:
        raise ConfigError(f"cell {cell} was {reason}; its weights are not publishable")
    if dataset_licence is None:
        from ..registry import get_dataset_entry

        try:
            dataset_licence = str(get_dataset_entry(record["dataset"]).meta.get("licence", ""))
        except Exception:  # noqa: BLE001 - a dataset no longer registered: the caller can still pass the terms
            dataset_licence = ""
    from ..recipe import recipe_name_of

    test = (record.get("metrics") or {}).get("test") or {}
    fold, seed = int(record.get("fold", 0)), int(record.get("seed", 0))
    recipe = recipe_name_of(config)  # a record from before named recipes ran what is now the model's registered one
    changed = recipe_changes(record["model"], record["dataset"], config)
    if changed:  # the tag names a recipe: weights that did not follow it (--epochs 1, --set) are "custom"
        note = " ".join(filter(None, [f"Trained with recipe {recipe!r} changed ({changed}), so tagged "
                                      f"{CUSTOM_RECIPE!r}.", note]))
        recipe = CUSTOM_RECIPE
    file = Path(weights["file"]) if run_dir is None else Path(run_dir) / weights["file"]
    entry = WeightEntry(
        tag=tag or make_tag(record["model"], record["dataset"], recipe, fold=fold, seed=seed),
        model=record["model"], dataset=record["dataset"], spec=dict(record["spec"]), sha256=weights["sha256"],
        file=str(file), url=url, bytes=weights.get("bytes"), hparams=dict(config.get("hparams") or {}),
        dataset_kwargs=dict(config.get("dataset_kwargs") or {}),
        preprocessing=preprocessing_of(record["model"], record["dataset"], record["spec"], config.get("hparams"),
                                       config.get("dataset_kwargs")), recipe=recipe,
        loss=str((config.get("recipe") or {}).get("loss", "ce")), config_hash=record.get("config_hash"),
        cell_id=record.get("cell_id"), seed=seed, fold=fold, model_revision=config.get("model_revision"),
        dataset_revision=config.get("dataset_revision"),
        accuracy=None if test.get("accuracy") is None else float(test["accuracy"]), commit=record.get("commit"),
        licence=licence, dataset_licence=dataset_licence, note=note)
    # through the manifest's checks, so an entry made here is one a manifest can hold
    return WeightEntry.from_dict(entry.to_dict(), f"cell {cell}", origin=f"cell {cell}")
