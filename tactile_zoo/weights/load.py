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

import fnmatch
import os
import re
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .. import registry
from ..data.base import file_sha256
from ..errors import ConfigError, DatasetError, PluginError, UnknownNameError
from .discovery import find_weights, list_weights
from .entry import WeightEntry, make_tag, tag_key
from .files import locate
from .heads import head_keys, head_name
from .manifest import read_manifest

__all__ = ["create_model", "list_models", "load_pretrained", "resolve_weights", "local_weights", "check_fit",
           "load_state"]

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


def weights_revision(entry: WeightEntry, revision: int | None = None) -> int:
    """The revision of model ``entry.model`` that weights ``entry`` load into: the one their manifest records (the
    path that trained them; the model's default for an entry that records none).

    Raises:
        ConfigError: that revision can no longer be built (its code is gone), or ``revision`` asks for another one.
    """
    model = registry.get_model_entry(entry.model)
    recorded = registry.revision_of(model) if entry.model_revision is None else entry.model_revision
    known = registry.model_revisions(model)
    if recorded not in known:
        made = f" (commit {entry.commit})" if entry.commit else ""
        raise ConfigError(f"weights {entry.tag!r} were trained with revision {recorded} of model {entry.model!r}"
                          f"{made}; the installed model is revision {registry.revision_of(model)} (it builds "
                          f"revision(s) {', '.join(map(str, known))}) and computes differently, so they cannot be "
                          f"loaded into it")
    if revision is not None and revision != recorded:
        raise ConfigError(f"revision={revision!r}: weights {entry.tag!r} were trained with revision {recorded} of "
                          f"model {entry.model!r} and load into that revision only (leave revision out)")
    return recorded


def load_pretrained(name: str, pretrained: Any, spec: Any = None, *, new_head: bool = False, download: bool = True,
                    revision: int | None = None, **hparams: Any) -> nn.Module:
    """Model ``name`` with the weights ``pretrained`` names (see the module docstring).

    Args:
        name: a registered model name.
        pretrained: a dataset name, a tag, a ``.json`` manifest or ``.safetensors`` file, or a WeightEntry.
        spec: the spec of your data; default the weights' own. The weights must fit it.
        new_head: keep every layer but the final classifier, which the model initialises afresh for ``spec``'s
            classes (``spec`` required).
        download: fetch a URL entry that is not in the cache.
        revision: the model revision to build; the weights' own (what their manifest records) is the only one
            accepted, and the one built when it is left out.
        **hparams: override the entry's constructor keywords (a change of shape fails to load).

    Returns:
        the model, in training mode, with ``zoo_pretrained`` (the entry) and ``zoo_loss`` set.
    """
    entry = resolve_weights(name, pretrained)
    revision = weights_revision(entry, revision)
    if new_head and spec is None:
        raise ConfigError("new_head=True starts a classifier for your classes: pass the spec of your data")
    trained = entry.dataset_spec()
    target = trained if spec is None else spec
    check_fit(entry, target, new_head=new_head)
    options = {**entry.hparams, **hparams}
    model = registry.instantiate_model(entry.model, target, revision=revision, **options)
    if target.num_steps != trained.num_steps and not new_head:
        reference = registry.instantiate_model(entry.model, trained, revision=revision, **options)
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


def _split_tag(name: str) -> tuple[str, str | None]:
    """``"x_tacformer.full_ev_objects"`` -> ``("x_tacformer", "x_tacformer.full_ev_objects")``: the model, and the
    weights tag when the name carries one (timm's ``model.tag``; a ``dist:`` model qualifier stays on the model)."""
    qualifier, colon, bare = name.rpartition(":")
    model, dot, tag = bare.partition(".")
    if not dot:
        return name, None
    if not model or not tag.strip():
        raise ConfigError(f"model name {name!r}: a tag reads <model>.<tag>, e.g. 'x_tacformer.full_ev_objects'")
    return f"{qualifier}{colon}{model}", f"{model}.{tag}"


def _choices(entries: list[WeightEntry]) -> str:
    return ", ".join(f"{e.qualified_tag} ({e.dataset})" for e in entries)


