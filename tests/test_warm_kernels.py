"""``tools.warm_kernels``: every built-in model (and ConvLSTM's compiled path) runs one forward and backward pass,
the LIF kernel's parallel builds run once, and a model that fails is named, not fatal. The models and kernels are
stand-ins here: the real passes are what ``make test`` runs in the background."""

from __future__ import annotations

from typing import Any

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.nn import backend
from tools import warm_kernels


def test_every_model_and_the_compiled_convlstm_run_forward_and_backward(monkeypatch: pytest.MonkeyPatch) -> None:
    built: list[tuple[str, dict[str, Any]]] = []
    backward: list[str] = []

    class Stand(torch.nn.Module):
        def __init__(self, name: str) -> None:
            super().__init__()
            self.name, self.w = name, torch.nn.Parameter(torch.ones(1))

        def forward(self, x: torch.Tensor, g: torch.Tensor | None) -> torch.Tensor:
            assert g is None and x.shape[0] == 2 and self.training
            out = x.flatten(1).sum(1, keepdim=True) * self.w
            out.register_hook(lambda grad: backward.append(self.name))
            return out

    def create(name: str, spec: Any, **kwargs: Any) -> torch.nn.Module:
        built.append((name, kwargs))
        if name == "tacformer":
            raise RuntimeError("planted")
        return Stand(name)

    monkeypatch.setattr(tz, "create_model", create)
    monkeypatch.setattr(warm_kernels, "warm_parallel_lif", lambda: [])
    zoo = [n for n in tz.list_models() if registry.get_model_entry(n).dist is None
           and registry.get_model_entry(n).obj.__module__.startswith("tactile_zoo.models.")]
    assert len(zoo) >= 8
    assert warm_kernels.warm() == ["tacformer: RuntimeError: planted"]
    assert built == [*((n, {}) for n in zoo), ("convlstm", {"backend": "compiled"})]
    assert backward == [n for n, _ in built if n != "tacformer"]


@pytest.mark.skipif(backend.lif_kernels() is None, reason="no compiled LIF kernel on this machine")
def test_the_lif_kernels_parallel_builds_run_once_on_two_threads(monkeypatch: pytest.MonkeyPatch) -> None:
    kernels, launched = backend.lif_kernels(), []
    for name in ("lif_forward", "lif_backward", "lif_forward_serial", "lif_backward_serial"):
        # stand-ins that record the build and its thread count (their outputs stay as allocated)
        monkeypatch.setattr(kernels, name, lambda *_a, _n=name: launched.append((_n, torch.get_num_threads())))
    torch.set_num_threads(1)
    assert warm_kernels.warm_parallel_lif() == []
    assert launched == [("lif_forward", 2), ("lif_backward", 2)]  # the parallel builds, not the serial ones
    assert torch.get_num_threads() == 1  # restored

    def broken(*_args: Any) -> None:
        raise RuntimeError("planted")

    monkeypatch.setattr(kernels, "lif_forward", broken)
    assert warm_kernels.warm_parallel_lif() == ["parallel LIF: RuntimeError: planted"]
    assert torch.get_num_threads() == 1
