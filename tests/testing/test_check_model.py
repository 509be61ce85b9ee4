"""``tactile_zoo.testing.check_model`` passes a sound model and fails each planted broken one on the rule it breaks.

``Sound`` is a tiny causal, streaming model with a global-feature input and a recipe; every planted model below
changes one thing about it, and the check must name exactly that rule (and the model) in one ``ContractError``.
The zoo's own models go through the suite in tests/models/test_zoo.py, the TCN plugin in tests/test_plugin_tcn.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.errors import ConfigError, ModelCannotConsume
from tactile_zoo.registry import _unregister
from tactile_zoo.testing import MODEL_LEVELS, MODEL_RULES, ContractError, check_model, tiny_spec

SPEC = tiny_spec("uskin_allegro")  # 60 taxels, 3 channels, 8 global features: every rule applies
META = {"paper": "-", "description": "a running mean of per-frame features", "tags": ["example"],
        "inputs": ["globals"], "causal": True, "streaming": True,
        "recipe": {"loss": "ce", "optimizer": "adam", "lr": 1e-3, "max_epochs": 2, "patience": None,
                   "batch_size": 4}}


class Sound(nn.Module):
    """Per-frame features, their running mean, a linear head: causal, and ``step`` is exact."""

    zoo_meta = META

    def __init__(self, spec, hidden: int = 8) -> None:
        super().__init__()
        self.frame = nn.Linear(spec.num_nodes * spec.num_channels + spec.num_globals, hidden)
        self.head = nn.Linear(hidden, spec.num_classes)
        self.num_globals = spec.num_globals

    def features(self, x: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
        flat = x.flatten(-2)  # (..., N * C)
        if self.num_globals:
            flat = torch.cat([flat, g], -1)
        return torch.tanh(self.frame(flat))

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.head(self.features(x, g).mean(1))

    def init_state(self, batch_size: int) -> tuple[torch.Tensor, int]:
        return torch.zeros(batch_size, self.head.in_features), 0

    def step(self, x_t, g_t, state):
        total, n = state
        total = total + self.features(x_t, g_t)
        return self.head(total / (n + 1)), (total, n + 1)


def _meta(**changes) -> dict:
    return {**META, **changes}


class BadKey(Sound):
    zoo_meta = _meta(papr="typo")


class StreamingButNotCausal(Sound):
    zoo_meta = _meta(causal=False)


class UnknownRecipeHparam(Sound):
    zoo_meta = {**{k: v for k, v in META.items() if k != "recipe"},
                "recipes": {"zoo": {**META["recipe"], "hparams": {"width": 16}}}}


class NoDefaults(Sound):
    def __init__(self, spec, hidden: int) -> None:  # cannot build with its defaults
        super().__init__(spec, hidden)


class WrongShape(Sound):
    def forward(self, x, g=None):
        return torch.cat([super().forward(x, g), torch.zeros(x.shape[0], 1)], 1)


class NaNScores(Sound):
    def forward(self, x, g=None):
        return super().forward(x, g) * torch.tensor(float("nan"))


class IgnoresGlobals(Sound):
    def features(self, x, g):
        return super().features(x, torch.zeros_like(g) if g is not None else g)


class BatchStatistics(Sound):
    zoo_meta = _meta(streaming=False)  # its step() could not normalise over the batch either

    def forward(self, x, g=None):  # normalises over the batch, in eval mode too
        out = super().forward(x, g)
        return (out - out.mean(0)) / (out.std(0, correction=0) + 1e-5)


class UnseededInit(Sound):
    def __init__(self, spec, hidden: int = 8) -> None:
        super().__init__(spec, hidden)
        noise = np.random.default_rng().normal(size=tuple(self.head.bias.shape))  # fresh entropy, not the seed
        with torch.no_grad():
            self.head.bias.copy_(torch.as_tensor(noise, dtype=torch.float32))


class NoisyEval(Sound):
    def forward(self, x, g=None):
        return super().forward(x, g) + 0.1 * torch.randn(x.shape[0], self.head.out_features)


class ClampsInput(Sound):
    def forward(self, x, g=None):  # issue 49: passed; on binary events it even leaves the values as they were
        x.clamp_(0, 1)
        return super().forward(x, g)


class ScalesGlobals(Sound):
    def features(self, x, g):
        if g is not None:
            g[..., 0] *= 2  # writes into the caller's g through a view
        return super().features(x, g)


class DeadParameter(Sound):
    def __init__(self, spec, hidden: int = 8) -> None:
        super().__init__(spec, hidden)
        self.unused = nn.Linear(3, 3)  # trainable, never in the forward


class WholeSequence(Sound):
    """Reads the whole window at once (one linear layer over T x features): it cannot read a prefix."""

    zoo_meta = _meta(streaming=False)

    def __init__(self, spec, hidden: int = 8) -> None:
        super().__init__(spec, hidden)
        self.time = nn.Linear(spec.num_steps, 1)

    def forward(self, x, g=None):
        h = self.features(x, g)  # (B, T, H)
        return self.head(self.time(h.transpose(1, 2)).squeeze(-1))


class ReversedStep(Sound):
    def step(self, x_t, g_t, state):  # weights the newest frame double: not what forward computes on the prefix
        total, n = state
        total = total + 2 * self.features(x_t, g_t)
        return self.head(total / (n + 1)), (total, n + 1)


class NoStep(Sound):
    init_state = None


class UnsavedProjection(Sound):
    def __init__(self, spec, hidden: int = 8) -> None:
        super().__init__(spec, hidden)
        self.mix = torch.randn(spec.num_classes, spec.num_classes)  # neither a parameter nor a buffer

    def forward(self, x, g=None):
        return super().forward(x, g) @ self.mix

    def step(self, x_t, g_t, state):
        scores, state = super().step(x_t, g_t, state)
        return scores @ self.mix, state


def test_a_sound_model_passes_every_rule_on_every_sensor() -> None:
    report = check_model(Sound, level="publication")
    assert report.subject == "Sound" and report.rules == list(MODEL_RULES)
    sensors = {where.split(" ")[0] for rule, where in report.passed if rule == "forward"}
    assert sensors == {f"synthetic_{s}" for s in tz.list_sensors()}
    # the specs without global features skip the inputs rule, and say why
    assert {where.split(" ")[0] for rule, where, _ in report.skipped if rule == "inputs"} == \
        {"synthetic_neutouch", "synthetic_biotac_sp"}
    assert "ok    state_dict" in str(report)


@pytest.mark.parametrize(("model", "rule", "detail"), [
    (BadKey, "metadata", "unknown metadata key"),
    (StreamingButNotCausal, "metadata", "streaming=True needs causal=True"),
    (UnknownRecipeHparam, "recipes", "['width'] the constructor does not take"),
    (NoDefaults, "builds", "hidden"),
    (WrongShape, "forward", "expected (B, num_classes) = (4, 5)"),
    (NaNScores, "forward", "non-finite scores"),
    (IgnoresGlobals, "inputs", "other global features leave its scores unchanged"),
    (BatchStatistics, "batch_independence", "batch-mates leak in"),
    (UnseededInit, "determinism", "randomness the seed does not reach"),
    (NoisyEval, "determinism", "it is stochastic: a second forward in eval mode on the same input differs"),
    (ClampsInput, "input_unchanged", "forward in train mode changes its input x in place (an in-place operation"),
    (ScalesGlobals, "input_unchanged", "changes its input g in place (its values changed"),
    (DeadParameter, "gradients", "parameter 'unused.weight' gets no gradient"),
    (WholeSequence, "causal", "cannot read the prefix of 1 of 12 steps"),
    (ReversedStep, "streaming", "step() and forward on the prefix"),
    (NoStep, "streaming", "has no init_state"),
    (UnsavedProjection, "state_dict", "neither a parameter nor a buffer"),
])
def test_a_planted_break_fails_its_rule(model: type, rule: str, detail: str) -> None:
    with pytest.raises(ContractError) as info:
        check_model(model, SPEC, hparams={"hidden": 8})
    err = info.value
    assert (err.rule, err.subject) == (rule, model.__name__), str(err)
    assert detail in err.detail, str(err)
    assert str(err).startswith(f"model {model.__name__!r} breaks rule {rule!r}")
    assert isinstance(err, AssertionError)  # pytest reports it as a failed check
    if rule not in ("metadata", "recipes"):
        assert "synthetic_uskin_allegro" in err.where
    # the same model passes once that rule is skipped: the break is confined to it
    if model not in (WrongShape, NaNScores, NoisyEval, ScalesGlobals):  # they break the rules after theirs too
        check_model(model, SPEC, hparams={"hidden": 8}, skip=[rule])


def test_a_registered_model_is_named_by_its_registry_name() -> None:
    tz.register_model("planted_batch_stats", **BatchStatistics.zoo_meta)(BatchStatistics)
    try:
        with pytest.raises(ContractError, match=r"model 'planted_batch_stats' breaks rule 'batch_independence'"):
            check_model("Planted-Batch-Stats", SPEC)
    finally:
        _unregister("model", "planted_batch_stats")


def test_metadata_given_by_the_caller_is_what_is_checked() -> None:
    class Bare(Sound):
        zoo_meta = None

    with pytest.raises(ContractError, match="it has no metadata"):
        check_model(Bare, SPEC, rules=["metadata", "completeness"])
    assert check_model(Bare, SPEC, meta=META, rules=["metadata", "completeness"]).rules == ["metadata",
                                                                                         "completeness"]


class OwnPlugin(Sound):
    """A plugin author's own model (issue 49, item 14): no paper, no description, no tags; the harness runs it."""

    zoo_meta = {"inputs": ["globals"], "causal": True, "streaming": True}


