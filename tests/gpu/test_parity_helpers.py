"""The CPU/CUDA comparison of ``parity.py``, checked on the CPU alone: two CPU runs agree exactly, a planted
difference in logits, spikes or gradients fails, and the spike recorder counts what a LIF layer fires."""

from __future__ import annotations

import copy
import types

import pytest
import torch
from parity import LOGIT_TOL, Run, SpikeRecorder, compare_model, compare_runs, sim_split, simulated_datasets

from tactile_zoo.nn.lif import MultiStepLIF

CPU = torch.device("cpu")


# ------------------------------------------------------------------------------------------------ whole models
def test_two_cpu_runs_agree_exactly_and_every_check_runs() -> None:
    """CPU against CPU on short sequences: every check passes with no difference at all, spikes were counted, and
    the ``1/T`` limit is the layer's own sequence length (SGnet: T = 10 steps; Tacformer: 2 frame bins)."""
    split = sim_split("sim_biotac_slip", batch=2, steps=10)
    rows = {(r["model"], r["check"]): r for m in ("sgnet", "tacformer", "dcnn") for r in compare_model(m, split, CPU)}
    spiking = {(m, c) for m in ("sgnet", "tacformer") for c in ("forward", "stream", "backward")}
    assert set(rows) == spiking | {("dcnn", "forward"), ("dcnn", "backward")}  # D-CNN does not stream
    for row in rows.values():
        assert row["status"] == "pass" and row["note"] == "" and row["max_abs_diff"] == 0.0
        assert (row["batch"], row["steps"], row["dataset"]) == (2, 10, "sim_biotac_slip")
    for check in ("forward", "backward", "stream"):
        sg = rows["sgnet", check]
        assert sg["spike_total"] > 0 and sg["spikes_equal"] is True  # there were spikes to compare
        assert sg["spike_rate_diff"] == 0.0 and sg["spike_rate_limit"] == pytest.approx(1 / 10)
    assert rows["tacformer", "forward"]["spike_rate_limit"] == pytest.approx(1 / 2)
    assert rows["dcnn", "forward"]["spike_total"] is None  # not spiking
    assert rows["dcnn", "backward"]["grad_rel_diff"] == 0.0 and rows["sgnet", "backward"]["grad_rel_diff"] == 0.0
    assert rows["sgnet", "stream"]["stream_vs_forward_diff"] == 0.0


def test_a_planted_difference_in_the_device_copy_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    """The 'device' copy of the model gets one weight moved by 1e-2: its logits and gradients no longer match."""
    import parity

    def perturbed(model: torch.nn.Module) -> torch.nn.Module:
        twin = copy.deepcopy(model)
        with torch.no_grad():
            next(twin.parameters()).add_(1e-2)
        return twin

    monkeypatch.setattr(parity, "copy", types.SimpleNamespace(deepcopy=perturbed))
    rows = compare_model("dcnn", sim_split("sim_biotac_slip", batch=2, steps=10), CPU)
    assert [(r["check"], r["status"]) for r in rows] == [("forward", "FAIL"), ("backward", "FAIL")]
    assert all("scores differ" in r["note"] and r["max_abs_diff"] > LOGIT_TOL for r in rows)
    assert "gradients differ" in rows[1]["note"]


def test_the_simulated_datasets_start_with_sim_evtouch() -> None:
    names = simulated_datasets()
    assert names[0] == "sim_evtouch" and {"sim_biotac_slip", "sim_uskin_textures"} <= set(names)
    assert "ev_objects" not in names  # real data is never part of the parity tests


# ------------------------------------------------------------------------------------------------ the recorder
def test_the_spike_recorder_counts_forward_and_step_calls_and_unwraps() -> None:
    net = torch.nn.Sequential(torch.nn.Identity(), MultiStepLIF(beta=0.5, threshold=0.5))
    x = torch.rand(6, 3, 4, generator=torch.Generator().manual_seed(0)) * 2  # (T, B, N), strong enough to fire
    with SpikeRecorder(net) as rec:
        spikes = net(x)
        lif = net[1]
        mem = None
        stepped = []
        for x_t in x.unbind(0):
            s, mem = lif.step(x_t, mem)
            stepped.append(s)
    assert list(rec.counts) == ["1"] and rec.calls == {"1": 7} and rec.steps == {"1": 12}
    expected = spikes.sum(0, dtype=torch.float64) + torch.stack(stepped).sum(0, dtype=torch.float64)
    assert float(spikes.sum()) > 0 and torch.equal(rec.counts["1"], expected)
    assert "forward" not in vars(lif)  # the class's forward again after the block


