"""The model contract as named rules, and :func:`check_model`, which runs them on a registered name or a class.

Every rule but ``metadata``, ``completeness`` and ``recipes`` runs once per spec. The rules, in the order they run:

- ``metadata``: the metadata (none at all is fine: the harness's defaults) passes ``register_model``'s checks, and
  ``streaming=True`` comes with ``causal=True``.
- ``completeness``: the metadata is complete for publication: a paper, a description, tags, and ``causal`` and
  ``streaming`` declared. Only the ``"publication"`` level runs it (:data:`MODEL_LEVELS`).
- ``recipes``: every named recipe resolves (each of its per-dataset sections too) and sets only constructor
  keywords the model takes.
- ``builds``: ``Model(spec)`` with its defaults gives a ``torch.nn.Module`` with trainable parameters (a
  :class:`~tactile_zoo.errors.ModelCannotConsume` skips the spec's other rules, as the harness skips its cells).
- ``forward``: ``(B, num_classes)`` finite scores of the input's dtype, in training and in eval mode; without global
  features ``g=None`` and the ``(B, T, 0)`` tensor a batch carries give the same scores.
- ``input_unchanged``: ``forward`` leaves ``x`` and ``g`` as they were, in training and in eval mode (the harness
  feeds the same tensors again: to the next epoch's prefixes, to the other models of a grid).
- ``determinism``: two builds after the same seed are equal, and a second forward in eval mode repeats the first.
  A model whose eval-mode scores change from one forward to the next on the same input is named *stochastic* here,
  whichever rule's comparison met it first.
- ``inputs``: a model whose ``inputs`` name ``globals`` reads them: other global features change its scores (or, for
  a spiking model silent before training, a gradient reaches them).
- ``batch_independence``: in eval mode a sample's scores do not depend on its batch-mates.
- ``gradients``: the recipe's loss reaches every trainable parameter with a finite, non-zero gradient.
- ``causal``: a ``causal=True`` model reads every prefix ``x[:, :t]`` (the harness's early classification just stops
  reading it there).
- ``streaming``: a ``streaming=True`` model's ``init_state``/``step`` give, after every frame, the scores of
  ``forward`` on the prefix read so far.
- ``state_dict``: the ``state_dict`` (after a training pass) survives ``torch.save``/``torch.load(weights_only=True)``
  and makes a model built after another seed compute the same scores.

Levels (:data:`MODEL_LEVELS`): ``"plugin"``, the default, is what the harness needs to run a model (every rule but
``completeness``: a plugin author's own model needs no paper); ``"publication"`` adds ``completeness``, and is the
level every built-in model keeps.
"""

from __future__ import annotations

import inspect
import io
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import torch

from .. import registry
from ..data.spec import DatasetSpec
from ..engine.config import resolve_model_recipe
from ..engine.runtime import seed_everything
from ..engine.train import compute_loss
from ..errors import ConfigError, ModelCannotConsume
from ..recipe import DEFAULT_RECIPE
from ..registry.entries import _check_meta, _normalise_recipes
from ._contract import Broken, ContractReport, Runner, Skipped, expect, random_batch, tiny_spec

__all__ = ["MODEL_RULES", "MODEL_LEVELS", "check_model"]

#: The model rules, in the order :func:`check_model` runs them (the module docstring says what each checks).
MODEL_RULES = ("metadata", "completeness", "recipes", "builds", "forward", "input_unchanged", "determinism", "inputs",
               "batch_independence", "gradients", "causal", "streaming", "state_dict")
#: The rules of each level (module docstring): ``"plugin"`` (the default) runs the harness needs, ``"publication"``
#: all of them.
MODEL_LEVELS = {"plugin": tuple(r for r in MODEL_RULES if r != "completeness"), "publication": MODEL_RULES}
#: scores that should be equal may differ by float rounding (a batched matmul sums in another order)
ATOL, RTOL = 1e-5, 1e-4
BATCH = 4
STREAM_STEPS = 7  # frames the streaming rule steps through (every prefix up to this length)


