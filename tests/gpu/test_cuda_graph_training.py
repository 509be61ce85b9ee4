"""Training from CUDA graphs (``tactile_zoo.engine.cuda_graph``) computes what eager training computes.

For every registered model on ``sim_evtouch``: the same weights, the same batch, dropout off, in training mode; the
scores and every gradient of one graph replay against the model's own forward and backward on the same device. A
model whose forward cannot be recorded must say so with :class:`CaptureError` (then the test skips, naming it).
Without a CUDA device the module skips; ``python -m benchmarks.gpu_check`` runs it on a lent GPU machine.
"""

from __future__ import annotations

import pytest
import torch
from parity import FIRST_DATASET, _dropout_off, max_abs, sim_split, tf32_off

from tactile_zoo.engine.cuda_graph import CaptureError, GraphedForward
from tactile_zoo.engine.runtime import flush_denormals
from tactile_zoo.errors import ModelCannotConsume
from tactile_zoo.registry import model_names

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(),
                                reason="no CUDA device: CUDA graphs are recorded on a GPU (python -m "
                                       "benchmarks.gpu_check runs these on a GPU machine)")

#: relative to the largest value compared: one graph replays the kernels eager mode launches, in the same order
TOL = 1e-5


def _step(fn, model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None
          ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    model.zero_grad(set_to_none=True)
    scores = fn(x, g)
    scores.square().sum().backward()  # a loss that weighs every score differently
    grads = {n: p.grad.detach().clone() for n, p in model.named_parameters() if p.grad is not None}
    return scores.detach().clone(), grads


@pytest.mark.parametrize("name", model_names())
def test_a_graph_replay_matches_the_eager_step(name: str) -> None:
    from tactile_zoo.engine.build import build_model

    split = sim_split(FIRST_DATASET, 8)
    dev = torch.device("cuda")
    x, g = split.x.to(dev), (split.g.to(dev) if split.g.shape[-1] > 0 else None)
    first, second = x[:4], x[4:]  # (4, T, N, C) each: the recorded batch and the compared one
    g1, g2 = (None, None) if g is None else (g[:4], g[4:])
    with flush_denormals(), tf32_off():
        try:
            model = build_model(name, split.spec, {}, 0).to(dev)
        except ModelCannotConsume as exc:
            pytest.skip(str(exc).splitlines()[0])
        _dropout_off(model)
        try:
            graphed = GraphedForward(model, first, g1)
        except CaptureError as exc:
            pytest.skip(f"{name} is not recorded: {exc}")
        eager_scores, eager_grads = _step(model, model, second, g2)
        graph_scores, graph_grads = _step(graphed, model, second, g2)
    assert graphed.replays == 1
    scale = float(eager_scores.abs().max()) or 1.0
    assert max_abs(graph_scores, eager_scores) <= TOL * scale
    assert graph_grads.keys() == eager_grads.keys()
    for key, grad in eager_grads.items():
        assert max_abs(graph_grads[key], grad) <= TOL * (float(grad.abs().max()) or 1.0), key
