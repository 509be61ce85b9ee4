"""X-Tacformer: shapes, gradients through both branches, streaming equals the forward on every prefix, metadata, and
its constructor (Tacformer's signature shared) builds what the written-out one built, bit for bit."""

from __future__ import annotations

import inspect

import pytest
import torch
from test_tacformer import check_attention_hparam

from tactile_zoo.data.sensors import BIOTAC_SP, NEUTOUCH
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.tacformer import Tacformer
from tactile_zoo.models.x_tacformer import XTacformer
from tactile_zoo.nn.tgcn import TemporalGraphAttention
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


# --------------------------------------------------------------- one constructor signature, shared with Tacformer
#: XTacformer's constructor as it was written out in full (all of Tacformer's keywords re-declared), kept as the
#: oracle of the shared signature: names, order, kinds, defaults and annotations
SIGNATURE = [
    ("spec", inspect.Parameter.empty, "DatasetSpec"), ("dim", 64, "int"), ("heads", 4, "int"), ("depth", 1, "int"),
    ("mlp_ratio", 0.0, "float"), ("hops", 3, "int"), ("tau", 2.0, "float"), ("v_th", 1.0, "float"),
    ("surrogate", "atan", "str"), ("detach_reset", True, "bool"), ("bin_size", 5, "int"),
    ("taxel_embedding", True, "bool"), ("pool", "flatten", "str"), ("readout_norm", True, "bool"),
    ("hidden", 16, "int"), ("temporal_pool", "mean", "str"), ("attn_dim", 32, "int"),
    ("temporal_backend", "native", "str"), ("dropout", 0.1, "float"), ("attn_dropout", 0.0, "float"),
    ("graph", "default", "str"), ("graph_backend", "dense", "str"), ("lif_backend", "fused", "str"),
    ("attention", "explicit", "str")]  # the default since revision 3


class _WrittenOut(Tacformer):
    """The constructor before it shared Tacformer's signature, verbatim in what it builds and in which order."""

    def __init__(self, spec: DatasetSpec, dim: int = 64, heads: int = 4, depth: int = 1, mlp_ratio: float = 0.0,
                 hops: int = 3, tau: float = 2.0, v_th: float = 1.0, surrogate: str = "atan",
                 detach_reset: bool = True, bin_size: int = 5, taxel_embedding: bool = True, pool: str = "flatten",
                 readout_norm: bool = True, hidden: int = 16, temporal_pool: str = "mean", attn_dim: int = 32,
                 temporal_backend: str = "native", dropout: float = 0.1, attn_dropout: float = 0.0,
                 graph: str = "default", graph_backend: str = "dense", lif_backend: str = "fused",
                 attention: str = "explicit") -> None:
        super().__init__(spec, dim=dim, heads=heads, depth=depth, mlp_ratio=mlp_ratio, hops=hops, tau=tau, v_th=v_th,
                         surrogate=surrogate, detach_reset=detach_reset, bin_size=bin_size,
                         taxel_embedding=taxel_embedding, pool=pool, readout_norm=readout_norm, dropout=dropout,
                         attn_dropout=attn_dropout, graph=graph, graph_backend=graph_backend,
                         lif_backend=lif_backend, attention=attention)
        self.name = "x_tacformer"
        self.temporal = TemporalGraphAttention(spec.num_channels, hidden, spec.sensor.edge_index(graph),
                                               spec.num_nodes, pool=temporal_pool, attn_dim=attn_dim,
                                               temporal_backend=temporal_backend, graph_backend=graph_backend)
        self.temporal_norm = torch.nn.LayerNorm(self.temporal.out_features)
        self.head = torch.nn.Linear(self.rate_width + self.temporal.out_features, spec.num_classes)

    _features = XTacformer._features


def test_the_signature_is_the_written_out_one() -> None:
    params = list(inspect.signature(XTacformer).parameters.values())
    assert [(p.name, p.default, p.annotation) for p in params] == SIGNATURE
    assert {p.kind for p in params} == {inspect.Parameter.POSITIONAL_OR_KEYWORD}
    assert inspect.signature(XTacformer) == inspect.signature(_WrittenOut)
    with pytest.raises(TypeError, match="hiddn"):
        XTacformer(spec(), hiddn=8)


@pytest.mark.parametrize(("args", "kwargs", "globals_"), [
    ((), {}, 0), ((), {**SMALL, "bin_size": 3}, 3), ((32, 2, 2, 1.0), {"temporal_pool": "flatten", "pool": "mean"}, 0),
    ((), {"hidden": 4, "taxel_embedding": False, "readout_norm": False, "mlp_ratio": 2.0, "dropout": 0.0}, 3)])
def test_the_same_model_bit_for_bit(args: tuple, kwargs: dict, globals_: int) -> None:
    """Same seed, same keywords (positional ones too): the same state_dict (keys, order, values), the same random
    numbers drawn, and the same outputs as the written-out constructor."""
    built = []
    for cls in (XTacformer, _WrittenOut):
        torch.manual_seed(7)
        model = cls(spec(globals_), *args, **kwargs).eval()
        built.append((model, torch.rand(3)))  # what the generator gives next: as many numbers drawn
    (new, new_next), (old, old_next) = built
    assert list(new.state_dict()) == list(old.state_dict()) and torch.equal(new_next, old_next)
    for key, value in old.state_dict().items():
        assert torch.equal(new.state_dict()[key], value), key
    x = events(2, 9, 39, 2, seed=4)
    g = torch.randn(2, 9, globals_) if globals_ else None
    with torch.no_grad():
        assert torch.equal(new(x, g), old(x, g))


def test_attention_hparam_reaches_the_blocks() -> None:
    """Tacformer's check (tests/models/test_tacformer.py) on X-Tacformer: the keyword passes through the shared
    signature to the spatial branch."""
    check_attention_hparam("x_tacformer", spec(), events(3, 9, 39, 2, seed=6).double() * 2.0, bin_size=3, **SMALL)
