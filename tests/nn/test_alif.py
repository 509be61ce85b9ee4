"""Adaptive LIF neurons: one step against the update rule written out in float64, the Gaussian surrogate's
derivative, the gradient-free path (what export traces) giving the same spikes, and the compiled step (the
multi-barrel SNN's revision 2) giving the torch chain's state bit for bit and its gradients within 1e-5."""

from __future__ import annotations

import math
from typing import Any

import pytest
import torch

from tactile_zoo.errors import ConfigError
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


def _run(neuron: AdaptiveLIF, steps: int, noisy: bool, seed: int = 3) -> tuple[list[torch.Tensor], dict[str, Any]]:
    """``steps`` steps of a (4, 39, 32) population from the multi-barrel SNN's start (an (N, 1) trace), then the
    gradients of a weighted sum of every output."""
    gen = torch.Generator().manual_seed(seed)
    current = (torch.randn(steps, 4, 39, 32, generator=gen) * 0.6).requires_grad_()
    mem, spikes = torch.rand(4, 39, 32, generator=gen), torch.rand(4, 39, 32, generator=gen)
    trace = torch.full((39, 1), 0.46, requires_grad=True)
    start = (mem.requires_grad_(), spikes.requires_grad_(), trace)
    state, outs = start, []
    for t in range(steps):
        noise = torch.randn(4, 39, 32, generator=gen) if noisy else None
        state = neuron.step(current[t], *state, noise)
        outs += list(state)
    weights = [torch.randn(o.shape, generator=gen) for o in outs]
    sum((o * w).sum() for o, w in zip(outs, weights)).backward()
    grads = {"current": current.grad, "mem": mem.grad, "spikes": spikes.grad, "trace": trace.grad,
             "tau_m": neuron.tau_m.grad, "tau_adp": neuron.tau_adp.grad}
    return [o.detach() for o in outs], grads


@pytest.mark.parametrize("noisy", [True, False])
def test_the_compiled_step_gives_the_same_state_and_gradients_within_1e_5(noisy: bool) -> None:
    pytest.importorskip("numba")
    torch.manual_seed(0)
    ref = AdaptiveLIF(32, 4.34378016, 9.90546331)
    fast = AdaptiveLIF(32, 4.34378016, 9.90546331, backend="compiled")
    fast.load_state_dict(ref.state_dict())
    outs_ref, grads_ref = _run(ref, 6, noisy)
    outs_fast, grads_fast = _run(fast, 6, noisy)
    spikes = sum(float(o.sum()) for o in outs_ref[1::3])
    assert 0 < spikes < sum(o.numel() for o in outs_ref[1::3]), "the example should spike, and not everywhere"
    for i, (a, b) in enumerate(zip(outs_ref, outs_fast)):
        what = ("membrane", "spikes", "trace")[i % 3]
        assert torch.equal(a, b), f"step {i // 3}, {what}: {int((a != b).sum())} differ"
    for name, ref_grad in grads_ref.items():
        assert grads_fast[name].shape == ref_grad.shape, name  # the (N, 1) trace's gradient summed back
        assert float((grads_fast[name] - ref_grad).abs().max() / ref_grad.abs().max()) <= 1e-5, name


def test_the_compiled_backend_runs_the_torch_chain_where_the_kernel_does_not_apply(monkeypatch) -> None:
    pytest.importorskip("numba")
    from tactile_zoo.nn import alif

    calls = []
    monkeypatch.setattr(alif._CompiledStep, "apply", lambda *a: calls.append(a) or pytest.fail("kernel ran"))
    n = _neuron()  # float64: the torch chain, the same numbers as the torch backend
    n.backend = alif.ALIFBackend.COMPILED
    current, mem, spikes = torch.randn(3, 5).double(), torch.rand(3, 5).double(), torch.rand(3, 5).double()
    got = n.step(current, mem, spikes, torch.full((1, 1), 0.46).double())
    n.backend = alif.ALIFBackend.TORCH
    want = n.step(current, mem, spikes, torch.full((1, 1), 0.46).double())
    assert all(torch.equal(a, b) for a, b in zip(got, want)) and not calls


def test_an_unknown_backend_is_one_error_naming_it() -> None:
    with pytest.raises(ConfigError, match="AdaptiveLIF: backend must be one of 'torch', 'compiled', got 'numba'"):
        AdaptiveLIF(4, 4.0, 9.0, backend="numba")
