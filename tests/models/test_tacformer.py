"""Tacformer: shapes, gradients, frame binning, streaming equals the forward on every prefix, registry metadata, the
``attention`` hyper-parameter (fused or explicit eq. 8) reaching every block."""

from __future__ import annotations

import pytest
import torch

from tactile_zoo.data.sensors import NEUTOUCH, USKIN_ALLEGRO
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.tacformer import Tacformer
from tactile_zoo.registry import get_model_entry, instantiate_model

SMALL = dict(dim=16, heads=2, v_th=0.5)


def spec(num_globals: int = 0, sensor=NEUTOUCH, channels: int = 2, steps: int = 10) -> DatasetSpec:
    return DatasetSpec("toy", 3, ("a", "b", "c"), steps, sensor.num_nodes, channels, num_globals, sensor)


def events(b: int, t: int, n: int, c: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(b, t, n, c, generator=g) < 0.3).float()


@pytest.mark.parametrize(("bin_size", "pool"), [(1, "flatten"), (3, "mean")])
def test_forward_shapes_and_finite_gradients(bin_size: int, pool: str) -> None:
    torch.manual_seed(0)
    model = Tacformer(spec(), bin_size=bin_size, pool=pool, mlp_ratio=2.0, **SMALL)
    x = events(4, 10, 39, 2)
    logits = model(x)
    assert logits.shape == (4, 3) and torch.isfinite(logits).all()
    torch.nn.functional.cross_entropy(logits, torch.tensor([0, 1, 2, 0])).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert sum(p.grad.abs().sum() for p in model.spatial.gc.parameters()) > 0  # gradient reaches the first layer


def test_globals_are_used_and_required() -> None:
    torch.manual_seed(1)
    model = Tacformer(spec(num_globals=4, sensor=USKIN_ALLEGRO, channels=3), bin_size=2, **SMALL).eval()
    x = torch.randn(2, 10, 60, 3)
    g = torch.randn(2, 10, 4)
    out = model(x, g)
    assert out.shape == (2, 3)
    assert not torch.allclose(out, model(x, g + 3.0))
    with pytest.raises(ConfigError, match="g must be"):
        model(x)
    with pytest.raises(ConfigError, match="x must be"):
        model(torch.randn(2, 10, 39, 3), g)


@pytest.mark.parametrize("bin_size", [1, 3])
def test_streaming_equals_forward_on_every_prefix(bin_size: int) -> None:
    torch.manual_seed(2)
    model = Tacformer(spec(), bin_size=bin_size, **SMALL).double().eval()
    x = events(2, 8, 39, 2, seed=3).double() * 2.0
    state = model.init_state(2)
    for t in range(x.shape[1]):
        scores, state = model.step(x[:, t], None, state)
        torch.testing.assert_close(scores, model(x[:, :t + 1]), msg=f"step {t}")


def test_streaming_with_globals() -> None:
    torch.manual_seed(4)
    model = Tacformer(spec(num_globals=2), bin_size=2, **SMALL).double().eval()
    x, g = events(1, 5, 39, 2).double(), torch.randn(1, 5, 2, dtype=torch.float64)
    state = model.init_state(1)
    for t in range(5):
        scores, state = model.step(x[:, t], g[:, t], state)
        torch.testing.assert_close(scores, model(x[:, :t + 1], g[:, :t + 1]))


def test_registered_with_recipe_and_streaming_meta() -> None:
    meta = get_model_entry("tacformer").meta
    assert meta["causal"] is True and meta["streaming"] is True
    assert {"spiking", "graph", "attention"} <= set(meta["tags"])
    assert {"loss", "optimizer", "lr", "max_epochs", "patience", "batch_size"} <= set(meta["recipe"])
    model = instantiate_model("Tacformer", spec(), dim=8, heads=2)
    assert isinstance(model, Tacformer)
    with pytest.raises(ConfigError, match="bin_size"):
        Tacformer(spec(), bin_size=0)


def check_attention_hparam(name: str, spec_: DatasetSpec, x: torch.Tensor, **small: object) -> None:
    """``attention=`` reaches every MSA block of model ``name`` (the default: ``"explicit"``, revision 3's; revision
    2's: ``"fused"``); with the same weights the explicit model's logits and gradients equal the fused one's
    (float64); a bad value is a ConfigError naming the argument, also where no attention block is built
    (``depth=0``)."""
    assert [blk.attention for blk in instantiate_model(name, spec_, **small).spatial.attn] == ["explicit"]
    assert [blk.attention for blk in instantiate_model(name, spec_, revision=2, **small).spatial.attn] == ["fused"]
    results = []
    for attention in ("fused", "explicit"):
        torch.manual_seed(5)
        model = instantiate_model(name, spec_, depth=2, attention=attention, **small).double()
        assert [blk.attention for blk in model.spatial.attn] == [attention] * 2
        logits = model(x)
        torch.nn.functional.cross_entropy(logits, torch.arange(len(x)) % 3).backward()
        results.append((model, logits))
    (fused, y_f), (explicit, y_e) = results
    torch.testing.assert_close(y_e, y_f)
    for (n, p_f), (_, p_e) in zip(fused.named_parameters(), explicit.named_parameters()):
        torch.testing.assert_close(p_e.grad, p_f.grad, msg=n)
    for depth in (1, 0):
        with pytest.raises(ConfigError, match="attention must be one of"):
            instantiate_model(name, spec_, depth=depth, attention="flash", **small)


def test_attention_hparam_reaches_the_blocks() -> None:
    check_attention_hparam("tacformer", spec(), events(3, 10, 39, 2, seed=6).double() * 2.0, bin_size=2, **SMALL)
