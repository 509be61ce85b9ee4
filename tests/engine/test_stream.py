"""Streaming replay: per-step scores equal the full forward on every prefix, probabilities, the settled step."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine import scores_to_probabilities
from tactile_zoo.engine.metrics import tied_top
from tactile_zoo.engine.stream import StreamTrace, check_streaming, replay, settled_step
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import get_model_entry

#: (model, small hparams, dataset, small dataset kwargs): a spiking mse_rate model and a ce model with globals-free
#: image input, on two sensors; sim_biotac_slip declares a frame period, sim_evtouch does not
CASES = [
    ("sgnet", {"graph_channels": 8, "hidden": (16, 16)}, "sim_evtouch",
     {"n_train_per_class": 2, "n_test_per_class": 1, "num_steps": 20}),
    ("convlstm", {"hidden_channels": 4, "fc_units": 8}, "sim_biotac_slip",
     {"n_train_per_class": 2, "n_test_per_class": 1, "num_steps": 12}),
]


@pytest.mark.parametrize(("name", "hparams", "dataset", "kwargs"), CASES)
def test_replay_gives_the_forward_scores_of_every_prefix(name: str, hparams: dict, dataset: str, kwargs: dict
                                                         ) -> None:
    ds = tz.load_dataset(dataset, split="test", **kwargs)
    torch.manual_seed(0)
    model = tz.create_model(name, ds.spec, **hparams)
    model.train()  # replay must switch to eval itself, and restore the mode afterwards
    loss = get_model_entry(name).meta["recipe"]["loss"]
    sample = ds[3]
    trace = replay(model, sample.x, sample.g, sample.y, frame_period=ds.frame_period)
    assert model.training
    T = ds.spec.num_steps
    assert trace.scores.shape == trace.probabilities.shape == (T, ds.spec.num_classes)
    assert len(trace.step_seconds) == T and all(s >= 0 for s in trace.step_seconds)
    assert trace.loss == loss and trace.target == sample.y
    model.eval()
    with torch.no_grad():
        g = sample.g[None] if ds.spec.num_globals else None
        prefix = torch.cat([model(sample.x[None, :t], None if g is None else g[:, :t]) for t in range(1, T + 1)])
    torch.testing.assert_close(trace.scores, prefix, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(trace.probabilities, scores_to_probabilities(prefix, loss))
    assert ((trace.probabilities >= 0) & (trace.probabilities <= 1)).all()
    torch.testing.assert_close(trace.probabilities.sum(-1), torch.ones(T))
    decided = [None if tie else p for p, tie in zip(prefix.argmax(-1).tolist(), tied_top(prefix, loss).tolist())]
    assert trace.predictions == decided  # an untrained SNN is silent at first: a tie, undecided
    assert trace.settled == settled_step(decided, sample.y)
    latency = trace.latency_ms()
    assert latency["max"] >= latency["median"] > 0 and latency["max"] >= latency["mean"]


def test_frame_period_gives_the_time_of_each_step() -> None:
    assert tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=1).frame_period \
        == 0.01
    trace = StreamTrace(torch.zeros(4, 2), torch.full((4, 2), 0.5), [0.0] * 4, 0, frame_period=0.02)
    assert trace.time_of(3) == pytest.approx(0.06)
    assert StreamTrace(torch.zeros(4, 2), torch.full((4, 2), 0.5), [0.0] * 4, 0).time_of(3) is None


@pytest.mark.parametrize(("predictions", "target", "expected"), [
    ([2, 2, 2, 2], 2, 1),  # right from the first frame
    ([0, 1, 2, 2], 2, 3),
    ([2, 2, 0, 2, 2], 2, 4),  # right, revised to wrong, right again: settles at the last run
    ([2, 2, 2, 0], 2, None),  # the final answer is wrong
    ([0, 1, 0, 1], 2, None),  # never right
    ([], 0, None),
])
def test_settled_step_is_the_start_of_the_final_run_of_correct_predictions(predictions: list[int], target: int,
                                                                           expected: int | None) -> None:
    assert settled_step(predictions, target) == expected


def test_trace_settled_uses_the_argmax_of_the_scores() -> None:
    scores = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [0.2, 0.9], [0.1, 0.8]])  # argmax 0, 1, 0, 1, 1
    trace = StreamTrace(scores, scores_to_probabilities(scores), [0.0] * 5, target=1)
    assert trace.settled == 4
    assert StreamTrace(scores, scores, [0.0] * 5, target=0).settled is None
    assert StreamTrace(scores, scores, [0.0] * 5, target=None).settled is None


def test_a_model_that_cannot_stream_is_refused_by_name() -> None:
    with pytest.raises(ConfigError, match=r"model 'dcnn' does not stream: .*streaming=False.*not causal.*prefix"):
        check_streaming("dcnn", dict(get_model_entry("dcnn").meta))
    with pytest.raises(ConfigError, match=r"model 'plain' does not stream: Linear has no init_state/step.*prefix"):
        check_streaming("plain", {"streaming": True}, torch.nn.Linear(2, 2))
    with pytest.raises(ConfigError, match="Linear has no init_state/step"):
        replay(torch.nn.Linear(2, 2), torch.zeros(5, 1, 2))
    check_streaming("sgnet", dict(get_model_entry("sgnet").meta))  # a streaming model passes


class _Counter(torch.nn.Module):
    """Streams the running sum of its input's first channel as the score of class 1 (class 0 scores 0)."""

    def init_state(self, batch_size: int) -> torch.Tensor:
        return torch.zeros(batch_size)

    def step(self, x_t: torch.Tensor, g_t: torch.Tensor | None, state: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor]:
        state = state + x_t[:, :, 0].sum(-1)  # (B,)
        return torch.stack([torch.zeros_like(state), state], dim=-1), state


