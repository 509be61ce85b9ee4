"""The settings schema: every key of every settings surface, its type and its range, written once.

The training recipe (:class:`RecipeSchema`, with its schedule, :class:`ScheduleSchema`), the bench settings
(:class:`BenchSettings`: the ``tactile-zoo bench`` flags, a ``--config`` YAML file, :class:`~tactile_zoo.bench.
BenchConfig` in Python, and the study files that reuse it) and constructor or dataset keywords (:data:`KEYWORDS`)
are pydantic models. :mod:`tactile_zoo.recipe`, the registry (recipe files, a plugin's recipe metadata), the engine
and the harness all check values here, so that a YAML file, ``--set``, ``--hparam`` and the Python API accept
exactly the same values.

Types are strict: no string is taken as a boolean or a number (YAML and ``--set`` values already arrive as the
``true``/``1e-3`` they spell), and a number is a number: an integer is accepted where a float belongs and becomes that
float, a float is never taken as an integer. Every key has a range. A bad value is a :class:`ConfigError` in the house
style, ``WHERE: KEY must be ..., got VALUE`` (:func:`check_value`).
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Mapping
from functools import cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, Strict, TypeAdapter, ValidationError

from .errors import ConfigError

__all__ = ["RecipeSchema", "ScheduleSchema", "TeachersSchema", "BenchSettings", "KEYWORDS", "EVALUATIONS", "LOSSES",
           "OPTIMIZERS", "MONITORS", "SCHEDULES", "check_value", "check_field", "check_keywords", "check_prefixes",
           "prefix_label", "describe_error"]

def _not_subnormal(value: Any) -> Any:
    """Refuse a subnormal float (below 2.2e-308 in size, not 0). Training flushes it to zero, and so does every
    command's flush-to-zero block, in which a range check misreads it (``-1e-310 >= 0`` holds there); so it is
    refused before any comparison, from its bits."""
    if type(value) is float:
        bits = struct.unpack("<Q", struct.pack("<d", value))[0]
        if (bits >> 52) & 0x7FF == 0 and bits & ((1 << 52) - 1):
            raise ValueError("must be 0 or at least 2.2e-308 in size (a subnormal number is flushed to zero)")
    return value


_Normal = BeforeValidator(_not_subnormal)
Int = Annotated[int, Strict()]
PositiveInt = Annotated[int, Strict(), Field(ge=1)]
NonNegativeInt = Annotated[int, Strict(), Field(ge=0)]
Number = Annotated[float, Strict(), Field(allow_inf_nan=False), _Normal]
PositiveNumber = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False), _Normal]
NonNegativeNumber = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False), _Normal]
Fraction = Annotated[float, Strict(), Field(ge=0, lt=1, allow_inf_nan=False), _Normal]  # [0, 1)
OpenFraction = Annotated[float, Strict(), Field(gt=0, lt=1, allow_inf_nan=False), _Normal]  # (0, 1)
Rate = Annotated[float, Strict(), Field(ge=0, le=1, allow_inf_nan=False), _Normal]  # [0, 1]
Decay = Annotated[float, Strict(), Field(gt=0, le=1, allow_inf_nan=False), _Normal]  # (0, 1]
Bool = Annotated[bool, Strict()]
Text = Annotated[str, Strict(), Field(min_length=1)]
Identifier = Annotated[str, Strict(), Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]

LOSSES = ("ce", "mse_rate")
OPTIMIZERS = ("adam", "adamw", "sgd")
MONITORS = ("val_accuracy", "val_loss")
#: the schedule types and the keys each takes (besides ``type`` and ``warmup_epochs``)
SCHEDULES = {"multistep": ("milestones", "gamma"), "step": ("step_size", "gamma"), "exponential": ("gamma",),
             "cosine": ("eta_min", "t_max")}
#: How a cell reaches its test figure (the meaning of each: :data:`tactile_zoo.engine.config.EVALUATIONS`).
EVALUATIONS = ("validation", "reference", "tuning", "final")
EXECUTORS = ("local", "process", "dask")
TRACKERS = ("tensorboard", "mlflow")


class _Schema(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, protected_namespaces=())


class ScheduleSchema(_Schema):
    """A learning-rate schedule's keys (``type`` chooses which apply: :data:`SCHEDULES`)."""

    type: Literal["multistep", "step", "exponential", "cosine"]
    #: epochs (0-based, increasing) after which the rate is multiplied by gamma
    milestones: Annotated[list[NonNegativeInt], Field(min_length=1)] | None = None
    gamma: Decay = 0.1
    step_size: PositiveInt = 30
    eta_min: Rate = 0.0
    t_max: PositiveInt | None = None
    warmup_epochs: NonNegativeInt = 0


