"""Frame bins shared by the binned models: sums and means with a partial last bin, and the bin size rule."""

from __future__ import annotations

import pytest
import torch

from tactile_zoo.errors import ConfigError
from tactile_zoo.models._binned import bin_frames, bins_for


def test_bin_frames_sums_and_averages_with_a_partial_last_bin() -> None:
    x = torch.arange(14.0).view(1, 7, 2)  # (B, T, F)
    s = bin_frames(x, 3, "sum")
    torch.testing.assert_close(s, torch.tensor([[[6.0, 9.0], [24.0, 27.0], [12.0, 13.0]]]))
    m = bin_frames(x, 3, "mean")
    torch.testing.assert_close(m, torch.tensor([[[2.0, 3.0], [8.0, 9.0], [12.0, 13.0]]]))
    assert bin_frames(x, 1) is x


@pytest.mark.parametrize(("steps", "max_frames", "want"), [(250, 50, 5), (325, 50, 7), (50, 50, 1), (51, 50, 2),
                                                          (30, 50, 1), (250, None, 1), (1, 1, 1)])
def test_bins_for_brings_the_recording_under_max_frames(steps: int, max_frames: int | None, want: int) -> None:
    k = bins_for("m", steps, max_frames)
    assert k == want
    if max_frames is not None:
        assert -(-steps // k) <= max_frames  # ceil(T / k) bins at most
        assert k == 1 or -(-steps // (k - 1)) > max_frames  # and the smallest such bin


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "50"])
def test_bins_for_names_the_model_and_the_bad_value(bad: object) -> None:
    with pytest.raises(ConfigError, match=r"cnn_lstm: max_frames must be a positive integer"):
        bins_for("cnn_lstm", 250, bad)  # type: ignore[arg-type]
