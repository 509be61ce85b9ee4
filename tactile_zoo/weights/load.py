"""Building a model with pretrained weights: resolving ``pretrained=``, checking that the weights fit, loading them.

``pretrained`` may be

* a dataset name (``"ev_objects"``): the installed weights of this model trained on it (the model's default recipe
  wins when there are several);
* a tag (``"x_tacformer.source_ev_objects"``, or ``"<distribution>:<tag>"``) of installed weights;
* a local manifest (``.json``): its entry for this model; a local ``.safetensors`` file: described by ``<file
  stem>.json`` or ``manifest.json`` next to it (the entry whose sha256 is the file's);
* a :class:`~tactile_zoo.weights.entry.WeightEntry` (a URL entry is downloaded into the cache, sha256-verified).

Fit: the weights were trained for one dataset spec. Without ``spec`` that spec is used. With ``spec`` (your data),
one :class:`ConfigError` lists everything that does not match: the sensor, taxels, channels, global features,
classes (count and names; not with ``new_head=True``) and the number of steps where the model depends on it (its
parameter shapes or its frame binning differ between the two lengths: D-CNN, the binned models with ``max_frames``;
a causal model that reads any length, such as SGnet, accepts another length).
"""

from __future__ import annotations

import os
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .. import registry
from ..data.base import file_sha256
from ..errors import ConfigError, DatasetError, UnknownNameError
from .discovery import find_weights, list_weights
from .entry import WeightEntry, make_tag, tag_key
from .files import locate
from .heads import head_keys, head_name
from .manifest import read_manifest

__all__ = ["create_model", "load_pretrained", "resolve_weights", "local_weights", "check_fit", "load_state"]

_LOCAL_SUFFIXES = (".json", ".safetensors")


def _same_model(a: str, b: str) -> bool:
    return registry.get_model_entry(a).qualified_name == registry.get_model_entry(b).qualified_name


def local_weights(manifest: str | os.PathLike, file: str | os.PathLike | None = None, *, model: str | None = None,
                  tag: str | None = None) -> WeightEntry:
    """The entry of a local manifest: the one describing ``file`` (matched by sha256, so the file may have been
    renamed or moved; the entry then points at ``file``), else the one for ``model`` or with ``tag``.

    Raises:
        ConfigError: no entry, or several, match; the message lists the manifest's tags.
    """
    entries = read_manifest(manifest)
    listed = ", ".join(e.tag for e in entries) or "none"
    if model is not None:
        entries = [e for e in entries if _model_key(e.model) == _model_key(model)]
    if tag is not None:
        entries = [e for e in entries if tag_key(e.tag) == tag_key(tag)]
    if file is not None:
        path = Path(file).expanduser()
        if not path.is_file():
            raise ConfigError(f"weights file {path} does not exist")
        sha = file_sha256(path)
        entries = [e for e in entries if e.sha256 == sha]
        entries = [_with_file(e, path) for e in entries]
        what = f"{path} (sha256 {sha[:16]}...)" + (f" for model {model!r}" if model else "")
    else:
        what = f"model {model!r}" if model else f"tag {tag!r}" if tag else "any model"
    if len(entries) == 1:
        return entries[0]
    if not entries:
        raise ConfigError(f"weights manifest {manifest} has no entry for {what}; it lists: {listed}")
    raise ConfigError(f"weights manifest {manifest} has several entries for {what} "
                      f"({', '.join(e.tag for e in entries)}); name one by its tag")


def _model_key(model: str) -> str:
    return registry.normalize_name(model.rpartition(":")[2])


def _with_file(entry: WeightEntry, path: Path) -> WeightEntry:
    return replace(entry, file=str(path.resolve()), base_dir=None)


def _local(model: str, path: Path) -> WeightEntry:
    if path.suffix.lower() == ".json":
        return local_weights(path, model=model)
    for manifest in (path.with_suffix(".json"), path.parent / "manifest.json"):
        if manifest.is_file():
            return local_weights(manifest, path, model=model)
    raise ConfigError(f"no manifest describes {path}: expected {path.with_suffix('.json').name} or manifest.json next "
                      f"to it (tactile_zoo.weights.write_manifest writes one), or pass a WeightEntry")


def _by_dataset(model: str, dataset: str) -> WeightEntry:
    found = list_weights(model, dataset)
    if len(found) == 1:
        return found[0]
    default, _ = registry.model_recipe(registry.get_model_entry(model).meta)
    if not found:
        mine = list_weights(model)
        if mine:
            raise UnknownNameError(f"no installed weights of model {model!r} for dataset {dataset!r}; installed for "
                                   f"{model!r}: {', '.join(e.qualified_tag for e in mine)}")
        raise UnknownNameError(f"no installed weights of model {model!r} (tag {make_tag(model, dataset, default)!r}); "
                               f"`tactile-zoo weights` lists what is installed")
    preferred = [e for e in found if e.recipe == default and e.fold == 0 and not e.seed]
    if len(preferred) == 1:
        return preferred[0]
    raise ConfigError(f"several installed weights of model {model!r} on {dataset!r}: "
                      f"{', '.join(e.qualified_tag for e in found)}; pass one tag")


