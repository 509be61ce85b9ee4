"""The training recipe schema: how a model is trained (loss, optimiser, schedule, epochs, early stopping, batch size).

Every model carries its default recipe in its registry metadata (``register_model(recipe={...})``); a plugin model
without one trains with :data:`DEFAULT_RECIPE` (cross-entropy, Adam). Users override single keys from the API, the CLI
(``--set lr=1e-3``) or a YAML config. A typo in a key, or a value of the wrong kind, is a :class:`ConfigError` naming
the key and where it came from, never a silently ignored setting.

Keys:
    loss: ``"ce"`` (cross-entropy on logits) or ``"mse_rate"`` (mean squared error between the output spike rates and
        ``rate_targets`` = (rate of the true class, rate of the others), as TactileSGNet trains).
    optimizer: ``"adam"``, ``"adamw"`` or ``"sgd"`` (with ``momentum``, optionally ``nesterov``).
    lr, weight_decay, amsgrad (Adam/AdamW), momentum, nesterov (SGD).
    schedule: ``None`` or a dict with ``type`` one of ``multistep`` (``milestones``, ``gamma``), ``step``
        (``step_size``, ``gamma``), ``exponential`` (``gamma``), ``cosine`` (``eta_min`` as a fraction of ``lr``,
        ``t_max`` in epochs, default ``max_epochs``); any type may add ``warmup_epochs`` (linear warm-up). The
        learning rate changes once per epoch. A bare string (``"cosine"``) means ``{"type": "cosine"}``.
    max_epochs: the epoch budget. patience: early stopping after this many epochs without improvement on the
        validation split (``None``: off). monitor: what "improvement" means, see below.
    batch_size, eval_batch_size, grad_clip (max gradient norm, ``None``: off), label_smoothing (``ce`` only).
    ema_decay: ``None`` (off, the default) or a decay in (0, 1): keep an exponential moving average of the weights
        (buffers included), updated after every optimiser step; validation, selection and the returned model use the
        averaged weights. Left out of the cell hash while off, so the hashes of cells from before it still hold.
    micro_batch_size: ``None`` (off, the default) or a sample count: gradient accumulation. Each batch runs forward
        and backward in consecutive micro-batches of at most this many samples (a lone last sample joins the one
        before it), each loss weighted by its share of the batch, and their summed gradients make one optimiser step:
        the step of the whole batch, except that batch norm in training mode normalises over each micro-batch and
        updates its running statistics once per micro-batch. It bounds the memory of a large batch. Off (or at least
        the batch size) the loop is the plain one; left out of the cell hash while off.
    distill_weight: 0 (off, the default) or a weight in (0, 1]: knowledge distillation from the averaged class
        probabilities of teacher models (:mod:`tactile_zoo.engine.distill`; the bench setting ``teachers`` names
        them). The loss becomes ``(1 - w) * CE(scores, y) + w * T**2 * KL(teachers || softmax(scores / T))``.
        distill_temperature: ``T``, the softmax temperature of both sides (default 1). Both are left out of the cell
        hash while at their defaults; ``ce`` loss only.

Model selection (the one documented choice the harness makes): with ``monitor="val_accuracy"`` (the default) the
selected epoch is the one with the highest validation accuracy, ties going to the lower validation loss; with
``monitor="val_loss"`` the lowest validation loss, ties going to the higher accuracy. Early stopping counts epochs
since that key last improved. Accuracy is what the leaderboard ranks, and the loss tie-break keeps small validation
sets (where accuracy saturates early) from freezing on the first perfect epoch.

A *named* recipe (a model's ``recipes={"source": {...}, "zoo": {...}}``) is a recipe dict that may also carry the
model's settings beside the training keys, because a recipe tuned for a dataset is more than an optimiser:

    hparams: the model's constructor keywords (``{"dropout": 0.1}``);
    dataset_kwargs: the dataset's keyword arguments (``{"augment": ["time_warp"], "augment_factor": 2}``);
    evaluation: how a cell of this recipe reaches its test figure, when the user names none (``"final"`` for a
        recipe that trains on every training recording for a fixed number of epochs; see
        :data:`tactile_zoo.engine.config.EVALUATIONS`);
    datasets: per-dataset sections, ``{"biotac_dos": {"max_epochs": 30, "dataset_kwargs": {"window": 5}}}``, each
        holding training keys, ``hparams``, ``dataset_kwargs`` and an ``evaluation`` that apply on that dataset only,
        on top of the rest.

:func:`named_recipe_for` resolves a named recipe on one dataset into its three parts; settings given by the user
(``--set``, ``--hparam``, ``--dataset-arg``) still win over the recipe's.

The keys' types and ranges are written once, in :class:`tactile_zoo.settings.RecipeSchema` (strict: text is never
a number or a boolean); this module builds recipes with it. Neither imports torch, so the registry validates a
model's ``recipe`` metadata at registration time and the engine trains with the same object.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from . import settings
from .errors import ConfigError

__all__ = ["Recipe", "DEFAULT_RECIPE", "RECIPE_KEYS", "RECIPE_SECTIONS", "resolve_recipe", "recipe_values",
           "named_recipe_for",
           "check_named_recipe", "lr_factor", "cap_epochs", "full_recipe", "recipe_name_of"]

LOSSES, OPTIMIZERS, MONITORS = settings.LOSSES, settings.OPTIMIZERS, settings.MONITORS
SCHEDULE_KEYS = {kind: set(keys) for kind, keys in settings.SCHEDULES.items()}


@dataclass(frozen=True)
class Recipe:
    """A validated training recipe; build one with :meth:`from_dict` or :func:`resolve_recipe`.

    Every value is checked against the one schema (:class:`tactile_zoo.settings.RecipeSchema`) when the object is
    built, so a ``Recipe(...)`` written by hand is checked as a YAML file's recipe is."""

    loss: str = "ce"
    optimizer: str = "adam"
    lr: float = 1e-3
    weight_decay: float = 0.0
    amsgrad: bool = False
    momentum: float = 0.9
    nesterov: bool = False
    schedule: dict[str, Any] | None = None
    max_epochs: int = 100
    patience: int | None = 20
    monitor: str = "val_accuracy"
    batch_size: int = 32
    eval_batch_size: int = 256
    grad_clip: float | None = None
    label_smoothing: float = 0.0
    rate_targets: tuple[float, float] = field(default=(1.0, 0.0))
    ema_decay: float | None = None
    micro_batch_size: int | None = None
    distill_weight: float = 0.0
    distill_temperature: float = 1.0

    def __post_init__(self) -> None:
        where = "recipe"
        for f in fields(self):
            object.__setattr__(self, f.name, _coerce(where, f.name, getattr(self, f.name)))
        if self.optimizer == "sgd" and self.nesterov and self.momentum == 0:
            raise ConfigError(f"{where}: nesterov needs a momentum > 0, got momentum={self.momentum!r}")
        if self.distill_weight > 0 and self.loss != "ce":
            raise ConfigError(f"{where}: distill_weight needs loss 'ce' (distillation matches the teachers' class "
                              f"probabilities), got loss={self.loss!r}")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None, where: str = "recipe") -> Recipe:
        """Validate a plain dict (unknown keys and wrong types raise :class:`ConfigError` naming ``where``)."""
        return resolve_recipe(None, values, where=where)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able values (lists, not tuples): what the config hash covers. Every key is present except the
        optional ones added after cells were first recorded (:data:`HASH_NEUTRAL_KEYS`), which appear only when set."""
        out = asdict(self)
        out["rate_targets"] = list(self.rate_targets)
        for key, off in HASH_NEUTRAL_KEYS.items():
            if out[key] == off:
                del out[key]
        return out

    def replace(self, **changes: Any) -> Recipe:
        return resolve_recipe(self, changes)


def _coerce(where: str, key: str, value: Any) -> Any:
    """One recipe key's value, checked against the schema and in the plain form a recipe holds (``"Adam"`` ->
    ``"adam"``, ``1`` -> ``1.0`` where a float belongs, ``false`` -> ``None`` for a key that can be off)."""
    if key in ("patience", "grad_clip", "ema_decay", "micro_batch_size") and value is False:
        return None
    if key in ("loss", "optimizer", "monitor") and isinstance(value, str):
        value = value.lower()
    if key == "schedule":
        return settings.check_schedule(value, where)
    if key == "rate_targets" and not (isinstance(value, list | tuple) and len(value) == 2):
        raise ConfigError(f"{where}: rate_targets must be [rate of the true class, rate of the others], "
                          f"got {value!r}")
    if key == "rate_targets":
        value = tuple(value)
    return settings.check_field(settings.RecipeSchema, key, value, where)


def check_recipe_keys(layer: Any, where: str) -> dict[str, Any]:
    """One layer of recipe keys (a file's ``recipe``, a ``--set``, an override dict) checked key by key: an unknown
    key, or a value of the wrong type or out of range, is a :class:`ConfigError` naming ``where`` and the key."""
    if not isinstance(layer, Mapping):
        raise ConfigError(f"{where} must be a dict of recipe keys, got {type(layer).__name__}")
    unknown = sorted(set(layer) - set(RECIPE_KEYS), key=str)
    if unknown:
        raise ConfigError(f"{where}: unknown recipe key(s) {unknown}; known keys: {', '.join(RECIPE_KEYS)}")
    return {key: _coerce(where, key, value) for key, value in layer.items()}


def resolve_recipe(base: Recipe | Mapping[str, Any] | None = None, overrides: Mapping[str, Any] | None = None,
                   epochs: int | None = None, where: str = "recipe") -> Recipe:
    """The recipe ``base`` (a Recipe, a model's metadata dict, or ``None`` = the default) with ``overrides`` applied.

    ``epochs`` (the CLI's ``--epochs``) replaces ``max_epochs`` last. Unknown keys raise :class:`ConfigError`. A
    cell's recipe is resolved by :func:`tactile_zoo.engine.config.resolve_model_recipe` (every layer, in order); this
    is the schema's merge of one base and its overrides.
    """
    return _build(recipe_values(base, overrides, epochs, where), where)


def recipe_values(base: Recipe | Mapping[str, Any] | None = None, overrides: Mapping[str, Any] | None = None,
                  epochs: int | None = None, where: str = "recipe") -> dict[str, Any]:
    """The keys :func:`resolve_recipe` builds its recipe from: the defaults, ``base``, ``overrides``, ``epochs``,
    each key checked (:func:`check_recipe_keys`); building the :class:`Recipe` checks their values together."""
    values: dict[str, Any] = {**_DEFAULT_VALUES, "rate_targets": list(_DEFAULT_VALUES["rate_targets"])}
    layers: list[tuple[str, Mapping[str, Any]]] = []
    if isinstance(base, Recipe):
        values = base.to_dict()
    elif base is not None:
        layers.append((where, base))
    if overrides:
        layers.append((where if base is None else f"{where} override", overrides))
    for label, layer in layers:
        values.update(check_recipe_keys(layer, label))
    if epochs is not None:
        values["max_epochs"] = settings.check_field(settings.RecipeSchema, "max_epochs", epochs, where, "epochs")
    return values


def _build(values: Mapping[str, Any], where: str) -> Recipe:
    """The :class:`Recipe` of :func:`recipe_values`' keys; a bad value is a :class:`ConfigError` naming ``where``."""
    try:
        return Recipe(**values)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace("recipe:", f"{where}:", 1)) from None

RECIPE_KEYS = tuple(f.name for f in fields(Recipe))
#: keys added after cells were first recorded, and their "off" value: left out of :meth:`Recipe.to_dict` while off,
#: so that adding a capability never moves an existing cell's hash
HASH_NEUTRAL_KEYS: dict[str, Any] = {"ema_decay": None, "micro_batch_size": None, "distill_weight": 0.0,
                                     "distill_temperature": 1.0}
DEFAULT_RECIPE = Recipe()
_DEFAULT_VALUES = DEFAULT_RECIPE.to_dict()  # the first layer of every resolution (a frozen recipe: read once)
#: the non-training sections a named recipe may carry (see the module docstring)
RECIPE_SECTIONS = ("hparams", "dataset_kwargs", "datasets", "evaluation")
#: the evaluations a named recipe may declare (the engine knows more: ``reference`` and ``tuning`` are chosen by the
#: user for a run, never by a recipe)
RECIPE_EVALUATIONS = ("validation", "final")


def _mapping(where: str, key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{where}: {key} must be a dict of keyword arguments, got {value!r}")
    return dict(value)


def _or_empty(recipe: Mapping[str, Any], key: str) -> Any:
    """``recipe[key]``, with an absent or null key as ``{}``."""
    value = recipe.get(key)
    return {} if value is None else value


def check_named_recipe(recipe: Mapping[str, Any], where: str = "recipe") -> None:
    """Validate a named recipe: its training keys against the schema, its sections' shapes (at registration)."""
    def check_evaluation(key: str, value: Any) -> None:
        if value is not None and value not in RECIPE_EVALUATIONS:
            raise ConfigError(f"{where}: {key} must be one of {', '.join(RECIPE_EVALUATIONS)}, got {value!r}")

    resolve_recipe(named_recipe_for(recipe, None, where)[0], where=where)  # the schema's check of the values
    check_evaluation("evaluation", recipe.get("evaluation"))
    for dataset, section in _mapping(where, "datasets", recipe.get("datasets") or {}).items():
        if not isinstance(section, Mapping):
            raise ConfigError(f"{where}: datasets.{dataset} must be a dict, got {section!r}")
        if "datasets" in section:
            raise ConfigError(f"{where}: datasets.{dataset} cannot nest another 'datasets' section")
        check_evaluation(f"datasets.{dataset}.evaluation", section.get("evaluation"))
        resolve_recipe(named_recipe_for(recipe, dataset, where)[0], where=f"{where} on {dataset}")


def declared_evaluation(recipe: Mapping[str, Any] | None, dataset: str | None) -> str | None:
    """The evaluation a named recipe declares on ``dataset``: its section's, else its own (``None``: undeclared)."""
    if recipe is None:
        return None
    section = (recipe.get("datasets") or {}).get(dataset) if dataset else None
    return (section or {}).get("evaluation") or recipe.get("evaluation")


def named_recipe_for(recipe: Mapping[str, Any] | None, dataset: str | None, where: str = "recipe"
                     ) -> tuple[dict[str, Any] | None, dict[str, Any], dict[str, Any]]:
    """``(training keys, hparams, dataset kwargs)`` of a named recipe on ``dataset`` (``None``: no dataset section).

    The dataset's section (``datasets[dataset]``) overrides the recipe's own training keys, ``hparams`` and
    ``dataset_kwargs`` key by key. A ``None`` recipe (a model without one) gives ``(None, {}, {})``.
    """
    if recipe is None:
        return None, {}, {}
    training = {k: v for k, v in recipe.items() if k not in RECIPE_SECTIONS}
    hparams = settings.check_keywords(_or_empty(recipe, "hparams"), where, "hparams")
    kwargs = settings.check_keywords(_or_empty(recipe, "dataset_kwargs"), where, "dataset_kwargs")
    section = _mapping(where, "datasets", recipe.get("datasets") or {}).get(dataset) if dataset else None
    if section:
        training.update({k: v for k, v in section.items() if k not in RECIPE_SECTIONS})
        hparams.update(settings.check_keywords(_or_empty(section, "hparams"), where, f"datasets.{dataset}.hparams"))
        kwargs.update(settings.check_keywords(_or_empty(section, "dataset_kwargs"), where,
                                              f"datasets.{dataset}.dataset_kwargs"))
    return training, hparams, kwargs


def full_recipe(recipe: Mapping[str, Any], epochs: Mapping[str, int]) -> dict[str, Any]:
    """The ``full`` variant of a named recipe: every training recording, a fixed epoch count per declared dataset.

    ``epochs`` maps a dataset to the epoch count declared for it beforehand from validation evidence alone (the rule
    is in ``benchmarks/results/paper-table1-full/PLAN.md``). On those datasets the variant declares ``evaluation:
    final`` (train on train + val, select nothing, read the test split once) and turns early stopping off. Everything
    else is the recipe's own, the learning-rate schedule included: a cosine schedule keeps the period of the recipe's
    full budget (``t_max``), so the first ``N`` epochs follow the same learning rates as the runs the count came from.

    A dataset without a declared count (a simulator, your own recordings) has no evidence for a fixed budget, so
    there the variant is the recipe itself: the epoch is selected on validation.
    """
    default_period = int(recipe.get("max_epochs", DEFAULT_RECIPE.max_epochs))
    sections = {name: dict(section) for name, section in (recipe.get("datasets") or {}).items()}
    for dataset, count in epochs.items():
        section = sections.setdefault(dataset, {})
        period = int(section.get("max_epochs", default_period))  # the budget whose schedule the count came from
        schedule = _fixed_period(section.get("schedule", recipe.get("schedule")), period)
        if schedule is not None:
            section["schedule"] = schedule
        section.update(max_epochs=int(count), patience=None, evaluation="final")
    return {**recipe, "datasets": sections}


def _fixed_period(schedule: Any, period: int) -> Any:
    """A cosine schedule whose period follows ``max_epochs`` (``t_max`` unset), pinned to ``period`` epochs."""
    if isinstance(schedule, str):
        schedule = {"type": schedule}
    if isinstance(schedule, Mapping) and schedule.get("type") == "cosine" and schedule.get("t_max") is None:
        return {**schedule, "t_max": period}
    return schedule


def cap_epochs(values: Mapping[str, Any], budget: int | None) -> dict[str, Any]:
    """Recipe keys (:func:`recipe_values`) limited to ``budget`` epochs, the schedule compressed to fit (a dataset's
    epoch budget).

    Multistep milestones and step sizes scale by ``budget / max_epochs`` (at least 1), so a schedule keeps its shape;
    a cosine schedule follows ``max_epochs`` by itself. Keys already within the budget are returned unchanged.
    """
    values = dict(values)
    if budget is None or values["max_epochs"] <= budget:
        return values
    scale = budget / values["max_epochs"]
    sched = dict(values["schedule"]) if values.get("schedule") else None
    if sched and sched["type"] == "multistep":
        sched["milestones"] = sorted({max(1, round(m * scale)) for m in sched["milestones"]})
    elif sched and sched["type"] == "step":
        sched["step_size"] = max(1, round(sched["step_size"] * scale))
    elif sched and sched["type"] == "cosine" and sched.get("t_max"):
        sched["t_max"] = max(1, round(sched["t_max"] * scale))
    return {**values, "max_epochs": budget, "schedule": sched}


def lr_factor(recipe: Recipe, epoch: int) -> float:
    """Multiplier of ``recipe.lr`` during 0-based ``epoch`` (the schedule as a pure function of the epoch)."""
    sched = recipe.schedule
    if sched is None:
        return 1.0
    kind = sched["type"]
    if kind == "multistep":
        factor = sched["gamma"] ** sum(1 for m in sched["milestones"] if m <= epoch)
    elif kind == "step":
        factor = sched["gamma"] ** (epoch // sched["step_size"])
    elif kind == "exponential":
        factor = sched["gamma"] ** epoch
    else:  # cosine from 1 down to eta_min over t_max epochs
        t_max = sched.get("t_max") or recipe.max_epochs
        progress = min(epoch, t_max) / t_max
        factor = sched["eta_min"] + (1 - sched["eta_min"]) * 0.5 * (1 + math.cos(math.pi * progress))
    warmup = sched.get("warmup_epochs", 0)
    if warmup and epoch < warmup:
        factor *= (epoch + 1) / warmup
    return float(factor)


def recipe_name_of(config: Mapping[str, Any]) -> str:
    """The recipe name of a cell's stored configuration. Records from before named recipes ran the registered recipe,
    which a built-in model now calls ``"source"`` and a plugin's lone recipe ``"default"``. It lives here, at the
    bottom of the layers, so that every layer can read it; results code gets it from :mod:`tactile_zoo.bench.records`.
    """
    legacy = "source" if config.get("model_source", "builtin") == "builtin" else "default"
    return str(config.get("recipe_name") or legacy)
