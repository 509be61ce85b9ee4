"""D-CNN's training step against a float64 copy on the CPU: ``bn_stats`` chooses batch norm's training statistics.

torch's CPU batch norm sums a channels-last map's rows one after another in float32, which put the old path's scores
3e-2 and its gradients 9 % (relative to the largest) from float64 on D-CNN's maps (``python -m tools.dcnn_precision``).
The accurate choices must be within 1e-4 (scores) and 1e-3 (gradients) of a float64 copy in training mode; the shape
here is small (32 x 78 images, batch 4) but has inputs with a mean large against their spread, which the old
path gets wrong even there.
"""

from __future__ import annotations

import copy

import pytest
import torch
import torch.nn.functional as F

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError

SENSOR = tz.get_sensor("neutouch")
SPEC = DatasetSpec("t", 5, tuple("abcde"), 32, SENSOR.num_nodes, 2, 0, SENSOR)


def _step(model: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    scores = model(x)
    F.cross_entropy(scores, y).backward()
    return scores.detach().double(), {n: p.grad.double() for n, p in model.named_parameters()}


def _errors(**hparams: object) -> tuple[float, float, torch.nn.Module, torch.nn.Module]:
    """Largest score and gradient differences of one training step from a float64 NCHW copy, each relative to the
    copy's largest; and the two models after the step."""
    torch.manual_seed(0)
    model = tz.create_model("dcnn", SPEC, **hparams).train()
    ref = copy.deepcopy(model).double()
    ref.features.to(memory_format=torch.contiguous_format)
    x, y = torch.rand(4, 32, SENSOR.num_nodes, 2) * 0.1 + 1.0, torch.arange(4) % 5
    (s, g), (rs, rg) = _step(model, x, y), _step(ref, x.double(), y)
    largest = max(v.abs().max() for v in rg.values())
    return ((s - rs).abs().max() / rs.abs().max()).item(), max(((g[n] - rg[n]).abs().max() / largest).item()
                                                               for n in g), model, ref


@pytest.mark.parametrize("hparams", [{"bn_stats": "two_pass", "fused_blocks": False},
                                     {"bn_stats": "float64", "fused_blocks": False},
                                     {"fused_blocks": True}])  # revision 3: the blocks' ReLU -> BN -> pool fused
def test_training_step_is_float64_accurate(hparams: dict) -> None:
    score_err, grad_err, model, ref = _errors(**hparams)
    assert score_err < 1e-4 and grad_err < 1e-3, (score_err, grad_err)
    # the running statistics follow the batch's as nn.BatchNorm's do (the first batch taken whole, variance unbiased)
    for (name, ours), theirs in zip(model.named_buffers(), ref.buffers()):
        assert torch.allclose(ours.to(theirs.dtype), theirs, rtol=1e-4, atol=1e-6), name
    # evaluation mode is torch's own path, whatever bn_stats says
    x = torch.rand(3, 32, SENSOR.num_nodes, 2)
    native = tz.create_model("dcnn", SPEC, revision=1)
    native.load_state_dict(model.state_dict())
    with torch.no_grad():
        assert torch.equal(model.eval()(x), native.eval()(x))


def test_the_old_path_is_revision_1_and_misses() -> None:
    """``native`` is revision 1 (committed cells rebuild bit for bit) and is what revisions 2 and 3 fix."""
    model = tz.create_model("dcnn", SPEC, revision=1)
    assert all(bn.stats == "native" for bn in model.modules() if hasattr(bn, "stats"))
    assert not any(block.fused for block in model.features)
    assert all(bn.stats == "two_pass" for bn in tz.create_model("dcnn", SPEC).modules() if hasattr(bn, "stats"))
    score_err, grad_err, _, _ = _errors(bn_stats="native", fused_blocks=False)
    assert score_err > 1e-4 or grad_err > 1e-3, (score_err, grad_err)


def test_an_unknown_choice_is_refused_with_the_keyword() -> None:
    with pytest.raises(ConfigError, match=r"dcnn: bn_stats must be one of 'native', 'two_pass', 'float64', got 'f64'"):
        tz.create_model("dcnn", SPEC, bn_stats="f64")
