"""The configuration room: what one cell runs, resolved once, hashed once, checked once.

Every way of running a cell (``tactile-zoo bench`` and ``tactile-zoo train`` through
:func:`tactile_zoo.bench.config.plan_cells`, the by-name ``tactile_zoo.fit("sgnet", "sim_evtouch")``) ends here, in
:func:`resolve_cell`, which returns one frozen, picklable :class:`CellConfig`. That object is what a worker receives
(the harness's ``CellTask`` carries it as it is) and what :func:`tactile_zoo.engine.cell.train_cell` trains; nothing
downstream resolves it again. Its plain form (:meth:`CellConfig.to_dict`) is what a cell record stores, and
:func:`config_hash` is the harness's cell hash of it.

The training recipe is resolved in exactly one function, :func:`resolve_model_recipe`, which applies every layer in
order:

1. the schema's defaults (:data:`tactile_zoo.recipe.DEFAULT_RECIPE`);
2. the model's named recipe (its registry metadata ``recipes``; ``None``: its default one);
3. that recipe's section for the dataset (``datasets[dataset]``);
4. the dataset's epoch budget (registry metadata ``max_epochs``; only when no epoch count is forced below);
5. the user's overrides (``--set``, a YAML file's ``recipe`` and ``model_overrides``, ``fit(recipe={...})``), or a
   whole :class:`~tactile_zoo.recipe.Recipe` given instead (then layers 2-4 give only the recipe's other settings);
6. ``--epochs`` (``epochs``), else ``--quick``'s :data:`QUICK_EPOCHS`.

``tests/engine/test_config_room.py`` fails when any other module of the package calls the layers' pieces.
"""

from __future__ import annotations

import hashlib
import inspect
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .. import registry, settings
from ..errors import ConfigError, ModelCannotConsume
from ..recipe import (
    Recipe,
    cap_epochs,
    declared_evaluation,
    named_recipe_for,
    recipe_name_of,
    recipe_values,
)
from .evaluate import DEFAULT_PREFIXES

__all__ = ["CellConfig", "NamedRecipe", "EVALUATIONS", "MERGED_EVALUATIONS", "UNHASHED_KEYS", "HASH_FORMAT",
           "QUICK_SUBSET", "QUICK_EPOCHS", "resolve_cell", "resolve_model_recipe", "config_hash", "check_hparams",
           "check_model_builds"]

#: Keys of a stored cell configuration that are labels, not settings: the cell hash leaves them out.
UNHASHED_KEYS = ("causal", "recipe_name")
#: How a cell reaches its test figure.
#: ``validation`` (the zoo's honest protocol): the epoch is selected on the validation split, then the test split is
#: read once. ``reference`` (the protocol of the sources that publish their best test epoch): train on train + val
#: for the recipe's fixed epoch budget (no early stopping, nothing selected), evaluate the test split after every
#: epoch and keep only two numbers: the final epoch's accuracy (honest: nothing was chosen) and the best epoch's
#: (optimistic: chosen on the test set itself, reported only as the sources' figure). No per-epoch test curve is
#: stored, so it can never steer a later choice. ``tuning`` (for choosing a recipe): train and select on validation
#: exactly as ``validation`` does, but never read a test split: the cell runs in tuning mode
#: (:mod:`tactile_zoo.data.guard`), where loading one raises, and records the validation score only. ``final``
#: (honest, for a recipe whose epoch count was declared beforehand from validation evidence, such as ``full``):
#: train on train + val for the recipe's fixed epochs, nothing selected, and read the test split once, at the end.
EVALUATIONS = settings.EVALUATIONS  # ("validation", "reference", "tuning", "final"), written in the schema
#: the evaluations that train on every training recording (train + val) and select nothing
MERGED_EVALUATIONS = ("reference", "final")
#: 2: the configuration gained the model's and the dataset's computational revisions (``model_revision``,
#: ``dataset_revision``); everything else hashes as in format 1.
HASH_FORMAT = 2
#: ``--quick``: at most this many samples per split (class-balanced), and this many epochs unless --epochs says so.
QUICK_SUBSET = {"train": 64, "val": 32, "test": 64}
QUICK_EPOCHS = 2


