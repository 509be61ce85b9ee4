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
from tactile_zoo.testing import MODEL_RULES, ContractError, check_model, tiny_spec

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
    report = check_model(Sound)
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
    (NoisyEval, "determinism", "a second forward in eval mode differs"),
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
    if model not in (WrongShape, NaNScores, NoisyEval):  # their scores break the rules after theirs too
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
        check_model(Bare, SPEC, rules=["metadata"])
    assert check_model(Bare, SPEC, meta=META, rules=["metadata"]).rules == ["metadata"]


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