@pytest.mark.parametrize("meta", [OwnPlugin.zoo_meta, None, {}])
def test_a_plugin_authors_own_model_passes_the_default_level_and_not_the_publication_one(meta) -> None:
    class Own(OwnPlugin):
        zoo_meta = meta

    report = check_model(Own, SPEC, hparams={"hidden": 8})  # the default level: "plugin"
    # no recipe: it trains with the harness's default; without metadata, it is neither causal nor streaming
    skipped = {"recipes"} | (set() if meta else {"inputs", "causal", "streaming"})
    assert report.rules == [r for r in MODEL_LEVELS["plugin"] if r not in skipped]
    assert "completeness" not in report.rules and "completeness" in MODEL_RULES
    with pytest.raises(ContractError) as info:
        check_model(Own, SPEC, hparams={"hidden": 8}, level="publication")
    assert info.value.rule == "completeness", str(info.value)
    assert ("'paper' is missing or empty" if meta is not None else "it has no metadata") in info.value.detail
    with pytest.raises(ConfigError, match="unknown check_model level 'strict'; known: plugin, publication"):
        check_model(Own, SPEC, level="strict")


@pytest.mark.parametrize("key", ["paper", "description", "tags", "streaming"])
def test_the_publication_level_names_each_missing_key(key: str) -> None:
    class Partial(Sound):
        zoo_meta = {k: v for k, v in META.items() if k != key}

    with pytest.raises(ContractError, match=f"breaks rule 'completeness': metadata '{key}'"):
        check_model(Partial, SPEC, level="publication", rules=None, skip=["recipes"])