@dataclass(frozen=True)
class CellConfig:
    """What one cell runs, fold and seed aside: everything that can change its numbers.

    ``to_dict()`` is the plain form stored in a cell record; every key but ``causal`` (a property of the model, not
    a setting) and ``recipe_name`` (a label: the resolved recipe itself is hashed) enters the harness's cell hash.
    """

    model: str  # the listed registry name (``dist:name`` for a shadowed or clashing plugin)
    dataset: str
    recipe: Recipe
    recipe_name: str = "source"  # which of the model's named recipes ``recipe`` started from (overrides on top)
    model_source: str = "builtin"  # the plugin distribution, or "builtin"
    hparams: Mapping[str, Any] = field(default_factory=dict)
    dataset_kwargs: Mapping[str, Any] = field(default_factory=dict)
    refit: bool = False
    subset: Mapping[str, int] | None = None  # at most this many samples per split (``--quick``)
    prefixes: tuple[float, ...] = DEFAULT_PREFIXES
    causal: bool = False
    model_revision: int = registry.DEFAULT_REVISION
    dataset_revision: int = registry.DEFAULT_REVISION
    evaluation: str = "validation"  # or "reference", "tuning", "final": see EVALUATIONS
    #: distillation: the seeds of the teachers, cells of this configuration with distillation off (:mod:`.distill`)
    teacher_seeds: tuple[int, ...] = ()

    def hashed(self) -> dict[str, Any]:
        """The part of :meth:`to_dict` a cell hash covers."""
        return {"model": self.model, "model_source": self.model_source, "hparams": dict(self.hparams),
                "recipe": self.recipe.to_dict(), "dataset": self.dataset, "dataset_kwargs": dict(self.dataset_kwargs),
                "refit": self.refit, "subset": None if self.subset is None else dict(self.subset),
                "prefixes": list(self.prefixes), "model_revision": self.model_revision,
                "dataset_revision": self.dataset_revision,
                # the default is left out, so that the hashes of cells from before the setting existed still hold
                **({"evaluation": self.evaluation} if self.evaluation != "validation" else {}),
                **({"teachers": list(self.teacher_seeds)} if self.teacher_seeds else {})}

    def to_dict(self) -> dict[str, Any]:
        return {**self.hashed(), "causal": self.causal, "recipe_name": self.recipe_name}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> CellConfig:
        """The inverse of :meth:`to_dict`, for reading a stored record back (revisions absent from older records mean
        1). Running a cell never needs it: the resolved object itself travels to the worker."""
        return cls(model=values["model"], dataset=values["dataset"],
                   recipe=Recipe.from_dict(values["recipe"], where=f"recipe of {values['model']}"),
                   recipe_name=recipe_name_of(values),
                   model_source=values.get("model_source", "builtin"), hparams=dict(values.get("hparams") or {}),
                   dataset_kwargs=dict(values.get("dataset_kwargs") or {}), refit=bool(values.get("refit")),
                   subset=values.get("subset") or None, prefixes=tuple(values.get("prefixes") or (1.0,)),
                   causal=bool(values.get("causal")),
                   model_revision=int(values.get("model_revision", registry.DEFAULT_REVISION)),
                   dataset_revision=int(values.get("dataset_revision", registry.DEFAULT_REVISION)),
                   evaluation=str(values.get("evaluation", "validation")),
                   teacher_seeds=tuple(int(s) for s in values.get("teachers") or ()))


@dataclass(frozen=True)
class NamedRecipe:
    """A model's recipe resolved for one dataset: its name, the training recipe, and the constructor keywords and
    dataset keywords it carries (the user's own, applied by :func:`resolve_cell`, win over these)."""

    name: str
    recipe: Recipe
    hparams: dict[str, Any]
    dataset_kwargs: dict[str, Any]
    evaluation: str | None = None  # the evaluation the recipe declares (``None``: the caller's choice)