# ------------------------------------------------------------------------------------------------ the judgement
def _run(scores: torch.Tensor, counts: torch.Tensor | None = None, steps: int = 10, horizon: int | None = None,
         grads: dict | None = None) -> Run:
    """A run whose one LIF layer ``lif`` fired ``counts`` over ``steps`` steps of sequences of ``horizon`` steps."""
    if counts is None:
        return Run(scores, grads=grads)
    return Run(scores, {"lif": counts}, {"lif": steps}, {"lif": horizon or steps}, grads)


def test_logits_beyond_the_tolerance_fail() -> None:
    scores = torch.randn(2, 5, generator=torch.Generator().manual_seed(0))
    assert compare_runs(_run(scores), _run(scores + 5e-5))["passed"]
    bad = scores.clone()
    bad[1, 3] += 3e-4
    verdict = compare_runs(_run(scores), _run(bad))
    assert not verdict["passed"] and "scores differ" in verdict["why"]
    assert verdict["max_abs_diff"] == pytest.approx(3e-4, rel=1e-3)
    nan = scores.clone()
    nan[0, 0] = float("nan")
    assert not compare_runs(_run(scores), _run(nan))["passed"]
    assert not compare_runs(_run(scores), _run(scores[:1]))["passed"]  # shapes differ


def test_spikes_differing_by_more_than_one_over_t_fail() -> None:
    """T = 10 steps: one spike more on one neuron (rate 1/10) is allowed, and then the logits are not judged; two
    spikes more (rate 2/10) fail."""
    counts = torch.tensor([[3.0, 0.0, 7.0], [1.0, 1.0, 0.0]], dtype=torch.float64)
    scores = torch.zeros(2, 3)
    same = compare_runs(_run(scores, counts), _run(scores, counts.clone()))
    assert same["passed"] and same["spikes_equal"] and same["spike_rate_diff"] == 0.0
    one = counts.clone()
    one[0, 1] += 1
    verdict = compare_runs(_run(scores, counts), _run(scores + 0.5, one))
    assert verdict["passed"] and verdict["spikes_equal"] is False and "not judged" in verdict["why"]
    assert verdict["spike_rate_diff"] == pytest.approx(0.1) and verdict["spike_rate_limit"] == pytest.approx(0.1)
    two = counts.clone()
    two[1, 2] += 2
    verdict = compare_runs(_run(scores, counts), _run(scores, two))
    assert not verdict["passed"] and "spike-rate mismatch" in verdict["why"]
    assert verdict["spike_rate_diff"] == pytest.approx(0.2)
    # a stream of 20 calls over a 10-step sequence (re-reading an open bin): 2 spikes in 20 calls is the limit
    assert compare_runs(_run(scores, counts, 20, 10), _run(scores, two, 20, 10))["passed"]
    three = two.clone()
    three[1, 2] += 1
    assert not compare_runs(_run(scores, counts, 20, 10), _run(scores, three, 20, 10))["passed"]
    assert not compare_runs(_run(scores, counts), _run(scores))["passed"]  # spiking layers missing on one side


def test_gradients_beyond_the_tolerance_fail() -> None:
    gen = torch.Generator().manual_seed(1)
    grads = {"w": torch.randn(4, 3, generator=gen), "b": torch.randn(3, generator=gen)}
    scores = torch.zeros(1, 3)
    close = {k: v + 1e-5 for k, v in grads.items()}
    assert compare_runs(_run(scores, grads=grads), _run(scores, grads=close))["passed"]
    far = {"w": grads["w"].clone(), "b": grads["b"] * 1.01}
    verdict = compare_runs(_run(scores, grads=grads), _run(scores, grads=far))
    assert not verdict["passed"] and "gradients differ" in verdict["why"] and verdict["grad_rel_diff"] > 1e-3
    assert not compare_runs(_run(scores, grads=grads), _run(scores, grads={"w": grads["w"], "b": None}))["passed"]


def test_a_model_that_draws_noise_in_training_is_skipped_not_passed_or_failed() -> None:
    """The multi-barrel SNN adds noise to its membranes in training mode, as released: two runs differ on one device,
    so its train-mode check says so (``skip``) instead of failing on the devices' different random draws; its
    eval-mode forward is deterministic and still compared."""
    rows = {r["check"]: r for r in compare_model("multibarrel", sim_split("sim_biotac_slip", batch=2, steps=10), CPU)}
    assert rows["forward"]["status"] == "pass"
    assert rows["backward"]["status"] == "skip" and "stochastic in training mode" in rows["backward"]["note"]
