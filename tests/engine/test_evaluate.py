from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine import fit
from tactile_zoo.engine.evaluate import earliness, prefix_evaluation, prefix_steps, time_inference


@pytest.fixture()
def trained() -> tuple:
    s = {k: tz.load_dataset("tiny_blobs", split=k) for k in ("train", "val", "test")}
    res = fit("tiny_rate", s["train"], seed=0, val_dataset=s["val"], device="cpu")
    return res, s["test"]


def test_prefix_steps_round_and_keep_at_least_one_step() -> None:
    assert prefix_steps(12, [0.01, 0.1, 0.25, 0.5, 1.0]) == [1, 1, 3, 6, 12]
    assert prefix_steps(100, [0.1, 0.25]) == [10, 25]


def test_earliness_is_the_first_prefix_reaching_90_percent_of_full_accuracy() -> None:
    assert earliness([0.1, 0.5, 1.0], [0.2, 0.85, 0.9], 0.9) == 0.5  # 0.85 >= 0.81
    assert earliness([0.1, 0.5, 1.0], [0.2, 0.5, 0.9], 0.9) == 1.0
    assert earliness([0.1, 1.0], [0.3, 0.3], 0.3) == 0.1


def test_causal_prefix_evaluation_reads_prefixes(trained: tuple) -> None:
    res, test = trained
    out = prefix_evaluation(res.model, test, [0.5, 0.1], causal=True)
    assert out["fractions"] == [0.1, 0.5, 1.0] and out["steps"] == [1, 6, 12]  # 1.0 always added, sorted
    assert out["causal"] and out["input"] == "causal"
    assert out["accuracy"][-1] == tz.evaluate(res.model, test).metrics["accuracy"]
    # the class evidence fades in over time in tiny_blobs: one step says less than the whole sequence
    assert out["accuracy"][0] < out["accuracy"][-1]
    x, g, _ = test.tensors()
    manual = res.model(x[:, :6], g[:, :6]).argmax(-1)
    assert out["accuracy"][1] == pytest.approx((manual == test.y).float().mean().item())


def test_a_model_that_needs_the_full_length_gets_zero_padded_prefixes(trained: tuple) -> None:
    res, test = trained

    class FixedLength(torch.nn.Module):
        def __init__(self, inner: torch.nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
            if x.shape[1] != 12:
                raise RuntimeError("positional table has 12 entries")
            return self.inner(x, g)

    out = prefix_evaluation(FixedLength(res.model), test, [0.25, 1.0], causal=False, loss="mse_rate")
    assert out["input"] == "zero_padded" and not out["causal"] and len(out["accuracy"]) == 2


def test_inference_timing_is_positive(trained: tuple) -> None:
    res, test = trained
    ms = time_inference(res.model, test, samples=3)
    assert ms is not None and ms > 0


class _Silent(torch.nn.Module):
    """Spike rates that are all zero until ``fires`` steps were read, then the true class of every sample: an SNN
    whose output neurons have not fired yet ties every class (p = 1/K)."""

    def __init__(self, y: torch.Tensor, num_classes: int, fires: int) -> None:
        super().__init__()
        self.y, self.k, self.fires = y, num_classes, fires
        self.anchor = torch.nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        out = torch.zeros(x.shape[0], self.k)
        if x.shape[1] >= self.fires:
            out[torch.arange(x.shape[0]), self.y[: x.shape[0]]] = 1.0
        return out


def test_a_tie_at_a_prefix_is_undecided_not_class_0() -> None:
    """Issue 49 item 6: before the model fires, argmax of the tie would pick class 0 and score every class-0 sample
    as correct; early classification counts them undecided."""
    test = tz.load_dataset("tiny_blobs", split="test")
    _, _, y = test.tensors()
    assert (y == 0).any() and (y != 0).any()
    out = prefix_evaluation(_Silent(y, test.spec.num_classes, fires=6), test, [0.25, 0.5], causal=True,
                            loss="mse_rate")
    assert out["steps"] == [3, 6, 12]
    assert out["accuracy"] == [0.0, 1.0, 1.0] and out["balanced_accuracy"] == [0.0, 1.0, 1.0]
    assert out["undecided"] == [1.0, 0.0, 0.0] and out["earliness"] == 0.5
