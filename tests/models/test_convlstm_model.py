"""ConvLSTM classifier (Zapata-Impata et al. 2019): source layers, read-out of the last hidden state, streaming."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError


def spec_for(sensor: str, channels: int, globals_: int = 0, steps: int = 10) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec("t", 4, ("a", "b", "c", "d"), steps, s.num_nodes, channels, globals_, s)


def test_layers_follow_the_source() -> None:
    model = tz.create_model("convlstm", spec_for("biotac_sp", 1))
    layers = model.convlstm.layers
    assert len(layers) == 2
    assert all(layer.hidden_channels == 16 and layer.hidden_conv.kernel_size == (3, 3) for layer in layers)
    assert (model.fc.in_features, model.fc.out_features, model.head.out_features) == (16, 16, 4)
    assert model.grid.grid_shape == (12, 11) and model.grid.fill_passes == 2  # the source's BioTac image


def test_forward_is_pooled_last_hidden_state_through_the_head() -> None:
    torch.manual_seed(0)
    spec = spec_for("neutouch", 2)
    model = tz.create_model("convlstm", spec).eval()
    x = torch.rand(3, 10, 39, 2)
    with torch.no_grad():
        seq, _ = model.convlstm(model.grid(x))  # (B, T, 16, 9, 13)
        pooled = seq[:, -1].mean(dim=(-2, -1))
        want = model.head(torch.relu(model.fc(pooled)))
        assert torch.allclose(model(x), want, atol=1e-6)


def test_globals_join_after_pooling_at_the_last_step() -> None:
    torch.manual_seed(1)
    model = tz.create_model("convlstm", spec_for("optoforce3", 4, globals_=3)).eval()
    assert model.fc.in_features == 16 + 3
    x, g = torch.rand(2, 10, 3, 4), torch.rand(2, 10, 3)
    with torch.no_grad():
        base = model(x, g)
        early = g.clone()
        early[:, :-1] += 5.0
        assert torch.equal(model(x, early), base)  # only g_T is read
        late = g.clone()
        late[:, -1] += 5.0
        assert not torch.allclose(model(x, late), base)
    with pytest.raises(ConfigError, match="3 global features"):
        model(x)


@pytest.mark.parametrize(("sensor", "channels", "globals_"), [("biotac_sp", 1, 0), ("uskin_allegro", 3, 8)])
def test_streaming_matches_forward_on_every_prefix(sensor: str, channels: int, globals_: int) -> None:
    torch.manual_seed(2)
    spec = spec_for(sensor, channels, globals_)
    model = tz.create_model("convlstm", spec).eval()
    x, g = torch.rand(2, 10, spec.num_nodes, channels), torch.rand(2, 10, globals_)
    with torch.no_grad():
        state = model.init_state(2)
        for t in range(10):
            scores, state = model.step(x[:, t], g[:, t] if globals_ else None, state)
            assert torch.allclose(scores, model(x[:, : t + 1], g[:, : t + 1]), atol=1e-5)
    # the state is one (h, c) pair per layer on the grid and one open bin: constant in T
    assert [tuple(h.shape) for h, _ in state.core] == [(2, 16, *spec.sensor.grid_shape)] * 2
    assert tuple(state.pending_x.shape) == (2, spec.num_nodes, channels) and state.pending == 0
    meta = tz.registry.get_model_entry("convlstm").meta
    assert meta["causal"] and meta["streaming"] and meta["recipe"]["batch_size"] == 32


def test_wrong_input_shape_is_named() -> None:
    model = tz.create_model("convlstm", spec_for("neutouch", 2))
    with pytest.raises(ConfigError, match="convlstm"):
        model(torch.rand(2, 10, 38, 2))
    with pytest.raises(ConfigError, match="convlstm"):
        model.step(torch.rand(2, 10, 39, 2), None, model.init_state(2))


def test_backends_agree_through_the_model() -> None:
    spec = spec_for("uskin_allegro", 3, globals_=8)
    torch.manual_seed(3)
    fused = tz.create_model("convlstm", spec)
    ref = tz.create_model("convlstm", spec, backend="autograd")
    ref.load_state_dict(fused.state_dict())
    x, g, y = torch.rand(2, 10, 60, 3), torch.rand(2, 10, 8), torch.tensor([1, 3])
    grads = []
    for model in (fused, ref):
        torch.nn.functional.cross_entropy(model(x, g), y).backward()
        grads.append([p.grad for p in model.parameters()])
    assert all(torch.allclose(a, b, atol=1e-5) for a, b in zip(*grads))
    with pytest.raises(ConfigError, match="backend"):
        tz.create_model("convlstm", spec, backend="cuda-graphs")


def test_long_recordings_are_averaged_into_at_most_max_frames_bins() -> None:
    torch.manual_seed(3)
    spec = spec_for("neutouch", 2, steps=250)
    model = tz.create_model("convlstm", spec).eval()
    assert model.bin_size == 5  # ceil(250 / 50)
    x = torch.rand(2, 250, 39, 2)
    with torch.no_grad():
        seq, _ = model.convlstm(model.grid(x).reshape(2, 50, 5, 2, 9, 13).mean(dim=2))  # 50 bins of 5 frames
        want = model.head(torch.relu(model.fc(seq[:, -1].mean(dim=(-2, -1)))))
        assert torch.allclose(model(x), want, atol=1e-6)
        # a prefix ending inside a bin counts the missing frames as zeros: 7 frames = one bin + 2/5 of the next
        short = torch.cat([x[:, :7], torch.zeros(2, 3, 39, 2)], dim=1)
        assert torch.allclose(model(x[:, :7]), model(short), atol=1e-6)
        assert not torch.equal(model(x[:, :7]), model(x[:, :10]))  # the open bin is read, not dropped
    unbinned = tz.create_model("convlstm", spec, max_frames=None)
    assert unbinned.bin_size == 1
    with pytest.raises(ConfigError, match="max_frames"):
        tz.create_model("convlstm", spec, max_frames=0)


def test_streaming_with_bins_matches_forward_on_every_prefix() -> None:
    torch.manual_seed(4)
    spec = spec_for("neutouch", 2, steps=12)
    model = tz.create_model("convlstm", spec, max_frames=4).eval()
    assert model.bin_size == 3
    x = torch.rand(2, 12, 39, 2)
    with torch.no_grad():
        state = model.init_state(2)
        for t in range(12):
            scores, state = model.step(x[:, t], None, state)
            assert state.pending == (t + 1) % 3
            assert torch.allclose(scores, model(x[:, : t + 1]), atol=1e-5), f"prefix of {t + 1} frames"


def test_windows_of_five_are_not_binned() -> None:
    # BioTac-DoS with window=5: num_steps 5, so max_frames=50 gives bins of one frame, i.e. the source's unbinned read
    spec = spec_for("biotac_sp", 1, steps=5)
    torch.manual_seed(5)
    binned = tz.create_model("convlstm", spec).eval()
    unbinned = tz.create_model("convlstm", spec, max_frames=None).eval()
    unbinned.load_state_dict(binned.state_dict())
    assert binned.bin_size == unbinned.bin_size == 1
    x = torch.rand(3, 5, 24, 1)
    with torch.no_grad():
        assert torch.equal(binned(x), unbinned(x))


def test_minmax_frame_norm_scales_every_image_by_its_own_range() -> None:
    spec = spec_for("biotac_sp", 1, steps=5)
    torch.manual_seed(6)
    plain = tz.create_model("convlstm", spec).eval()
    scaled = tz.create_model("convlstm", spec, frame_norm="minmax").eval()
    scaled.load_state_dict(plain.state_dict())
    x = 2000.0 + 1500.0 * torch.rand(2, 5, 24, 1)  # raw-like electrode values
    images = plain.grid(x)  # (B, T, 1, 12, 11), the source's filled image
    low, high = images.amin(dim=(-2, -1), keepdim=True), images.amax(dim=(-2, -1), keepdim=True)
    with torch.no_grad():
        seq, _ = plain.convlstm((images - low) / (high - low))
        want = plain.head(torch.relu(plain.fc(seq[:, -1].mean(dim=(-2, -1)))))
        assert torch.allclose(scaled(x), want, atol=1e-5)
        # per frame: a positive gain and an offset per frame change nothing
        gain, offset = 1.0 + torch.rand(2, 5, 1, 1), 100.0 * torch.randn(2, 5, 1, 1)
        assert torch.allclose(scaled(x * gain + offset), scaled(x), atol=1e-4)
        assert not torch.allclose(plain(x * gain + offset), plain(x), atol=1e-4)
        assert torch.isfinite(scaled(torch.ones(2, 5, 24, 1))).all()  # a flat image does not divide by zero
    with pytest.raises(ConfigError, match="frame_norm"):
        tz.create_model("convlstm", spec, frame_norm="zscore")


def test_torch_init_keeps_pytorch_conv_defaults() -> None:
    spec = spec_for("biotac_sp", 1, steps=5)
    keras = tz.create_model("convlstm", spec)
    src = tz.create_model("convlstm", spec, init="torch")
    for k_layer, t_layer in zip(keras.convlstm.layers, src.convlstm.layers):
        hid = k_layer.hidden_channels
        forget_k, forget_t = (layer.input_conv.bias[hid: 2 * hid] for layer in (k_layer, t_layer))
        assert torch.equal(forget_k, torch.ones(hid)) and not torch.equal(forget_t, torch.ones(hid))
        for conv in (t_layer.input_conv, t_layer.hidden_conv):  # kaiming_uniform(a=sqrt(5)): |w| <= 1/sqrt(fan_in)
            bound = 1.0 / (conv.in_channels * 9) ** 0.5
            assert conv.weight.abs().max() <= bound
        assert t_layer.input_conv.bias.abs().max() <= 1.0 / (t_layer.input_conv.in_channels * 9) ** 0.5
        # Keras' recurrent kernel is orthogonal: W W^T = I over its (4h, h*k*k) matrix; PyTorch's is not
        w_k, w_t = (layer.hidden_conv.weight.reshape(4 * hid, -1) for layer in (k_layer, t_layer))
        assert torch.allclose(w_k @ w_k.t(), torch.eye(4 * hid), atol=1e-5)
        assert not torch.allclose(w_t @ w_t.t(), torch.eye(4 * hid), atol=1e-2)
    with pytest.raises(ConfigError, match="init"):
        tz.create_model("convlstm", spec, init="xavier")


def test_readout_dropout_acts_in_training_only() -> None:
    spec = spec_for("biotac_sp", 1, steps=5)
    torch.manual_seed(7)
    model = tz.create_model("convlstm", spec, dropout=0.5)
    x = torch.rand(8, 5, 24, 1)
    model.train()
    with torch.no_grad():
        assert not torch.equal(model(x), model(x))  # a fresh mask per call
        model.eval()
        assert torch.equal(model(x), model(x))
    default = tz.create_model("convlstm", spec).train()
    with torch.no_grad():
        state = torch.get_rng_state()
        first = default(x)
        assert torch.equal(torch.get_rng_state(), state)  # dropout 0 (the default) draws nothing
        assert torch.equal(default(x), first)
    with pytest.raises(ConfigError, match="dropout"):
        tz.create_model("convlstm", spec, dropout=1.0)


def test_taxel_readout_keeps_each_taxels_cell() -> None:
    torch.manual_seed(2)
    spec = spec_for("neutouch", 2)
    model = tz.create_model("convlstm", spec, readout="taxels").eval()
    assert model.fc.in_features == 16 * 39
    x = torch.rand(3, 10, 39, 2)
    rows_cols = tz.get_sensor("neutouch").grid
    with torch.no_grad():
        seq, _ = model.convlstm(model.grid(x))  # (B, T, 16, 9, 13)
        top = seq[:, -1]
        # taxel-major per channel: channel c of taxel n is feature c * N + n
        feats = torch.stack([top[:, :, r, c] for r, c in rows_cols], dim=-1).flatten(1)  # (B, 16 * 39)
        want = model.head(torch.relu(model.fc(feats)))
        assert torch.allclose(model(x), want, atol=1e-6)
        # the read-out depends on which taxel saw what
        assert not torch.allclose(model(x.flip(2)), model(x), atol=1e-3)
    for t in range(1, 4):  # the streaming step reads out the same way
        state = model.init_state(3)
        for i in range(t):
            out, state = model.step(x[:, i], None, state)
        with torch.no_grad():
            assert torch.allclose(out, model(x[:, :t]), atol=1e-5)
    with pytest.raises(ConfigError, match="readout must be one of"):
        tz.create_model("convlstm", spec, readout="flat")


def test_the_source_recipe_carries_the_source_setup_on_biotac_dos_and_the_taxel_read_out_on_ev() -> None:
    from tactile_zoo.engine.config import resolve_cell

    own = resolve_cell("convlstm", "biotac_dos", recipe_name="source")
    assert own.hparams == {"frame_norm": "minmax", "init": "torch"}
    assert own.dataset_kwargs == {"window": 5, "stride": 5, "normalize": "none"}
    assert (own.recipe.max_epochs, own.recipe.patience, own.recipe.grad_clip, own.recipe.batch_size) == (30, None,
                                                                                                         None, 32)
    # the read-out chosen on validation, and on Ev-Containers no early stopping; the rest as on any dataset
    for name, patience in (("ev_objects", 20), ("ev_containers", None)):
        ev = resolve_cell("convlstm", name, recipe_name="source")
        assert ev.hparams == {"readout": "taxels"} and ev.dataset_kwargs == {}
        assert (ev.recipe.patience, ev.recipe.grad_clip, ev.recipe.max_epochs) == (patience, 1.0, 100)
    other = resolve_cell("convlstm", "sim_evtouch", recipe_name="source")
    assert other.hparams == {} and other.dataset_kwargs == {} and other.recipe.patience == 20