def resolve_model_recipe(meta: Mapping[str, Any], name: str | None = None, dataset: str | None = None,
                         overrides: Recipe | Mapping[str, Any] | None = None, epochs: int | None = None, *,
                         budget: int | None = None, quick: bool = False, owner: str = "the model") -> NamedRecipe:
    """THE recipe resolution: every layer of the module docstring, in order, for a model's registry ``meta``.

    Args:
        meta: the model's registry metadata (or a module's ``zoo_meta``; ``{}``: the schema's defaults).
        name: which named recipe (``None``: the model's default one).
        dataset: the dataset whose ``datasets[...]`` section applies (``None``: none).
        overrides: recipe keys on top, or a whole :class:`Recipe` used instead of the named one (name ``custom``).
        epochs: replaces ``max_epochs`` last (the CLI's ``--epochs``).
        budget: the dataset's epoch budget, which caps the named recipe when no epoch count is forced.
        quick: ``--quick``: :data:`QUICK_EPOCHS` when ``epochs`` is not given.
        owner: names the model in error messages.
    """
    try:
        name, base = registry.model_recipe(meta, name)
    except ConfigError as exc:
        raise ConfigError(f"{owner}: {exc}") from None
    training, hparams, kwargs = named_recipe_for(base, dataset, where=f"recipe {name!r} of {owner}")
    forced = epochs if epochs is not None else (QUICK_EPOCHS if quick else None)
    where = f"recipe of {owner}"
    if isinstance(overrides, Recipe):
        name, values = "custom", recipe_values(overrides, None, forced, where)
    else:
        values = recipe_values(training, overrides, forced, where)
        if forced is None and budget is not None:
            values = cap_epochs(values, int(budget))
    try:  # the layers' keys merged first, then the Recipe built once, here, from all of them
        recipe = Recipe(**values)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("recipe:", f"{where}:", 1)) from None
    return NamedRecipe(name, recipe, hparams, kwargs, declared_evaluation(base, dataset))