def resolve_weights(model: str, pretrained: Any) -> WeightEntry:
    """The :class:`WeightEntry` that ``pretrained`` names for ``model`` (see the module docstring)."""
    if isinstance(pretrained, WeightEntry):
        entry = pretrained
    elif isinstance(pretrained, os.PathLike) or (isinstance(pretrained, str) and
                                                 Path(pretrained).suffix.lower() in _LOCAL_SUFFIXES):
        entry = _local(model, Path(os.fspath(pretrained)).expanduser())
    elif isinstance(pretrained, str) and pretrained.strip():
        text = pretrained.strip()
        if re.match(r"^https?://", text, re.IGNORECASE):
            raise ConfigError(f"pretrained={text!r}: a URL alone does not say what the weights are; put it in a "
                              f"manifest entry (url and sha256) and pass the manifest")
        entry = find_weights(text) if "." in text else _by_dataset(model, text)
    else:
        raise ConfigError(f"pretrained must be a dataset name, a tag, a .json manifest, a .safetensors file or a "
                          f"WeightEntry, got {pretrained!r}")
    try:
        registry.get_model_entry(entry.model)
    except UnknownNameError:
        raise UnknownNameError(f"weights {entry.tag!r} are for model {entry.model!r}, which is not registered "
                               f"(a plugin that is not installed?)") from None
    if not _same_model(model, entry.model):
        raise ConfigError(f"weights {entry.tag!r} ({entry.origin}) are for model {entry.model!r}, not {model!r}")
    return entry


def check_fit(entry: WeightEntry, spec: Any, *, new_head: bool = False) -> None:
    """Raise one :class:`ConfigError` listing what of ``spec`` the weights of ``entry`` do not fit (number of steps
    aside: that needs the model, see :func:`load_pretrained`)."""
    problems = _mismatches(entry.dataset_spec(), spec, new_head)
    if problems:
        raise _misfit(entry, spec, problems, classes=any(p.startswith("class") for p in problems))


def _misfit(entry: WeightEntry, spec: Any, problems: list[str], classes: bool = False) -> ConfigError:
    hint = " (new_head=True keeps the trunk and starts a fresh classifier for your classes)" if classes else ""
    return ConfigError(f"pretrained weights {entry.tag!r} (trained on {entry.dataset!r}) do not fit dataset "
                       f"{getattr(spec, 'name', '?')!r}: {'; '.join(problems)}{hint}")


def _mismatches(trained: Any, spec: Any, new_head: bool) -> list[str]:
    problems = []
    if not new_head:
        if trained.num_classes != spec.num_classes:
            problems.append(f"classes: the weights know {trained.num_classes}, your data has {spec.num_classes}")
        elif tuple(trained.class_names) != tuple(spec.class_names):
            first = next(i for i, (a, b) in enumerate(zip(trained.class_names, spec.class_names)) if a != b)
            problems.append(f"class names: class {first} is {trained.class_names[first]!r} in the weights, "
                            f"{spec.class_names[first]!r} in your data")
    if trained.sensor.name != spec.sensor.name:
        problems.append(f"sensor: the weights were trained on {trained.sensor.name!r}, your data is "
                        f"{spec.sensor.name!r}")
    for key, what in (("num_nodes", "taxels"), ("num_channels", "channels per taxel"),
                      ("num_globals", "global features")):
        if getattr(trained, key) != getattr(spec, key):
            problems.append(f"{what}: the weights expect {getattr(trained, key)}, your data has {getattr(spec, key)}")
    return problems


def _time_dependence(model: nn.Module) -> tuple[Any, ...]:
    """What of a model depends on the number of steps it is built for: parameter shapes and frame binning."""
    shapes = tuple((k, tuple(v.shape)) for k, v in model.state_dict().items())
    return shapes, getattr(model, "bin_size", None), getattr(model, "num_steps", None)