def _pick(model: str, spec: Any, dataset: str | None, new_head: bool) -> WeightEntry:
    """The installed weights of ``model`` that ``pretrained=True`` means: those for ``dataset``; else those trained on
    ``spec``'s dataset, else the only ones whose spec ``spec`` fits; else the only ones installed. Every error names
    the choices."""
    if dataset is not None:
        return _by_dataset(model, dataset)
    mine = list_weights(model)
    if not mine:
        raise UnknownNameError(f"no installed weights of model {model!r}; `tactile-zoo weights` lists what is "
                               f"installed (pip install ./plugins/tactile-zoo-weights ships the zoo's)")
    if spec is None:
        if len({registry.normalize_name(e.dataset) for e in mine}) == 1:
            return _by_dataset(model, mine[0].dataset)
        raise ConfigError(f"create_model({model!r}, pretrained=True): model {model!r} has weights for several "
                          f"datasets; pass the spec of your data, dataset=, or a tag in the name. Choices: "
                          f"{_choices(mine)}")
    if any(registry.normalize_name(e.dataset) == registry.normalize_name(spec.name) for e in mine):
        return _by_dataset(model, spec.name)
    fitting = [e for e in mine if not _mismatches(e.dataset_spec(), spec, new_head)]
    if len({registry.normalize_name(e.dataset) for e in fitting}) == 1:
        return _by_dataset(model, fitting[0].dataset)
    why = "none fits" if not fitting else "several fit"
    raise ConfigError(f"create_model({model!r}, spec of {spec.name!r}, pretrained=True): no weights of model "
                      f"{model!r} were trained on {spec.name!r}, and {why} its sensor, taxels, channels, globals"
                      f"{'' if new_head else ' and classes'}; pass dataset= or a tag. Choices: {_choices(mine)}")


def _with_classes(spec: Any, num_classes: int) -> Any:
    """``spec`` with ``num_classes`` classes (names ``class_<i>`` when the count changes: the old names are another
    task's)."""
    if isinstance(num_classes, bool) or not isinstance(num_classes, int) or num_classes < 1:
        raise ConfigError(f"num_classes must be a positive integer, got {num_classes!r}")
    if num_classes == spec.num_classes:
        return spec
    return replace(spec, num_classes=num_classes, class_names=tuple(f"class_{i}" for i in range(num_classes)))