def test_a_stochastic_model_is_named_stochastic_not_blamed_on_g() -> None:
    """Issue 49, item 13: on a spec without global features the first comparison a noisy model met was g=None
    against the empty g, and it was reported as "g=None and an empty g give different scores"."""
    spec = tiny_spec("neutouch")
    with pytest.raises(ContractError) as info:
        check_model(NoisyEval, spec, hparams={"hidden": 8})
    assert info.value.rule == "determinism" and "it is stochastic" in info.value.detail, str(info.value)
    assert "g=None" not in str(info.value)
    with pytest.raises(ContractError) as info:  # determinism skipped: the rule that met it says stochastic
        check_model(NoisyEval, spec, hparams={"hidden": 8}, skip=["determinism"])
    assert info.value.rule == "forward" and "it is stochastic" in info.value.detail, str(info.value)
    with pytest.raises(ContractError) as info:  # the same on a spec with globals, where batch independence meets it
        check_model(NoisyEval, SPEC, hparams={"hidden": 8}, skip=["determinism"])
    assert info.value.rule == "batch_independence" and "it is stochastic" in info.value.detail, str(info.value)


class GNoneDiffers(Sound):
    zoo_meta = _meta(streaming=False)

    def forward(self, x, g=None):  # deterministic, but an empty g is not the same as none
        return super().forward(x, g) + (0.0 if g is None else 1.0)


def test_a_deterministic_model_whose_g_none_differs_is_still_blamed_on_g() -> None:
    with pytest.raises(ContractError, match="breaks rule 'forward'.*g=None and an empty"):
        check_model(GNoneDiffers, tiny_spec("neutouch"), hparams={"hidden": 8})


def test_a_model_that_cannot_consume_a_spec_is_skipped_there_not_failed() -> None:
    class NeedsGlobals(Sound):
        def __init__(self, spec, hidden: int = 8) -> None:
            if not spec.num_globals:
                raise ModelCannotConsume("needs global features")
            super().__init__(spec, hidden)

    report = check_model(NeedsGlobals, [tiny_spec("neutouch"), SPEC])
    assert [(rule, where.split(" ")[0]) for rule, where, _ in report.skipped if rule == "*"] == \
        [("*", "synthetic_neutouch")]
    assert {where.split(" ")[0] for _, where in report.passed if where} == {"synthetic_uskin_allegro"}


def test_rules_can_be_chosen_and_an_unknown_rule_is_an_error() -> None:
    report = check_model(WrongShape, SPEC, rules=["metadata", "gradients"])  # the broken forward rule is not run
    assert report.rules == ["metadata", "gradients"]
    with pytest.raises(ConfigError, match="unknown model rule"):
        check_model(Sound, SPEC, rules=["shapes"])
