"""MultiStepLIF: the fused backend against stepping snntorch.Leaky, the paper's eqs. 2-4 and TactileSGNet's rule."""

from __future__ import annotations

import itertools

import pytest
import torch
from snntorch import surrogate as snn_surrogate

import tactile_zoo.nn.lif_fused as fused
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn.lif import MultiStepLIF

SURROGATES = {"rect": "rect", "atan": "atan", "fast_sigmoid": snn_surrogate.fast_sigmoid(slope=5)}


def _run(lif: MultiStepLIF, x: torch.Tensor, mem0: torch.Tensor, w_s: torch.Tensor, w_m: torch.Tensor):
    """Spikes, final membrane and the gradients of a loss on both w.r.t. the input and the initial membrane."""
    x = x.detach().clone().requires_grad_(True)
    mem0 = mem0.detach().clone().requires_grad_(True)
    spikes, mem = lif(x, mem0, return_mem=True)
    gx, gm = torch.autograd.grad((spikes * w_s).sum() + (mem * w_m).sum(), [x, mem0])
    return spikes, mem, gx, gm


def _compare(kw: dict, shape: tuple[int, ...], seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(shape, generator=gen) * 0.6 + 0.3  # around the threshold: spikes, resets and surrogate activity
    mem0 = torch.randn(shape[1:], generator=gen) * 0.5
    w_s, w_m = torch.randn(shape, generator=gen), torch.randn(shape[1:], generator=gen)
    fused = _run(MultiStepLIF(backend="fused", **kw), x, mem0, w_s, w_m)
    ref = _run(MultiStepLIF(backend="snntorch", **kw), x, mem0, w_s, w_m)
    assert torch.equal(fused[0], ref[0]), "spikes differ"
    assert torch.equal(fused[1], ref[1]), "final membrane differs"
    torch.testing.assert_close(fused[2], ref[2], rtol=1e-5, atol=1e-6, msg="input gradients differ")
    torch.testing.assert_close(fused[3], ref[3], rtol=1e-5, atol=1e-6, msg="initial-membrane gradients differ")
    return ref[0]


@pytest.mark.parametrize("surrogate,detach_reset,reset", list(itertools.product(
    SURROGATES, [False, True], ["zero", "subtract"])))
@pytest.mark.parametrize("shape", [(40, 3, 5), (1, 4), (9, 2, 3, 4)])
def test_fused_equals_stepping_snntorch_leaky(surrogate: str, detach_reset: bool, reset: str,
                                              shape: tuple[int, ...]) -> None:
    spikes = _compare(dict(surrogate=SURROGATES[surrogate], detach_reset=detach_reset, reset=reset), shape)
    if shape[0] > 1:
        assert 0.05 < spikes.mean() < 0.95  # the comparison saw both spikes and silence


@pytest.mark.parametrize("save_limit,block_bytes", [(0, 3 * 15 * 4), (1 << 30, 4 * 15 * 4), (0, 1)])
@pytest.mark.parametrize("detach_reset", [False, True])
def test_blocked_and_recomputed_backward(monkeypatch: pytest.MonkeyPatch, save_limit: int, block_bytes: int,
                                         detach_reset: bool) -> None:
    """Long sequences keep per-block checkpoints and recompute; blocks that do not divide T; blocks of one step."""
    monkeypatch.setattr(fused, "SAVE_LIMIT_BYTES", save_limit)
    monkeypatch.setattr(fused, "BLOCK_BYTES", block_bytes)
    for reset in ("zero", "subtract"):
        _compare(dict(surrogate="atan", detach_reset=detach_reset, reset=reset), (23, 3, 5), seed=1)


def test_sigmoid_surrogate_through_the_layer() -> None:
    _compare(dict(surrogate="sigmoid", surrogate_slope=5, detach_reset=False), (30, 4, 3))


def test_paper_equations_hand_computed() -> None:
    """X-Tacformer eqs. 2-4: H = V + (X - (V - V_reset)) / tau, S = H > V_th, V = H (1 - S) + V_reset S."""
    # tau 2, V_th 1, V_reset 0, V(0) = 0:
    # H1 = 0.75; H2 = 0.75 + (0.5 - 0.75)/2 = 0.625; H3 = 0.625 + (2.5 - 0.625)/2 = 1.5625 -> spike, V = 0;
    # H4 = 0; H5 = 1.5 -> spike
    x = torch.tensor([1.5, 0.5, 2.5, 0.0, 3.0]).view(5, 1)
    # tau 2, V_th 1, V_reset -0.5, V(0) = V_reset:
    # H1 = -0.5 + (2 - 0)/2 = 0.5; H2 = 0.5 + (1 - 1)/2 = 0.5; H3 = 0.5 + (3 - 1)/2 = 1.5 -> spike
    x2 = torch.tensor([2.0, 1.0, 3.0]).view(3, 1)
    for backend in ("fused", "snntorch"):
        lif = MultiStepLIF.from_tau(tau=2.0, v_th=1.0, backend=backend)
        spikes, mem = lif(x, return_mem=True)
        assert spikes.flatten().tolist() == [0.0, 0.0, 1.0, 0.0, 1.0]
        assert mem.item() == pytest.approx(1.5)  # H(5), before the reset that the next step applies
        spikes, mem = MultiStepLIF.from_tau(tau=2.0, v_th=1.0, v_reset=-0.5, backend=backend)(x2, return_mem=True)
        assert spikes.flatten().tolist() == [0.0, 0.0, 1.0]
        assert mem.item() == pytest.approx(1.5 - (-0.5))  # the membrane is V - V_reset
    explicit = MultiStepLIF(beta=0.75, threshold=1.5, input_scale=0.25)
    torch.testing.assert_close(MultiStepLIF.from_tau(4.0, 1.0, -0.5)(x * 2), explicit(x * 2))


class _ReferenceSpike(torch.autograd.Function):
    """TactileSGNet's spike function as the rule states it: mem > 0.5, gradient 1 where |mem - 0.5| < 0.5."""

    @staticmethod
    def forward(ctx, mem: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(mem)
        return (mem > 0.5).float()

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (mem,) = ctx.saved_tensors
        return grad * ((mem - 0.5).abs() < 0.5).float()


def _reference_sgnet_neuron(x: torch.Tensor) -> torch.Tensor:
    mem = spike = torch.zeros_like(x[0])
    out = []
    for x_t in x.unbind(0):
        mem = mem * 0.2 * (1.0 - spike) + x_t  # the reset keeps its gradient
        spike = _ReferenceSpike.apply(mem)
        out.append(spike)
    return torch.stack(out)


def test_sgnet_neuron_rule() -> None:
    # mem: 0.3; 0.06 + 0.3 = 0.36; 0.072 + 0.5 = 0.572 -> spike; 0 + 0.1; 0.02 + 0.6 = 0.62 -> spike;
    # 0 + 0.5 = 0.5 (equal to the threshold) -> no spike
    x = torch.tensor([0.3, 0.3, 0.5, 0.1, 0.6, 0.5]).view(6, 1)
    for backend in ("fused", "snntorch"):
        assert MultiStepLIF(backend=backend)(x).flatten().tolist() == [0, 0, 1, 0, 1, 0]
    gen = torch.Generator().manual_seed(3)
    x = (torch.rand(30, 4, 6, generator=gen) * 0.8).requires_grad_(True)
    w = torch.randn(30, 4, 6, generator=gen)
    ref = _reference_sgnet_neuron(x)
    (g_ref,) = torch.autograd.grad((ref * w).sum(), x)
    for backend in ("fused", "snntorch"):
        lif = MultiStepLIF(beta=0.2, threshold=0.5, surrogate="rect", detach_reset=False, backend=backend)
        out = lif(x)
        (g,) = torch.autograd.grad((out * w).sum(), x)
        assert torch.equal(out, ref)
        torch.testing.assert_close(g, g_ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("backend", ["fused", "snntorch"])
def test_step_and_continuation_equal_forward(backend: str) -> None:
    lif = MultiStepLIF(surrogate="atan", backend=backend)
    x = torch.randn(12, 2, 7) + 0.4
    full, last = lif(x, return_mem=True)
    mem, steps = None, []
    for x_t in x.unbind(0):
        s, mem = lif.step(x_t, mem)
        steps.append(s)
    assert torch.equal(torch.stack(steps), full) and torch.equal(mem, last)
    head, mem = lif(x[:5], return_mem=True)
    tail = lif(x[5:], mem)
    assert torch.equal(torch.cat([head, tail]), full)
    assert torch.equal(lif(x), full)  # no state survives a call


def test_float64_and_no_grad() -> None:
    x = torch.randn(20, 3, dtype=torch.float64) + 0.4
    with torch.no_grad():
        fused = MultiStepLIF(surrogate="atan")(x)
    assert fused.dtype == torch.float64
    assert torch.equal(fused, MultiStepLIF(surrogate="atan", backend="snntorch")(x).detach())


def test_backends_share_an_empty_state_dict() -> None:
    fused, ref = MultiStepLIF(), MultiStepLIF(backend="snntorch")
    ref(torch.randn(3, 2))  # builds the snnTorch neuron, which must not leak into the state_dict
    assert fused.state_dict().keys() == ref.state_dict().keys() == set()


@pytest.mark.parametrize("kwargs", [dict(reset="none"), dict(backend="cuda"), dict(surrogate="tanh"),
                                    dict(beta=1.5), dict(surrogate="rect", surrogate_width=0.0)])
def test_bad_configuration(kwargs: dict) -> None:
    with pytest.raises(ConfigError):
        MultiStepLIF(**kwargs)


def test_bad_inputs() -> None:
    lif = MultiStepLIF()
    with pytest.raises(ConfigError, match="mem has shape"):
        lif(torch.randn(4, 3), torch.zeros(2))
    with pytest.raises(ConfigError, match="T >= 1"):
        lif(torch.randn(0, 3))
    with pytest.raises(ConfigError):
        MultiStepLIF.from_tau(tau=0.5, v_th=1.0)
