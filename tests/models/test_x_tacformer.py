"""X-Tacformer: shapes, gradients through both branches, streaming equals the forward on every prefix, metadata."""

from __future__ import annotations

import pytest
import torch

from tactile_zoo.data.sensors import BIOTAC_SP, NEUTOUCH
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.x_tacformer import XTacformer
from tactile_zoo.registry import get_model_entry, instantiate_model

SMALL = dict(dim=16, heads=2, hidden=8, attn_dim=8, v_th=0.5)


def spec(num_globals: int = 0, sensor=NEUTOUCH, channels: int = 2) -> DatasetSpec:
    return DatasetSpec("toy", 3, ("a", "b", "c"), 9, sensor.num_nodes, channels, num_globals, sensor)


def events(b: int, t: int, n: int, c: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(b, t, n, c, generator=g) < 0.3).float()


@pytest.mark.parametrize("temporal_pool", ["mean", "flatten"])
def test_forward_shapes_and_gradients_reach_both_branches(temporal_pool: str) -> None:
    torch.manual_seed(0)
    model = XTacformer(spec(), bin_size=3, temporal_pool=temporal_pool, **SMALL)
    x = events(4, 9, 39, 2)
    logits = model(x)
    assert logits.shape == (4, 3) and torch.isfinite(logits).all()
    torch.nn.functional.cross_entropy(logits, torch.tensor([0, 1, 2, 0])).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    for first_layer in (model.spatial.gc, model.temporal.cell.gc):
        assert sum(p.grad.abs().sum() for p in first_layer.parameters()) > 0


def test_the_temporal_branch_depends_on_frame_order() -> None:
    torch.manual_seed(1)
    model = XTacformer(spec(), bin_size=1, **SMALL).eval()
    x = events(2, 9, 39, 2, seed=1)
    tg = model.temporal(x.transpose(0, 1))
    tg_rev = model.temporal(x.flip(1).transpose(0, 1))
    assert not torch.allclose(tg, tg_rev)  # a recurrence, not a bag of frames


@pytest.mark.parametrize("bin_size", [1, 2])
def test_streaming_equals_forward_on_every_prefix(bin_size: int) -> None:
    torch.manual_seed(2)
    model = XTacformer(spec(), bin_size=bin_size, **SMALL).double().eval()
    x = events(2, 7, 39, 2, seed=2).double() * 2.0
    state = model.init_state(2)
    for t in range(x.shape[1]):
        scores, state = model.step(x[:, t], None, state)
        torch.testing.assert_close(scores, model(x[:, :t + 1]), msg=f"step {t}")


def test_other_sensor_with_globals() -> None:
    torch.manual_seed(3)
    model = XTacformer(spec(num_globals=3, sensor=BIOTAC_SP, channels=1), bin_size=2, **SMALL).eval()
    x, g = torch.randn(2, 9, 24, 1), torch.randn(2, 9, 3)
    assert model(x, g).shape == (2, 3)
    with pytest.raises(ConfigError, match="g must be"):
        model(x, g[..., :2])


def test_registered_with_recipe_and_streaming_meta() -> None:
    meta = get_model_entry("x_tacformer").meta
    assert meta["causal"] is True and meta["streaming"] is True
    assert {"spiking", "graph", "attention", "recurrent"} <= set(meta["tags"])
    assert {"loss", "optimizer", "lr", "max_epochs", "patience", "batch_size"} <= set(meta["recipe"])
    assert isinstance(instantiate_model("X-Tacformer", spec(), dim=8, heads=2, hidden=4), XTacformer)