def resolve_cell(model: str, dataset: str, *, recipe: Recipe | Mapping[str, Any] | str | None = None,
                 recipe_name: str | None = None,
                 hparams: Mapping[str, Any] | None = None, epochs: int | None = None,
                 dataset_kwargs: Mapping[str, Any] | None = None, refit: bool = False, quick: bool = False,
                 subset: Mapping[str, int] | None = None, prefixes: Sequence[float] = DEFAULT_PREFIXES,
                 evaluation: str | None = None, model_revision: int | None = None,
                 teacher_seeds: Sequence[int] = ()) -> CellConfig:
    """The configuration of ``model`` on ``dataset``.

    Args:
        model: a registered model name, as listed (``list_models()``).
        dataset: a registered dataset name, as listed.
        recipe: overrides of single keys on top of the model's named recipe, a :class:`Recipe` used as is, or a
            recipe name (the same as ``recipe_name``).
        recipe_name: which of the model's registered recipes to start from (``"source"``...); default: the model's
            default recipe.
        hparams: the model's constructor keywords.
        epochs: replaces ``max_epochs`` (the CLI's ``--epochs``); without it the dataset's epoch budget (registry
            metadata ``max_epochs``) caps an overriding-dict or registered recipe, its schedule compressed to fit.
        dataset_kwargs: keyword arguments of the dataset.
        refit: retrain on train + val for the selected epoch count.
        quick: ``--quick``: :data:`QUICK_EPOCHS` unless ``epochs`` is given, and :data:`QUICK_SUBSET` unless
            ``subset`` is.
        subset: at most this many (class-balanced) samples per split, keyed ``train``/``val``/``test``.
        prefixes: early-classification prefix fractions evaluated on the test split.
        evaluation: one of :data:`EVALUATIONS`; default: the one the named recipe declares, else ``"validation"``.
        model_revision: which of the model's revisions to build (:func:`tactile_zoo.registry.model_revisions`);
            default: its registered default. Part of the hash, so cells of two revisions never pool.
        teacher_seeds: distillation's teachers (:mod:`.distill`), for a recipe whose ``distill_weight`` is above 0.

    Raises:
        ConfigError: a bad setting, a revision the model does not have (naming its revisions), or distillation
            without teachers (or teachers without distillation).
    """
    if evaluation is not None and evaluation not in EVALUATIONS:
        raise ConfigError(f"--evaluation must be one of {', '.join(EVALUATIONS)}, got {evaluation!r}")
    hparams = settings.check_keywords(hparams or {}, "", "hparams")  # the schema's keyword names, finite values
    dataset_kwargs = settings.check_keywords(dataset_kwargs or {}, "", "dataset_kwargs")
    entry = registry.get_model_entry(model)
    registry.revision_keywords(entry, model_revision)  # an unknown revision stops here, naming the model's revisions
    data_entry = registry.get_dataset_entry(dataset)
    if isinstance(recipe, str):
        recipe, recipe_name = None, recipe
    budget = data_entry.meta.get("max_epochs")
    named = resolve_model_recipe(entry.meta, recipe_name, dataset, recipe, epochs, budget=budget, quick=quick,
                                 owner=f"model {model!r}")
    # a named recipe may carry the model's and the dataset's settings; the user's own (hparams, dataset_kwargs) win
    evaluation = evaluation or named.evaluation or "validation"
    if evaluation in MERGED_EVALUATIONS and refit:
        raise ConfigError(f"--evaluation {evaluation} already trains on train + val; it does not combine with --refit")
    subset = subset if subset is not None else (QUICK_SUBSET if quick else None)
    _check_distillation(model, named.recipe, teacher_seeds, evaluation)
    return CellConfig(model=model, dataset=dataset, recipe=named.recipe, recipe_name=named.name,
                      model_source=entry.dist or "builtin", hparams={**named.hparams, **dict(hparams or {})},
                      dataset_kwargs={**named.dataset_kwargs, **dict(dataset_kwargs or {})}, refit=bool(refit),
                      subset=dict(subset) if subset else None, prefixes=tuple(prefixes),
                      causal=bool(entry.meta.get("causal", False)),
                      model_revision=registry.revision_of(entry) if model_revision is None else model_revision,
                      dataset_revision=registry.revision_of(data_entry), evaluation=evaluation,
                      teacher_seeds=tuple(sorted(teacher_seeds)))


def _check_distillation(model: str, recipe: Recipe, teacher_seeds: Sequence[int], evaluation: str) -> None:
    """A distilling recipe needs teachers, teachers need a distilling recipe, and a ``reference`` cell (which reads
    the test split after every epoch) is never a student."""
    if recipe.distill_weight > 0 and not teacher_seeds:
        raise ConfigError(f"model {model!r}: recipe distill_weight {recipe.distill_weight:g} needs teachers (the "
                          f"setting teachers: {{folder: FOLDER, seeds: [...]}}), and none are given")
    if teacher_seeds and recipe.distill_weight == 0:
        raise ConfigError(f"model {model!r}: teachers are given but the recipe's distill_weight is 0, so they would "
                          f"not be used; set distill_weight (and distill_temperature) or drop teachers")
    if teacher_seeds and evaluation == "reference":
        raise ConfigError(f"model {model!r}: distillation runs under evaluation validation, tuning or final, not "
                          f"reference")
    if len(set(teacher_seeds)) != len(teacher_seeds):
        raise ConfigError(f"model {model!r}: teachers.seeds lists a seed twice: {list(teacher_seeds)}")


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def config_hash(config: Mapping[str, Any] | CellConfig, hash_format: int = HASH_FORMAT) -> str:
    """16 hex digits of the SHA-256 of the canonical JSON of a cell's configuration (its labels aside): a
    :class:`CellConfig`, or the ``config`` dict a record stores."""
    values = config.hashed() if isinstance(config, CellConfig) else \
        {k: v for k, v in config.items() if k not in UNHASHED_KEYS}
    return hashlib.sha256(_canonical({"hash_format": hash_format, **values}).encode()).hexdigest()[:16]