class RecipeSchema(_Schema):
    """The training recipe's keys (:mod:`tactile_zoo.recipe` documents each)."""

    loss: Literal["ce", "mse_rate"] = "ce"
    optimizer: Literal["adam", "adamw", "sgd"] = "adam"
    lr: PositiveNumber = 1e-3
    weight_decay: NonNegativeNumber = 0.0
    amsgrad: Bool = False
    momentum: Fraction = 0.9
    nesterov: Bool = False
    schedule: dict[str, Any] | None = None  # checked by :func:`check_schedule`
    max_epochs: PositiveInt = 100
    patience: PositiveInt | None = 20
    monitor: Literal["val_accuracy", "val_loss"] = "val_accuracy"
    batch_size: PositiveInt = 32
    eval_batch_size: PositiveInt = 256
    grad_clip: PositiveNumber | None = None
    label_smoothing: Fraction = 0.0
    rate_targets: tuple[Rate, Rate] = (1.0, 0.0)
    ema_decay: OpenFraction | None = None
    micro_batch_size: PositiveInt | None = None
    distill_weight: Rate = 0.0
    distill_temperature: PositiveNumber = 1.0


class TeachersSchema(_Schema):
    """Distillation's teachers (:mod:`tactile_zoo.engine.distill`): the cells of the student's own configuration,
    distillation off, with these seeds, in the bench folder ``folder``, which saved their weights."""

    folder: Text
    seeds: Annotated[list[NonNegativeInt], Field(min_length=1)]


#: constructor keywords (``--hparam``, a recipe's ``hparams``) and dataset keywords (``--dataset-arg``): keyword
#: names mapped to plain values (the model or the dataset checks its own values; :func:`check_keywords` refuses a
#: NaN or an infinity, which no record can hold)
KEYWORDS = TypeAdapter(dict[Identifier, Any])


class BenchSettings(_Schema):
    """Every setting of a bench run, as a ``--config`` file or :class:`~tactile_zoo.bench.BenchConfig` gives it:
    the types and ranges (a list may also be written as a comma-separated string, as on the command line). The one
    list of the settings: ``BenchConfig`` takes its fields, their order and their defaults from this class."""

    models: Text | list[Text] = "all"
    datasets: Text | list[Text] = "all"
    root: Text | None = None
    download: Bool = False
    seeds: NonNegativeInt | Text | list[NonNegativeInt | Text] = 0
    folds: PositiveInt | Literal["all"] | None = None
    epochs: PositiveInt | None = None
    refit: Bool = False
    quick: Bool = False
    device: Text = "auto"
    out: Text | None = None
    force: Bool = False
    executor: Literal["local", "process", "dask"] = "local"
    workers: PositiveInt | None = None
    scheduler: Text | None = None
    retries: NonNegativeInt | None = None
    dashboard: Text | None = None
    save_weights: Bool = False
    tracker: Literal["tensorboard", "mlflow"] | None = None
    tracker_dir: Text | None = None
    threads: PositiveInt | None = None
    plugin_modules: Text | list[Text] | None = None
    prefixes: Text | list[Number] | None = None  # :func:`check_prefixes` checks the fractions
    recipe_name: Text | None = None
    evaluation: Literal["validation", "reference", "tuning", "final"] | None = None
    recipe: dict[Text, Any] | Text = Field(default_factory=dict)  # recipe keys (RecipeSchema), or a recipe's name
    hparams: dict[Identifier, Any] = Field(default_factory=dict)
    model_overrides: dict[Text, dict[Literal["recipe", "hparams"], dict[Text, Any]]] = Field(default_factory=dict)
    dataset_kwargs: dict[Text, dict[Identifier, Any]] = Field(default_factory=dict)
    model_revisions: dict[Text, PositiveInt] = Field(default_factory=dict)  # model ("*": every model) -> revision
    teachers: TeachersSchema | None = None  # distillation's teachers (a recipe's distill_weight > 0 needs them)