def test_replay_feeds_frames_in_order_and_rejects_a_batch_or_an_empty_sample() -> None:
    x = torch.tensor([-1.0, -1.0, 3.0, 1.0]).reshape(4, 1, 1)  # running sums -1, -2, 1, 2
    trace = replay(_Counter(), x, None, 1, loss="ce")
    assert trace.scores[:, 1].tolist() == [-1.0, -2.0, 1.0, 2.0] and trace.settled == 3
    with pytest.raises(ConfigError, match=r"shape \(T, N, C\) with T >= 1, got \(2, 4, 1, 1\)"):
        replay(_Counter(), x[None].expand(2, -1, -1, -1))
    with pytest.raises(ConfigError, match="T >= 1"):
        replay(_Counter(), x[:0])


def test_a_tie_is_undecided_never_correct() -> None:
    """Issue 49 item 6: all-zero output rates (an SNN that never fired, p = 1/K for every class) are not a
    prediction of class 0; a stream of them never settles on class 0, and a tie breaks a run of correct steps."""
    silent = torch.zeros(4, 10)
    trace = StreamTrace(silent, scores_to_probabilities(silent, "mse_rate"), [0.0] * 4, target=0, loss="mse_rate")
    assert trace.predictions == [None] * 4 and trace.ties == [True] * 4
    assert trace.settled is None and trace.tied_classes(1) == list(range(10))
    scores = torch.tensor([[0.0, 3.0, 3.0], [0.0, 3.0, 1.0], [2.0, 2.0, 2.0], [0.0, 3.0, 1.0]])
    trace = StreamTrace(scores, scores_to_probabilities(scores), [0.0] * 4, target=1)
    assert trace.predictions == [None, 1, None, 1] and trace.settled == 4
    assert settled_step([None, None], 0) is None
    negative = torch.tensor([[-1.0, -2.0]])  # spike rates clipped at 0: a tie, as the probabilities (0.5, 0.5) say
    assert StreamTrace(negative, scores_to_probabilities(negative, "mse_rate"), [0.0], loss="mse_rate"
                       ).predictions == [None]