def create_model(name: str, spec: Any = None, pretrained: Any = None, new_head: bool = False, *,
                 num_classes: int | None = None, dataset: str | None = None, revision: int | None = None,
                 **hparams: Any) -> nn.Module:
    """Build model ``name`` for a dataset ``spec``, optionally with pretrained weights (timm's calls).

    Without ``pretrained`` this is the registry's ``Model(spec, **hparams)``. With it, the weights are loaded (see
    :func:`load_pretrained`): ``spec`` may be omitted (the weights' own spec is used); given, the weights must fit it,
    and ``new_head=True`` keeps the trunk and starts a fresh classifier for ``spec``'s classes.

    Args:
        name: a registered model name (normalised: ``X-Tacformer`` = ``x_tacformer``), optionally with a weights tag,
            timm style: ``"x_tacformer.full_ev_objects"``. With ``pretrained=True`` the tag names the weights; without,
            the model is built for the tag's spec and hyper-parameters, freshly initialised (as timm does).
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` of the data.
        pretrained: ``None``/``False``, ``True`` (the installed weights that match: the tag in ``name``, else those
            for ``dataset``, else those trained on ``spec``'s dataset or the only ones that fit ``spec``, else the
            model's only ones; an error lists the choices), a dataset name (``"ev_objects"``), a tag
            (``"x_tacformer.source_ev_objects"``), a local ``.json`` manifest or ``.safetensors`` file, or a
            :class:`~tactile_zoo.weights.entry.WeightEntry`.
        new_head: with ``pretrained``: a fresh classifier for ``spec``'s classes.
        num_classes: a fresh classifier with this many outputs (the model's spec then has ``num_classes`` classes,
            named ``class_<i>`` when the count changes). With ``pretrained``: every other layer is loaded; without
            ``spec``, a count equal to the weights' keeps their classifier too (as timm).
        dataset: with ``pretrained=True``: the dataset whose weights to load.
        revision: which of the model's revisions to build (``registry.model_revisions``; default: its registered
            default). With weights (``pretrained``, or a tag in ``name``), the revision their manifest records is
            built, and another one is refused.
        **hparams: the model's constructor keywords (they win over the revision's compute keywords).

    Raises:
        ConfigError: a revision the model does not have (the message lists its revisions), among the other checks.
    """
    model_name, tag = _split_tag(name)
    if dataset is not None and pretrained is not True:
        raise ConfigError(f"dataset={dataset!r} picks pretrained weights: pass pretrained=True (or "
                          f"pretrained={dataset!r})")
    if tag is not None:
        if pretrained not in (None, False, True):
            raise ConfigError(f"create_model({name!r}): the name's tag already names the weights; pass "
                              f"pretrained=True or nothing, not pretrained={pretrained!r}")
        entry = resolve_weights(model_name, tag)
        if pretrained is True:
            pretrained = entry
        else:  # timm: the tag's configuration (its revision too), random weights
            hparams = {**entry.hparams, **hparams}
            spec = entry.dataset_spec() if spec is None else spec
            revision = weights_revision(entry, revision)
    if pretrained is True:
        pretrained = _pick(model_name, spec, dataset, new_head or num_classes is not None)
    if pretrained is None or pretrained is False:
        if new_head:
            raise ConfigError("new_head=True replaces the classifier of pretrained weights: pass pretrained=")
        if spec is None:
            raise ConfigError(f"create_model({name!r}): pass the dataset spec, or pretrained= weights (whose spec is "
                              f"then used)")
        if num_classes is not None:
            spec = _with_classes(spec, num_classes)
        return registry.instantiate_model(model_name, spec, revision=revision, **hparams)
    if num_classes is not None:
        entry = resolve_weights(model_name, pretrained)
        base = entry.dataset_spec() if spec is None else spec
        target = _with_classes(base, num_classes)
        # a classifier of the weights' own size loads as it is (timm keeps it too); any other gets a fresh one
        keep = spec is None and num_classes == entry.num_classes
        return load_pretrained(model_name, entry, None if keep else target, new_head=not keep, revision=revision,
                               **hparams)
    return load_pretrained(model_name, pretrained, spec, new_head=new_head, revision=revision, **hparams)


def list_models(pattern: str | Iterable[str] = "*", tags: Iterable[str] | None = None, pretrained: bool = False
                ) -> list[str]:
    """Registered model names matching fnmatch ``pattern`` and having all ``tags`` (the registry's
    :func:`~tactile_zoo.registry.model_names`); with ``pretrained=True``, the tags of their installed weights
    instead, timm style (``["x_tacformer.full_ev_objects", ...]``), which ``pattern`` may also match whole
    (``"*ev_objects"``). A tag shipped by several distributions is listed as ``<distribution>:<tag>``."""
    names = registry.model_names(pattern, tags)
    if not pretrained:
        return names
    models = {registry.get_model_entry(n).qualified_name for n in names}
    allowed = {registry.get_model_entry(n).qualified_name for n in registry.model_names("*", tags)}
    patterns = [pattern] if isinstance(pattern, str) else list(pattern)
    entries = []
    for entry in list_weights():
        try:
            model = registry.get_model_entry(entry.model).qualified_name
        except (UnknownNameError, PluginError):  # weights of a model whose plugin is absent: nothing to build
            continue
        if model in models or (model in allowed and any(fnmatch.fnmatchcase(entry.tag.lower(), p.lower())
                                                        for p in patterns)):
            entries.append(entry)
    shared = {tag_key(e.tag) for e in entries if sum(tag_key(o.tag) == tag_key(e.tag) for o in entries) > 1}
    return sorted({e.qualified_tag if tag_key(e.tag) in shared else e.tag for e in entries})
