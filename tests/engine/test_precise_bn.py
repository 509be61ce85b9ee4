"""Precise batch norm (issue 53): a model with ``precise_bn = True`` leaves :func:`~tactile_zoo.engine.fit` with
every batch norm's running statistics recomputed over the training split with the final weights (a cumulative
average over the training batches, as ``torch.optim.swa_utils.update_bn`` computes it); a model without the flag
keeps its moving averages. D-CNN declares it at revision 2."""

from __future__ import annotations

from typing import Any

import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.engine import fit
from tactile_zoo.engine.tensors import as_split, concat
from tactile_zoo.errors import ConfigError


class _StaleBN(nn.Module):
    """Linear -> BatchNorm1d -> Linear whose running statistics barely move (momentum 1e-4): stale by design."""

    def __init__(self, spec: Any, precise_bn: bool) -> None:
        super().__init__()
        width = spec.num_steps * spec.num_nodes * spec.num_channels
        self.hidden, self.bn = nn.Linear(width, 8), nn.BatchNorm1d(8, momentum=1e-4)
        self.out = nn.Linear(8, spec.num_classes)
        self.precise_bn = precise_bn

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.out(torch.relu(self.bn(self.hidden(x.flatten(1)))))


class _Spy:
    """A split that logs when its tensors are read."""

    def __init__(self, inner: Any, log: list[str], name: str) -> None:
        self.inner, self.log, self.name, self.spec = inner, log, name, inner.spec

    def tensors(self) -> Any:
        self.log.append(f"read {self.name}")
        return self.inner.tensors()


def _splits() -> dict[str, Any]:
    return {s: tz.load_dataset("tiny_blobs", split=s) for s in ("train", "val", "test")}


def _cumulative(model: _StaleBN, split: Any, batch_size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The training split's batch statistics under the final weights, averaged with equal weight per batch (in
    split order; the engine's batching keeps a lone last sample with the batch before it)."""
    x = as_split(split).x.flatten(1)
    starts = list(range(0, len(x), batch_size))
    if len(starts) > 1 and len(x) - starts[-1] == 1:
        starts.pop()
    ends = [*starts[1:], len(x)]
    with torch.no_grad():
        h = [model.hidden(x[a:b]) for a, b in zip(starts, ends)]
    return torch.stack([b.mean(0) for b in h]).mean(0), torch.stack([b.var(0, unbiased=True) for b in h]).mean(0)


@pytest.mark.parametrize("val", [False, True], ids=["fixed-epochs", "selected-on-val"])
def test_precise_bn_recomputes_the_running_statistics_over_the_training_split(val: bool) -> None:
    s = _splits()
    torch.manual_seed(0)
    model = _StaleBN(s["train"].spec, precise_bn=True)
    log: list[str] = []
    recipe = {"max_epochs": 4, "patience": None, "batch_size": 7, "lr": 0.05}
    res = fit(model, s["train"], val_dataset=s["val"] if val else None, test_dataset=_Spy(s["test"], log, "test"),
              recipe=recipe, seed=0, device="cpu")
    mean, var = _cumulative(model, s["train"], 7)
    torch.testing.assert_close(model.bn.running_mean, mean, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(model.bn.running_var, var, rtol=1e-5, atol=1e-6)
    assert model.bn.momentum == 1e-4  # restored
    assert log == ["read test"]  # the test split is still read once
    assert res.test is not None and res.test.metrics["n"] == len(s["test"])


def test_after_a_refit_the_statistics_are_over_train_and_val() -> None:
    s = _splits()
    torch.manual_seed(0)
    model = _StaleBN(s["train"].spec, precise_bn=True)
    fit(model, s["train"], val_dataset=s["val"], recipe={"max_epochs": 3, "patience": None, "batch_size": 7},
        refit=True, seed=0, device="cpu")
    mean, var = _cumulative(model, concat(as_split(s["train"]), as_split(s["val"])), 7)
    torch.testing.assert_close(model.bn.running_mean, mean, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(model.bn.running_var, var, rtol=1e-5, atol=1e-6)


def test_without_the_flag_the_moving_averages_stay() -> None:
    s = _splits()
    torch.manual_seed(0)
    model = _StaleBN(s["train"].spec, precise_bn=False)
    fit(model, s["train"], recipe={"max_epochs": 4, "patience": None, "batch_size": 7, "lr": 0.05}, seed=0,
        device="cpu")
    mean, _ = _cumulative(model, s["train"], 7)
    assert not torch.allclose(model.bn.running_mean, mean, rtol=1e-3, atol=1e-3)  # stale, as built
    assert int(model.bn.num_batches_tracked) == 4 * -(-len(s["train"]) // 7)  # the training steps only


def test_dcnn_declares_precise_bn_at_revision_2_only() -> None:
    spec = _splits()["train"].spec
    assert tz.create_model("dcnn", spec).precise_bn is True  # revision 2, the default
    assert tz.create_model("dcnn", spec, revision=1).precise_bn is False
    assert tz.create_model("dcnn", spec, revision=2).precise_bn is True


@pytest.mark.parametrize("revision", [1, 2])
def test_dcnn_revision_2_leaves_fit_with_one_pass_of_statistics(revision: int) -> None:
    """Revision 2's batch norms hold one pass over the training split (reset, then one update per batch); revision 1's
    hold every training step's moving average, as before."""
    s = _splits()
    torch.manual_seed(0)
    model = tz.create_model("dcnn", s["train"].spec, revision=revision)
    recipe = {"max_epochs": 2, "patience": None, "batch_size": 16}
    fit(model, s["train"], recipe=recipe, seed=0, device="cpu")
    steps = -(-len(s["train"]) // 16)
    counts = {int(m.num_batches_tracked) for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)}
    assert counts == {steps if revision == 2 else 2 * steps}


def test_dcnn_refuses_a_precise_bn_that_is_not_a_boolean() -> None:
    with pytest.raises(ConfigError, match="dcnn: precise_bn must be true or false, got 'yes'"):
        tz.create_model("dcnn", _splits()["train"].spec, precise_bn="yes")
