"""CNN-LSTM: frame encoder applied per frame, globals per frame, LSTM read-out of the last step, streaming."""

from __future__ import annotations

import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError


def spec_for(sensor: str, channels: int, globals_: int = 0, steps: int = 9) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec("t", 3, ("a", "b", "c"), steps, s.num_nodes, channels, globals_, s)


def test_documented_layers() -> None:
    model = tz.create_model("cnn_lstm", spec_for("neutouch", 2))
    convs = [m for m in model.encoder.modules() if isinstance(m, nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size, c.padding) for c in convs] == \
        [(2, 16, (3, 3), (1, 1)), (16, 32, (3, 3), (1, 1))]
    assert model.encoder.proj.in_features == 32 * 5 * 7  # 9x13 pooled with ceil -> 5x7
    assert (model.lstm.input_size, model.lstm.hidden_size, model.lstm.num_layers) == (64, 64, 1)
    assert model.head.in_features == 64 and model.head.out_features == 3


def test_frames_are_encoded_independently_and_globals_join_each_frame() -> None:
    torch.manual_seed(0)
    model = tz.create_model("cnn_lstm", spec_for("optoforce3", 4, globals_=3)).eval()
    x, g = torch.rand(2, 9, 3, 4), torch.rand(2, 9, 3)
    with torch.no_grad():
        frame_codes = model.encoder(model.grid(x.flatten(0, 1))).view(2, 9, 64)  # each frame on its own
        assert torch.allclose(frame_codes[1, 4], model.encoder(model.grid(x[1, 4])[None])[0], atol=1e-6)
        _, (h, _) = model.lstm(torch.cat([frame_codes, g], dim=-1))  # (B, T, 64 + 3): globals join every frame
        assert torch.allclose(model(x, g), model.head(h[-1]), atol=1e-6)
        early = g.clone()
        early[:, 0] += 3.0  # unlike ConvLSTM's read-out, every step's globals matter
        assert not torch.allclose(model(x, early), model(x, g))


@pytest.mark.parametrize(("sensor", "channels", "globals_"), [("neutouch", 2, 0), ("optoforce3", 4, 3)])
def test_streaming_matches_forward_on_every_prefix(sensor: str, channels: int, globals_: int) -> None:
    torch.manual_seed(1)
    spec = spec_for(sensor, channels, globals_)
    model = tz.create_model("cnn_lstm", spec).eval()
    x, g = torch.rand(3, 9, spec.num_nodes, channels), torch.rand(3, 9, globals_)
    with torch.no_grad():
        state = model.init_state(3)
        for t in range(9):
            scores, state = model.step(x[:, t], g[:, t] if globals_ else None, state)
            assert torch.allclose(scores, model(x[:, : t + 1], g[:, : t + 1]), atol=1e-5)
    assert [tuple(s.shape) for s in state.core] == [(1, 3, 64), (1, 3, 64)]


def test_max_frames_averages_frames_and_globals_into_bins_and_streams_exactly() -> None:
    torch.manual_seed(2)
    spec = spec_for("optoforce3", 4, globals_=3, steps=12)
    model = tz.create_model("cnn_lstm", spec, max_frames=4).eval()
    assert model.bin_size == 3 and tz.create_model("cnn_lstm", spec, max_frames=None).bin_size == 1
    x, g = torch.rand(2, 12, 3, 4), torch.rand(2, 12, 3)
    with torch.no_grad():
        xb, gb = x.view(2, 4, 3, 3, 4).mean(dim=2), g.view(2, 4, 3, 3).mean(dim=2)  # 4 bins of 3 frames
        codes = model.encoder(model.grid(xb.flatten(0, 1))).view(2, 4, 64)
        _, (h, _) = model.lstm(torch.cat([codes, gb], dim=-1))
        assert torch.allclose(model(x, g), model.head(h[-1]), atol=1e-6)
        state = model.init_state(2)
        for t in range(12):
            scores, state = model.step(x[:, t], g[:, t], state)
            assert torch.allclose(scores, model(x[:, : t + 1], g[:, : t + 1]), atol=1e-5), f"prefix of {t + 1}"
    with pytest.raises(ConfigError, match="cnn_lstm: max_frames"):
        tz.create_model("cnn_lstm", spec, max_frames=0)


def test_one_row_grid_and_bad_arguments() -> None:
    model = tz.create_model("cnn_lstm", spec_for("optoforce3", 4, globals_=3))
    assert model.encoder.proj.in_features == 32 * 1 * 2  # 1x3 pooled with ceil -> 1x2
    with pytest.raises(ConfigError, match="conv_channels"):
        tz.create_model("cnn_lstm", spec_for("neutouch", 2), conv_channels=(16,))
    with pytest.raises(ConfigError, match="global"):
        model(torch.rand(2, 9, 3, 4), None)