def _constructor_keywords(model: str) -> tuple[str, ...] | None:
    """The keywords model ``model``'s constructor takes besides the spec; ``None`` when it takes any (``**kwargs``)
    or its signature cannot be read (a C callable): then only building the model can tell."""
    obj = registry.get_model_entry(model).obj
    try:
        params = list(inspect.signature(obj).parameters.values())
    except (TypeError, ValueError):
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return None
    named = [p for p in params if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]
    if named and named[0].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD:
        named = named[1:]  # the spec, passed positionally
    return tuple(p.name for p in named)


def check_hparams(config: CellConfig, given: Mapping[str, Any] | None = None) -> None:
    """An unknown constructor keyword (``--hparam``, a config file's ``hparams``, a named recipe's) is bad input:
    it stops the command before anything runs, instead of failing every cell of the model. ``given``: the keywords
    the user gave (``None``: all of them); a keyword among the others is blamed on the model's recipe."""
    accepted = _constructor_keywords(config.model)
    unknown = sorted(set(config.hparams) - set(accepted)) if accepted is not None else []
    if unknown:
        theirs = [k for k in unknown if given is None or k in given]
        source = "--hparam" if theirs else _recipe_source(config)
        raise ConfigError(f"{source}: model {config.model!r} takes no keyword argument(s) "
                          f"{', '.join(map(repr, theirs or unknown))}; it takes {', '.join(accepted) or 'none'}")


def _recipe_source(config: CellConfig) -> str:
    """Names the hparams of the recipe a cell's configuration started from, for an error about them."""
    return f"recipe {config.recipe_name!r} of model {config.model!r}: hparams"


def check_model_builds(resolved: CellConfig, spec: Any, given: Mapping[str, Any]) -> bool:
    """Build ``resolved``'s model once on ``spec`` (no data, no training), so that a bad hyper-parameter value stops
    the command before any cell runs instead of failing (or, worse, skipping) every cell of the model.

    Args:
        resolved: the cell configuration (its model and every constructor keyword, the named recipe's included).
        spec: the dataset's spec.
        given: the constructor keywords the user gave (``--hparam``, a config file's ``hparams``): an error while
            any is given is blamed on them, else on the keywords of the model's recipe, if it has any.

    Returns:
        False when the model declares it cannot consume this dataset (:class:`ModelCannotConsume`: its cells are
        skipped), else True. A model that fails without any keyword (the user's or its recipe's) is not bad input:
        its cells run and record the failure, as a broken dataset's do.

    Raises:
        ConfigError: the model cannot be built with the user's keywords; one line naming them, the model, the dataset
            and the model's own message.
    """
    import torch

    try:
        with torch.random.fork_rng(devices=[]):  # the check leaves the caller's random state as it found it
            registry.instantiate_model(resolved.model, spec, revision=resolved.model_revision,
                                       **dict(resolved.hparams))
    except ModelCannotConsume:
        return False
    except Exception as exc:  # noqa: BLE001 - whatever a constructor raises for a value it cannot use
        recipe_keywords = {k: v for k, v in resolved.hparams.items() if k not in given}
        if not given and not recipe_keywords:
            return True
        blamed = given or recipe_keywords
        values = ", ".join(f"{key}={value!r}" for key, value in blamed.items())
        source = "--hparam" if given else _recipe_source(resolved)
        why = " ".join(f"{type(exc).__name__}: {exc}".split())  # one line, whatever the model's message holds
        raise ConfigError(f"{source} {values}: model {resolved.model!r} cannot be built with it for dataset "
                          f"{resolved.dataset!r}: {why}") from None
    return True