class _Subject:
    """The model under check: its name, its factory and its metadata (registered, or the class's ``zoo_meta``)."""

    def __init__(self, model: str | Callable[..., Any], meta: Mapping[str, Any] | None) -> None:
        if isinstance(model, str):
            entry = registry.get_model_entry(model)
            self.name, self.factory = registry.listed_name(entry), entry.obj
            self.meta: Mapping[str, Any] | None = entry.meta if meta is None else meta
        else:
            self.name = getattr(model, "__name__", type(model).__name__)
            self.factory = model
            self.meta = getattr(model, "zoo_meta", None) if meta is None else meta
        if isinstance(self.meta, Mapping):  # as registration stores it: a lone recipe is the one named "default"
            self.meta = _normalise_recipes("model", dict(self.meta))

    def build(self, spec: DatasetSpec, hparams: Mapping[str, Any], seed: int = 0) -> torch.nn.Module:
        seed_everything(seed)  # as the harness builds a model: its initial weights depend on the seed only
        model = self.factory(spec, **hparams)
        expect(isinstance(model, torch.nn.Module), f"building it gave a {type(model).__name__}, not a torch.nn.Module")
        return model

    def recipe(self) -> Any:
        if not self.meta or not (self.meta.get("recipes") or self.meta.get("recipe")):
            return DEFAULT_RECIPE
        return resolve_model_recipe(self.meta, owner=f"model {self.name!r}").recipe


