"""``tools.warm_kernels``: every built-in model (and ConvLSTM's compiled path) runs one forward and backward pass,
and a model that fails is named, not fatal. The models are stand-ins here: the real passes are what ``make test``
runs in the background."""

from __future__ import annotations

from typing import Any

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo import registry
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
    zoo = [n for n in tz.list_models() if registry.get_model_entry(n).dist is None
           and registry.get_model_entry(n).obj.__module__.startswith("tactile_zoo.models.")]
    assert len(zoo) >= 8
    assert warm_kernels.warm() == ["tacformer: RuntimeError: planted"]
    assert built == [*((n, {}) for n in zoo), ("convlstm", {"backend": "compiled"})]
    assert backward == [n for n, _ in built if n != "tacformer"]