def load_state(path: Path, entry: WeightEntry) -> dict[str, torch.Tensor]:
    """The tensors of a verified ``.safetensors`` file (safetensors never runs code from the file)."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        return load_file(str(path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise DatasetError(f"weights {entry.tag!r}: {path} is not a readable safetensors file ({exc})") from None


def _check_revision(entry: WeightEntry) -> None:
    if entry.model_revision is None:
        return
    current = registry.revision_of(registry.get_model_entry(entry.model))
    if current != entry.model_revision:
        made = f" (commit {entry.commit})" if entry.commit else ""
        raise ConfigError(f"weights {entry.tag!r} were trained with revision {entry.model_revision} of model "
                          f"{entry.model!r}{made}; the installed model is revision {current} and computes "
                          f"differently, so they cannot be loaded into it")


def load_pretrained(name: str, pretrained: Any, spec: Any = None, *, new_head: bool = False, download: bool = True,
                    **hparams: Any) -> nn.Module:
    """Model ``name`` with the weights ``pretrained`` names (see the module docstring).

    Args:
        name: a registered model name.
        pretrained: a dataset name, a tag, a ``.json`` manifest or ``.safetensors`` file, or a WeightEntry.
        spec: the spec of your data; default the weights' own. The weights must fit it.
        new_head: keep every layer but the final classifier, which the model initialises afresh for ``spec``'s
            classes (``spec`` required).
        download: fetch a URL entry that is not in the cache.
        **hparams: override the entry's constructor keywords (a change of shape fails to load).

    Returns:
        the model, in training mode, with ``zoo_pretrained`` (the entry) and ``zoo_loss`` set.
    """
    entry = resolve_weights(name, pretrained)
    _check_revision(entry)
    if new_head and spec is None:
        raise ConfigError("new_head=True starts a classifier for your classes: pass the spec of your data")
    trained = entry.dataset_spec()
    target = trained if spec is None else spec
    check_fit(entry, target, new_head=new_head)
    options = {**entry.hparams, **hparams}
    model = registry.create_model(entry.model, target, **options)
    if target.num_steps != trained.num_steps and not new_head:
        reference = registry.create_model(entry.model, trained, **options)
        if _time_dependence(model) != _time_dependence(reference):
            raise _misfit(entry, target, [f"steps: the weights were trained on {trained.num_steps} steps, your data "
                                          f"has {target.num_steps}, and model {entry.model!r} depends on the length "
                                          f"(its layer shapes or frame bins change)"])
    state = load_state(locate(entry, download=download), entry)
    where = f"weights {entry.tag!r} ({entry.origin})"
    try:
        if new_head:
            head = head_name(model, target.num_classes)
            fresh = set(head_keys(model, head))
            trunk = {k: v for k, v in state.items() if not k.startswith(f"{head}.")}
            result = model.load_state_dict(trunk, strict=False)
            missing = sorted(set(result.missing_keys) - fresh)
            if missing or result.unexpected_keys:
                raise ConfigError(f"{where} do not fit model {entry.model!r}: missing {missing[:3]}, unexpected "
                                  f"{sorted(result.unexpected_keys)[:3]}")
        else:
            model.load_state_dict(state)
    except RuntimeError as exc:  # load_state_dict: the first line is a title, the second the first mismatch
        lines = [line.strip() for line in str(exc).splitlines() if line.strip()] or [type(exc).__name__]
        detail = lines[min(1, len(lines) - 1)]
        raise ConfigError(f"{where} do not fit model {entry.model!r} built with {options}: {detail}") from None
    model.zoo_loss = entry.loss
    model.zoo_pretrained = entry
    return model


def create_model(name: str, spec: Any = None, pretrained: Any = None, new_head: bool = False, **hparams: Any
                 ) -> nn.Module:
    """Build model ``name`` for a dataset ``spec``, optionally with pretrained weights.

    Without ``pretrained`` this is the registry's ``Model(spec, **hparams)``. With it, the weights are loaded (see
    :func:`load_pretrained`): ``spec`` may be omitted (the weights' own spec is used); given, the weights must fit it,
    and ``new_head=True`` keeps the trunk and starts a fresh classifier for ``spec``'s classes.

    Args:
        name: a registered model name (normalised: ``X-Tacformer`` = ``x_tacformer``).
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` of the data.
        pretrained: ``None``, a dataset name (``"ev_objects"``), a tag (``"x_tacformer.source_ev_objects"``), a local
            ``.json`` manifest or ``.safetensors`` file, or a :class:`~tactile_zoo.weights.entry.WeightEntry`.
        new_head: with ``pretrained``: a fresh classifier for ``spec``'s classes.
        **hparams: the model's constructor keywords.
    """
    if pretrained is None:
        if new_head:
            raise ConfigError("new_head=True replaces the classifier of pretrained weights: pass pretrained=")
        if spec is None:
            raise ConfigError(f"create_model({name!r}): pass the dataset spec, or pretrained= weights (whose spec is "
                              f"then used)")
        return registry.create_model(name, spec, **hparams)
    return load_pretrained(name, pretrained, spec, new_head=new_head, **hparams)