_PHRASES = {
    "int_type": "must be an integer", "float_type": "must be a number", "bool_type": "must be true or false",
    "string_type": "must be a string", "finite_number": "must be a finite number", "dict_type": "must be a dict",
    "list_type": "must be a list", "tuple_type": "must be a list", "string_too_short": "must not be empty",
    "extra_forbidden": "is not a known key", "missing": "is required",
}


def _phrase(error: Mapping[str, Any]) -> str:
    kind, ctx = error["type"], error.get("ctx") or {}
    if kind in _PHRASES:
        return _PHRASES[kind]
    bounds = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}
    if kind == "greater_than" and ctx.get("gt") == 0:
        return "must be a positive number"
    if kind in bounds:
        limit = next(iter(ctx.values()))
        return f"must be {bounds[kind]} {limit:g}" if isinstance(limit, float) else \
            f"must be an integer {bounds[kind]} {limit}"
    if kind == "literal_error":
        return "must be one of " + ", ".join(re.findall(r"'([^']*)'", str(ctx.get("expected", ""))))
    if kind == "too_short":
        return f"must hold at least {ctx.get('min_length')} item(s)"
    if kind in ("too_long", "tuple_length"):
        return f"must hold {ctx.get('max_length')} item(s)" if kind == "too_long" else "has the wrong length"
    if kind == "string_pattern_mismatch":
        return "must be a Python identifier (letters, digits, _)"
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    return str(error["msg"]).lower()


def describe_error(exc: ValidationError, where: str, key: str = "") -> str:
    """One line for a pydantic error: ``WHERE: KEY.PATH must be ..., got VALUE`` (the first error; for a value
    several types allow, the error of the type closest to what was given)."""
    errors = exc.errors(include_url=False)
    error = min(errors, key=lambda e: (e["type"] in ("int_type", "float_type", "string_type", "bool_type",
                                                     "literal_error", "list_type", "dict_type"), len(e["loc"])))
    name = key
    for part in (p for p in error["loc"] if not _is_tag(p)):
        name += f"[{part}]" if isinstance(part, int) else (f".{part}" if name else str(part))
    name = name or "value"
    head = f"{where}: {name}" if where else name
    return f"{head} {_phrase(error)}, got {error['input']!r}"


def _is_tag(part: Any) -> bool:
    """A union member's label in an error location (``list[...]``, ``int``), not a key of the value."""
    return isinstance(part, str) and (part in ("int", "str", "float", "bool", "none") or "[" in part or
                                      part.startswith(("function-", "literal", "constrained-")))


@cache
def _adapter(model: type[BaseModel], key: str) -> TypeAdapter[Any]:
    field = model.model_fields[key]
    if not field.metadata:
        return TypeAdapter(field.annotation)
    return TypeAdapter(Annotated[(field.annotation, *field.metadata)])  # type: ignore[misc]


def check_field(model: type[BaseModel], key: str, value: Any, where: str, name: str | None = None) -> Any:
    """``value`` checked as ``model``'s field ``key`` and converted (an int where a float belongs becomes that
    float); a bad one is a :class:`ConfigError` naming ``where`` and ``name`` (default: ``key``)."""
    try:
        return _adapter(model, key).validate_python(value)
    except ValidationError as exc:
        raise ConfigError(describe_error(exc, where, key if name is None else name)) from None


def check_value(adapter: TypeAdapter[Any], value: Any, where: str, key: str = "") -> Any:
    """``value`` checked by ``adapter``; a bad one is a :class:`ConfigError` naming ``where`` and ``key``."""
    try:
        return adapter.validate_python(value)
    except ValidationError as exc:
        raise ConfigError(describe_error(exc, where, key)) from None


