"""What both suites share: the error a broken rule raises, the report of a passing check, the rule runner, and the
tiny synthetic specs and batches the model rules run on."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from .. import registry
from ..data.spec import DatasetSpec
from ..errors import ConfigError

__all__ = ["ContractError", "ContractReport", "tiny_spec", "random_batch"]


class ContractError(AssertionError):
    """A model or dataset breaks a rule of its contract.

    An ``AssertionError``, so pytest reports it as a failed check, not as an error in the test. The message names the
    rule, the model or dataset, where (which spec or split) and what was wrong.

    Attributes:
        rule: the rule's name (one of :data:`~tactile_zoo.testing.MODEL_RULES` or
            :data:`~tactile_zoo.testing.DATASET_RULES`).
        subject: the model's or dataset's name.
        where: the spec or split the rule broke on (``""`` for a rule that runs once).
        detail: what was wrong.
    """

    def __init__(self, rule: str, subject: str, detail: str, where: str = "", kind: str = "model") -> None:
        self.rule, self.subject, self.detail, self.where, self.kind = rule, subject, detail, where, kind
        on = f" on {where}" if where else ""
        super().__init__(f"{kind} {subject!r} breaks rule {rule!r}{on}: {detail}")


class Broken(Exception):
    """Raised inside a rule: what is wrong (the runner turns it into a :class:`ContractError`); ``rule``: the rule
    it breaks when that is not the rule running (a stochastic model met by another rule's comparison)."""

    def __init__(self, detail: str, rule: str | None = None) -> None:
        super().__init__(detail)
        self.rule = rule


class Skipped(Exception):  # noqa: N818 - a signal, not an error
    """Raised inside a rule that does not apply (a non-causal model's causal rule): why."""


def expect(condition: Any, detail: str | Callable[[], str]) -> None:
    """Raise :class:`Broken` with ``detail`` (a string, or a callable that builds it) unless ``condition``."""
    if not condition:
        raise Broken(detail() if callable(detail) else detail)


@dataclass
class ContractReport:
    """What a check ran: the rules passed and the rules skipped, each with where (the spec or split).

    Attributes:
        subject: the model's or dataset's name.
        kind: ``"model"`` or ``"dataset"``.
        passed: ``(rule, where)`` for every rule that held.
        skipped: ``(rule, where, why)`` for every rule that did not apply (``"*"``: a whole spec the model cannot
            consume).
        order: every rule of the suite, in the order it runs them.
    """

    subject: str
    kind: str
    passed: list[tuple[str, str]] = field(default_factory=list)
    skipped: list[tuple[str, str, str]] = field(default_factory=list)

    order: tuple[str, ...] = ()

    @property
    def rules(self) -> list[str]:
        """The rules that held at least once, in the suite's order."""
        held = {rule for rule, _ in self.passed}
        return [rule for rule in self.order if rule in held]

    def __str__(self) -> str:
        lines = [f"{self.kind} {self.subject!r}: {len(self.passed)} checks passed, {len(self.skipped)} skipped"]
        lines += [f"  ok    {rule}{f' [{where}]' if where else ''}" for rule, where in self.passed]
        lines += [f"  skip  {rule}{f' [{where}]' if where else ''}: {why}" for rule, where, why in self.skipped]
        return "\n".join(lines)


class Runner:
    """Runs rules for one subject, records them in a report and turns any failure into one :class:`ContractError`."""

    def __init__(self, subject: str, kind: str, known: Sequence[str], rules: Iterable[str] | None,
                 skip: Iterable[str], passthrough: tuple[type[Exception], ...] = ()) -> None:
        wanted = list(known) if rules is None else [rules] if isinstance(rules, str) else list(rules)
        skip = [skip] if isinstance(skip, str) else list(skip)
        unknown = sorted(set(wanted + skip) - set(known))
        if unknown:
            raise ConfigError(f"unknown {kind} rule(s) {unknown}; known: {', '.join(known)}")
        self.selected = [r for r in known if r in wanted and r not in skip]
        self.report = ContractReport(subject, kind, order=tuple(known))
        self.kind, self.passthrough = kind, passthrough

    def wants(self, rule: str) -> bool:
        return rule in self.selected

    def run(self, rule: str, fn: Callable[..., Any], *args: Any, where: str = "") -> Any:
        """``fn(*args)`` as rule ``rule``: its result, or ``None`` when the rule is not selected or skipped."""
        if not self.wants(rule):
            return None
        try:
            result = self.guard(rule, fn, *args, where=where)
        except Skipped as why:
            self.report.skipped.append((rule, where, str(why)))
            return None
        self.report.passed.append((rule, where))
        return result

    def guard(self, rule: str, fn: Callable[..., Any], *args: Any, where: str = "") -> Any:
        """``fn(*args)``, selected or not and unrecorded (a build the other rules need); a failure breaks ``rule``.
        :class:`Skipped` and the exception types in ``passthrough`` pass unchanged."""
        try:
            return fn(*args)
        except (Skipped, ContractError, *self.passthrough):
            raise
        except Broken as exc:
            raise ContractError(exc.rule or rule, self.report.subject, str(exc), where, self.kind) from None
        except Exception as exc:  # any error inside a rule is that rule broken, named with its cause
            raise ContractError(rule, self.report.subject, f"{type(exc).__name__}: {exc}", where, self.kind) from exc


def _dataset_counts(sensor: str) -> tuple[int | None, int]:
    """(channels, globals) of the registered datasets recorded with ``sensor`` (the most globals any carries)."""
    channels, globals_ = None, 0
    for name in registry.list_datasets():
        meta = registry.get_dataset_entry(name).meta
        if meta.get("sensor") == sensor:
            channels = channels or meta.get("num_channels")
            globals_ = max(globals_, int(meta.get("num_globals") or 0))
    return channels, globals_


def tiny_spec(sensor: str, num_steps: int = 12, num_classes: int = 5, num_channels: int | None = None,
              num_globals: int | None = None) -> DatasetSpec:
    """A small synthetic spec on a registered sensor: its taxels, ``num_steps`` steps and ``num_classes`` classes.

    Args:
        sensor: a registered sensor name.
        num_channels: default: the sensor's channels (2 where it names none).
        num_globals: default: the most global features a registered dataset on this sensor carries (the models'
            global-feature branches then run).
    """
    s = registry.get_sensor(sensor)
    dataset_channels, dataset_globals = _dataset_counts(s.name)
    channels = num_channels or len(s.channels) or dataset_channels or 2
    globals_ = dataset_globals if num_globals is None else num_globals
    return DatasetSpec(f"synthetic_{s.name}", num_classes, tuple(f"c{i}" for i in range(num_classes)), num_steps,
                       s.num_nodes, channels, globals_, s)


def random_batch(spec: DatasetSpec, batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``x (B, T, N, C)``, ``g (B, T, G)``, ``y (B,)``: distinct random binary events, labels spread over the classes.

    The event density rises with the sample index, so the classes also differ in density (a model that pools early
    can tell them apart), and binary events drive spiking models.
    """
    gen = torch.Generator().manual_seed(seed)
    density = torch.linspace(0.1, 0.9, batch).view(batch, 1, 1, 1)
    x = (torch.rand(batch, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen) < density).float()
    g = torch.randn(batch, spec.num_steps, spec.num_globals, generator=gen)
    return x, g, torch.arange(batch) * spec.num_classes // batch