def _close(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.shape == b.shape and torch.allclose(a, b, atol=ATOL, rtol=RTOL)


def _diff(a: torch.Tensor, b: torch.Tensor) -> str:
    return f"they differ by up to {(a - b).abs().max().item():.3g}" if a.shape == b.shape else \
        f"shapes {tuple(a.shape)} and {tuple(b.shape)}"


# --- the rules that run once -----------------------------------------------------------------------------------


def _metadata(subject: _Subject) -> None:
    meta = _normalise_recipes("model", _check_meta("model", subject.name, subject.meta or {}))
    expect(meta.get("causal") or not meta.get("streaming"), "streaming=True needs causal=True")


def _completeness(subject: _Subject) -> None:
    expect(subject.meta is not None, "it has no metadata: register it with register_model(...) or give the class a "
                                     "zoo_meta dict (the keys register_model accepts)")
    meta = subject.meta
    for key in ("paper", "description"):
        value = meta.get(key)
        expect(isinstance(value, str) and value.strip(), f"metadata {key!r} is missing or empty (the publication "
                                                         f"level wants it; a plugin's own model need not have it)")
    expect(meta.get("tags"), "metadata 'tags' is missing or empty (list_models(tags=...) filters on it)")
    for key in ("causal", "streaming"):
        expect(isinstance(meta.get(key), bool), f"metadata {key!r} must be declared True or False")


def _constructor_keywords(factory: Callable[..., Any]) -> set[str] | None:
    """The keywords ``factory(spec, ...)`` takes; ``None`` when it takes any (``**kwargs``) or cannot be read."""
    try:
        params = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return None
    return {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def _recipes(subject: _Subject) -> None:
    meta = subject.meta or {}
    recipes = meta.get("recipes") or ({"default": meta["recipe"]} if meta.get("recipe") else {})
    if not recipes:
        raise Skipped("it registers no recipe (it trains with the harness's default)")
    accepted = _constructor_keywords(subject.factory)
    for name, recipe in recipes.items():
        for dataset in [None, *sorted((recipe or {}).get("datasets") or {})]:  # the recipe, then each section
            resolved = resolve_model_recipe(meta, name, dataset, owner=f"model {subject.name!r}")
            unknown = sorted(set(resolved.hparams) - accepted) if accepted is not None else []
            on = f" on {dataset}" if dataset else ""
            expect(not unknown, f"recipe {name!r}{on} sets hyper-parameter(s) {unknown} the constructor does not take")


# --- the rules that run per spec ---------------------------------------------------------------------------------


def _builds(subject: _Subject, spec: DatasetSpec) -> None:
    model = subject.build(spec, {})
    trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    expect(trainable > 0, "built with its defaults, it has no trainable parameter")


def _stochastic(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, blame: str | None) -> None:
    """Raise :class:`Broken` naming the model stochastic (under rule ``blame``, when given) if two forwards in eval
    mode on the same input differ: called where another comparison failed, so that it is not blamed on that one."""
    model.eval()
    with torch.no_grad():
        a, b = model(x, g), model(x, g)
    if not _close(a, b):
        raise Broken(_stochastic_text(_diff(a, b)), rule=blame)


def _stochastic_text(diff: str) -> str:
    return (f"it is stochastic: a second forward in eval mode on the same input differs from the first ({diff}): "
            f"randomness at evaluation (noise, dropout or sampling left on), or state kept between calls")


def _forward(model: torch.nn.Module, spec: DatasetSpec, x: torch.Tensor, g: torch.Tensor,
             blame: str | None = None) -> None:
    for mode in ("train", "eval"):
        model.train(mode == "train")
        with torch.no_grad():
            out = model(x, g)
        expect(isinstance(out, torch.Tensor), f"forward in {mode} mode returned a {type(out).__name__}, not a tensor")
        expect(tuple(out.shape) == (x.shape[0], spec.num_classes),
               f"forward in {mode} mode gave shape {tuple(out.shape)}, expected (B, num_classes) = "
               f"{(x.shape[0], spec.num_classes)}")
        expect(out.dtype == x.dtype, f"forward in {mode} mode gave {out.dtype} scores for {x.dtype} input")
        expect(torch.isfinite(out).all(), f"forward in {mode} mode gave non-finite scores "
                                          f"({int((~torch.isfinite(out)).sum())} of {out.numel()})")
    if spec.num_globals == 0:  # g may be omitted, or come as the (B, T, 0) tensor collate() builds
        with torch.no_grad():
            a, b = model(x, None), model(x, g)
        if not _close(a, b):
            _stochastic(model, x, g, blame)
            raise Broken(f"g=None and an empty (B, T, 0) g give different scores: {_diff(a, b)}")


def _input_unchanged(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor) -> None:
    for mode in ("train", "eval"):
        model.train(mode == "train")
        given = {"x": x.clone(), "g": g.clone()}
        versions = {name: value._version for name, value in given.items()}  # counts in-place writes, even same values
        with torch.no_grad():
            model(given["x"], given["g"])
        for name, kept in (("x", x), ("g", g)):
            value = given[name]
            same = value.shape == kept.shape and torch.equal(value, kept)
            expect(same and value._version == versions[name],
                   f"forward in {mode} mode changes its input {name} in place ("
                   f"{'its values changed' if not same else 'an in-place operation wrote it'}: {name}.clamp_(), "
                   f"{name}.mul_(), {name}[...] = ...); the harness passes the same tensors again, so work on a copy "
                   f"({name} = {name}.clamp(...))")


def _inputs(model: torch.nn.Module, meta: Mapping[str, Any], spec: DatasetSpec, x: torch.Tensor,
            g: torch.Tensor) -> None:
    if "globals" not in meta.get("inputs", ()) or spec.num_globals == 0:
        raise Skipped("it declares no global-feature input, or the spec has none")
    model.eval()
    other = torch.randn(g.shape, generator=torch.Generator().manual_seed(99)) * 3.0
    with torch.no_grad():
        if not torch.equal(model(x, g), model(x, other)):
            return
    # an untrained spiking model may not fire at all in eval mode: then the (surrogate) gradient has to show it
    probe = g.clone().requires_grad_(True)
    model(x, probe).sum().backward()
    model.zero_grad(set_to_none=True)
    expect(probe.grad is not None and probe.grad.abs().sum() > 0,
           "its metadata 'inputs' names 'globals', but other global features leave its scores unchanged and no "
           "gradient reaches them")


def _batch_independence(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor, blame: str | None = None) -> None:
    model.eval()
    with torch.no_grad():
        together = model(x, g)
        for i in (0, x.shape[0] - 1):
            alone = model(x[i:i + 1], g[i:i + 1])
            if not _close(alone[0], together[i]):
                _stochastic(model, x, g, blame)
                raise Broken(f"in eval mode sample {i}'s scores alone differ from its scores in a batch of "
                             f"{x.shape[0]} (batch-mates leak in, e.g. through batch statistics): "
                             f"{_diff(alone[0], together[i])}")


def _determinism(subject: _Subject, spec: DatasetSpec, hparams: Mapping[str, Any], x: torch.Tensor,
                 g: torch.Tensor, seed: int) -> None:
    a, b = subject.build(spec, hparams, seed).eval(), subject.build(spec, hparams, seed).eval()
    sa, sb = a.state_dict(), b.state_dict()
    expect(sa.keys() == sb.keys(), "two builds after the same seed have different state_dict keys")
    unequal = [k for k in sa if not torch.equal(sa[k], sb[k])]
    expect(not unequal, f"two builds after the same seed differ in {unequal[:3]} (randomness the seed does not "
                        f"reach: an unseeded generator, numpy's default_rng(), ...)")
    with torch.no_grad():
        first = a(x, g)
        second = a(x, g)
        expect(torch.equal(first, second), lambda: _stochastic_text(_diff(first, second)))
        expect(torch.equal(first, b(x, g)), "two builds after the same seed give different scores")


def _gradients(model: torch.nn.Module, recipe: Any, x: torch.Tensor, g: torch.Tensor, y: torch.Tensor) -> None:
    model.train()
    model.zero_grad(set_to_none=True)
    compute_loss(model(x, g), y, recipe).backward()
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        expect(p.grad is not None, f"trainable parameter {name!r} gets no gradient from the {recipe.loss} loss")
        expect(torch.isfinite(p.grad).all(), f"trainable parameter {name!r} gets a non-finite gradient")
        expect(p.grad.abs().sum() > 0, f"trainable parameter {name!r} gets an all-zero gradient")
    model.zero_grad(set_to_none=True)


def _causal(model: torch.nn.Module, meta: Mapping[str, Any], spec: DatasetSpec, x: torch.Tensor,
            g: torch.Tensor) -> None:
    if not meta.get("causal"):
        raise Skipped("causal=False")
    model.eval()
    with torch.no_grad():
        for t in sorted({1, spec.num_steps // 2, spec.num_steps - 1} - {0}):
            try:
                out = model(x[:, :t], g[:, :t])
            except Exception as exc:
                raise Broken(f"causal=True, but it cannot read the prefix of {t} of {spec.num_steps} steps "
                             f"({type(exc).__name__}: {exc})") from exc
            expect(tuple(out.shape) == (x.shape[0], spec.num_classes) and torch.isfinite(out).all(),
                   f"causal=True, but on the prefix of {t} steps it gives shape {tuple(out.shape)} or non-finite "
                   f"scores")


def _streaming(model: torch.nn.Module, meta: Mapping[str, Any], spec: DatasetSpec, x: torch.Tensor,
               g: torch.Tensor) -> None:
    if not meta.get("streaming"):
        raise Skipped("streaming=False")
    expect(callable(getattr(model, "init_state", None)) and callable(getattr(model, "step", None)),
           "streaming=True, but it has no init_state(batch_size) and step(x_t, g_t, state)")
    model.eval()
    x, g = x[:2], g[:2]
    with torch.no_grad():
        state = model.init_state(2)
        for t in range(min(STREAM_STEPS, spec.num_steps)):
            scores, state = model.step(x[:, t], g[:, t] if spec.num_globals else None, state)
            full = model(x[:, :t + 1], g[:, :t + 1])
            if not _close(scores, full):
                raise Broken(f"after frame {t} step() and forward on the prefix of {t + 1} steps disagree: "
                             f"{_diff(scores, full)}")


def _state_dict(subject: _Subject, spec: DatasetSpec, hparams: Mapping[str, Any], x: torch.Tensor,
                g: torch.Tensor, seed: int) -> None:
    source = subject.build(spec, hparams, seed).train()
    with torch.no_grad():
        source(x, g)  # a training pass: running statistics and other buffers leave their initial values
    source.eval()
    buffer = io.BytesIO()
    torch.save(source.state_dict(), buffer)
    buffer.seek(0)
    state = torch.load(buffer, weights_only=True)
    target = subject.build(spec, hparams, seed + 1)
    target.load_state_dict(state, strict=True)
    target.eval()
    with torch.no_grad():
        a, b = source(x, g), target(x, g)
    expect(_close(a, b), lambda: f"a model loaded from its state_dict computes other scores ({_diff(a, b)}): "
                                 f"something it computes with is neither a parameter nor a buffer")


def _check_spec(run: Runner, subject: _Subject, spec: DatasetSpec, hparams: Mapping[str, Any], seed: int) -> None:
    where = f"{spec.name} (T={spec.num_steps}, N={spec.num_nodes}, C={spec.num_channels}, G={spec.num_globals}, " \
            f"K={spec.num_classes})"
    try:
        run.run("builds", _builds, subject, spec, where=where)
        model = run.guard("builds", subject.build, spec, hparams, seed, where=where)
    except ModelCannotConsume as exc:  # the model says so, as the harness expects: a verdict, not a broken rule
        run.report.skipped.append(("*", where, f"it cannot consume this spec: {exc}"))
        return
    meta = subject.meta or {}
    x, g, y = random_batch(spec, BATCH, seed=1)
    blame = "determinism" if run.wants("determinism") else None  # a stochastic model breaks this rule, named so
    run.run("forward", _forward, model, spec, x, g, blame, where=where)
    run.run("input_unchanged", _input_unchanged, model, x, g, where=where)
    # randomness first: it would pass for a global-feature input or fail batch independence, and mislead both
    run.run("determinism", _determinism, subject, spec, hparams, x[:3], g[:3], seed + 7, where=where)
    run.run("inputs", _inputs, model, meta, spec, x, g, where=where)
    run.run("batch_independence", _batch_independence, model, x, g, blame, where=where)
    run.run("gradients", _gradients, model, subject.recipe(), x, g, y, where=where)
    run.run("causal", _causal, model, meta, spec, x, g, where=where)
    run.run("streaming", _streaming, model, meta, spec, x, g, where=where)
    run.run("state_dict", _state_dict, subject, spec, hparams, x, g, seed, where=where)


def check_model(model: str | Callable[..., Any], specs: DatasetSpec | Sequence[DatasetSpec] | None = None, *,
                hparams: Mapping[str, Any] | None = None, meta: Mapping[str, Any] | None = None,
                rules: Iterable[str] | None = None, skip: Iterable[str] = (), seed: int = 0,
                level: str = "plugin") -> ContractReport:
    """Check a model against the model contract; raise one :class:`~tactile_zoo.testing.ContractError` on the first
    rule it breaks.

    Args:
        model: a registered model name (a plugin's ``dist:name`` too), or the class or factory
            ``f(spec, **hparams)`` itself (its metadata is then its ``zoo_meta`` attribute, or ``meta``).
        specs: the specs to check on; default: a tiny synthetic spec (:func:`~tactile_zoo.testing.tiny_spec`: 12
            steps, 5 classes) on every registered sensor.
        hparams: constructor keywords for every rule but ``builds`` (which builds with the defaults): small sizes
            keep a large model's check fast.
        meta: metadata to check instead of the registered (or ``zoo_meta``) one.
        rules: run only these rules (default: the rules of ``level``).
        skip: rules not to run.
        seed: the seed every build starts from.
        level: ``"plugin"`` (default: what the harness needs to run the model; metadata completeness is not
            asked for) or ``"publication"`` (every rule, ``completeness`` too: what a built-in model keeps);
            :data:`MODEL_LEVELS`.

    Returns:
        The report: every rule that held, and every rule that did not apply, with the spec.

    Raises:
        ContractError: the rule broken, the model, the spec and what was wrong.
    """
    subject = _Subject(model, meta)
    if level not in MODEL_LEVELS:
        raise ConfigError(f"unknown check_model level {level!r}; known: {', '.join(MODEL_LEVELS)}")
    run = Runner(subject.name, "model", MODEL_RULES, MODEL_LEVELS[level] if rules is None else rules, skip,
                 passthrough=(ModelCannotConsume,))
    run.run("metadata", _metadata, subject)
    run.run("completeness", _completeness, subject)
    run.run("recipes", _recipes, subject)
    if specs is None:
        specs = [tiny_spec(sensor) for sensor in registry.list_sensors()]
    elif isinstance(specs, DatasetSpec):
        specs = [specs]
    hparams = dict(hparams or {})
    for spec in specs:
        _check_spec(run, subject, spec, hparams, seed)
    return run.report