def check_schedule(value: Any, where: str) -> dict[str, Any] | None:
    """A schedule in the plain form a recipe holds (``None``, or ``{"type": ..., its keys}``, defaults filled):
    ``"cosine"`` means ``{"type": "cosine"}``; keys of another type, or a value out of range, raise."""
    if value is None or value in ("none", "None", "constant"):
        return None
    if isinstance(value, str):
        value = {"type": value}
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where}: schedule must be null, a type name or a dict with 'type'; got {value!r}")
    kind = value.get("type")
    if kind not in SCHEDULES:
        raise ConfigError(f"{where}: schedule.type must be one of {', '.join(SCHEDULES)}, got {kind!r}")
    allowed = {"type", "warmup_epochs", *SCHEDULES[kind]}
    unknown = sorted(set(value) - allowed, key=str)
    if unknown:
        raise ConfigError(f"{where}: schedule: unknown key(s) {unknown} in a {kind!r} schedule; allowed: "
                          f"{sorted(allowed)}")
    if kind == "multistep" and "milestones" not in value:
        raise ConfigError(f"{where}: schedule.milestones is required: a multistep schedule needs a non-empty list")
    try:
        checked = ScheduleSchema.model_validate(dict(value))
    except ValidationError as exc:
        raise ConfigError(describe_error(exc, where, "schedule")) from None
    out: dict[str, Any] = {"type": kind}
    if kind == "multistep":
        milestones = list(checked.milestones)
        if any(b <= a for a, b in zip(milestones, milestones[1:], strict=False)):
            raise ConfigError(f"{where}: schedule.milestones must increase, got {value['milestones']!r}")
        out["milestones"] = milestones
    if kind == "step":
        out["step_size"] = checked.step_size
    if kind in ("multistep", "step", "exponential"):
        out["gamma"] = checked.gamma
    if kind == "cosine":
        out["eta_min"], out["t_max"] = checked.eta_min, checked.t_max
    if checked.warmup_epochs:
        out["warmup_epochs"] = checked.warmup_epochs
    return out


def check_keywords(value: Any, where: str, key: str) -> dict[str, Any]:
    """Keyword arguments (``hparams``, ``dataset_kwargs``): a mapping of identifiers to values holding no NaN or
    infinity (every cell records its settings, and a record holds neither)."""
    out = check_value(KEYWORDS, value, where, key)
    budget = [MAX_VALUES]
    for name, item in out.items():
        _refuse_non_finite(where, f"{key}.{name}" if key else name, item, budget)
    return out


#: the most values (nested ones counted) the keywords of one setting may hold: a constructor takes a few, and a
#: value built from shared references (an anchor bomb read by another YAML loader) is refused, not walked for ever
MAX_VALUES = 100_000


def _refuse_non_finite(where: str, key: str, value: Any, budget: list[int]) -> None:
    budget[0] -= 1
    if budget[0] < 0:
        raise ConfigError(f"{where + ': ' if where else ''}{key}: more than {MAX_VALUES:,} values")
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{where + ': ' if where else ''}{key} is {value}, expected a finite number")
    if isinstance(value, Mapping):
        for name, item in value.items():
            _refuse_non_finite(where, f"{key}.{name}", item, budget)
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            _refuse_non_finite(where, f"{key}[{i}]", item, budget)


def prefix_label(fraction: float) -> str:
    """0.25 -> ``"25"``: a prefix fraction as a percentage, as in the column ``accuracy_at_25``."""
    return f"{fraction * 100:g}"


def check_prefixes(value: Any, flag: str = "--prefixes") -> list[float]:
    """Early-classification prefix fractions in (0, 1] (a number above 1, up to 100, is a percentage), sorted and
    distinct, 1.0 always included. Each names a column ``accuracy_at_<percent>``, so a fraction must be written
    with at most 6 decimals (``1e-7`` would round to a column ``accuracy_at_0``)."""
    if isinstance(value, str):
        items: list[Any] = []
        for token in (t.strip() for t in value.split(",")):
            if not token:
                continue
            try:
                items.append(float(token))
            except ValueError:
                raise ConfigError(f"{flag}: {token!r} is not a number") from None
        value = items
    if not isinstance(value, list | tuple) or not value:
        raise ConfigError(f"{flag} must be a comma-separated list of fractions in (0, 1], got {value!r}")
    out: dict[str, float] = {}
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float):
            raise ConfigError(f"{flag}: {item!r} is not a number")
        frac = float(item) / 100 if 1 < item <= 100 else float(item)  # percentages
        if not 0 < frac <= 1:
            raise ConfigError(f"{flag}: {item!r} is not a fraction in (0, 1] (or a percentage)")
        if abs(round(frac, 6) - frac) > 1e-12:
            raise ConfigError(f"{flag}: {item!r} has more than 6 decimals as a fraction; each prefix names a column "
                              f"accuracy_at_<percent>, which would not tell it apart")
        out[prefix_label(round(frac, 6))] = round(frac, 6)
    out[prefix_label(1.0)] = 1.0
    return sorted(out.values())
