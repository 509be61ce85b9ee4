"""Adaptive LIF neurons: one step against the update rule written out in float64, the Gaussian surrogate's
derivative, and the gradient-free path (what export traces) giving the same spikes."""

from __future__ import annotations

import math

import torch

from tactile_zoo.nn.alif import AdaptiveLIF, gaussian_spike


def _neuron() -> AdaptiveLIF:
    torch.manual_seed(0)
    return AdaptiveLIF(5, tau_m_init=4.0, tau_adp_init=9.0, threshold=0.1, beta=1.8).double()


def test_one_step_is_the_update_rule() -> None:
    n = _neuron()
    f64 = torch.float64
    current = torch.tensor([[0.5, -1.0, 2.0, 0.05, 3.0]], dtype=f64)
    mem = torch.tensor([[0.2, 0.9, 0.0, 0.1, 0.7]], dtype=f64)
    spikes, trace = torch.tensor([[1.0, 0.0, 1.0, 0.0, 0.3]], dtype=f64), torch.full((1, 1), 0.4, dtype=f64)
    noise = torch.tensor([[0.1, 0.0, -0.2, 0.0, 0.0]], dtype=f64)
    new_mem, new_spikes, new_trace = n.step(current, mem, spikes, trace, noise)
    for k in range(5):
        alpha, rho = math.exp(-1 / n.tau_m[k].item()), math.exp(-1 / n.tau_adp[k].item())
        b = rho * 0.4 + (1 - rho) * float(spikes[0, k])
        theta = 0.1 + 1.8 * b
        u = alpha * float(mem[0, k]) + (1 - alpha) * (float(current[0, k]) + float(noise[0, k]))
        s = float(u - theta > 0)
        assert abs(float(new_trace[0, k]) - b) < 1e-12
        assert float(new_spikes[0, k]) == s
        assert abs(float(new_mem[0, k]) - (u - theta * s)) < 1e-12
    assert 0 < float(new_spikes.sum()) < 5, "the example should have both spiking and silent neurons"


def test_the_surrogate_is_a_scaled_gaussian() -> None:
    u = torch.linspace(-2, 2, 41, dtype=torch.float64, requires_grad=True)
    spikes = gaussian_spike(u, width=0.5, scale=0.5)
    assert torch.equal(spikes.detach(), (u > 0).double())
    (grad,) = torch.autograd.grad(spikes.sum(), u)
    want = 0.5 * torch.exp(-u.detach() ** 2 / (2 * 0.25)) / math.sqrt(2 * math.pi) / 0.5
    torch.testing.assert_close(grad, want)


def test_the_time_constants_learn_and_no_grad_gives_the_same_spikes() -> None:
    n = _neuron()
    torch.manual_seed(1)
    current, mem, spikes = torch.randn(3, 5).double(), torch.rand(3, 5).double(), torch.rand(3, 5).double()
    trace = torch.full((1, 1), 0.46).double()
    mem1, s1, _ = n.step(current, mem, spikes, trace)
    (mem1.sum() + s1.sum()).backward()
    assert n.tau_m.grad.abs().sum() > 0 and n.tau_adp.grad.abs().sum() > 0
    with torch.no_grad():
        mem2, s2, _ = n.step(current, mem, spikes, trace)
    assert torch.equal(s1.detach(), s2) and torch.equal(mem1.detach(), mem2)
