"""SensorGrid: taxels land on their cells, empty cells are filled pass by pass with their filled neighbours' mean."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.data.sensors import Sensor
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models._inputs import sensor_grid
from tactile_zoo.nn.sensor_grid import SensorGrid, grid_weights

BUILTIN = ["neutouch", "biotac_sp", "optoforce3", "uskin_allegro"]


def reference_image(sensor: Sensor, values: list[float], passes: int) -> list[list[float]]:
    """A plain-Python rendering of the fill rule, one cell at a time, for one channel of one frame."""
    h, w = sensor.grid_shape
    img = [[0.0] * w for _ in range(h)]
    filled = [[False] * w for _ in range(h)]
    for v, (r, c) in zip(values, sensor.grid):
        img[r][c], filled[r][c] = v, True
    for _ in range(passes):
        new_img = [row[:] for row in img]
        new_filled = [row[:] for row in filled]
        for r in range(h):
            for c in range(w):
                if filled[r][c]:
                    continue
                vals = [img[r + dr][c + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)
                        if (dr or dc) and 0 <= r + dr < h and 0 <= c + dc < w and filled[r + dr][c + dc]]
                if vals:
                    new_img[r][c], new_filled[r][c] = sum(vals) / len(vals), True
        img, filled = new_img, new_filled
    return img


def tiny_sensor() -> Sensor:
    return Sensor("tiny", positions=((0.0, 0.0), (0.0, 2.0)), grid_shape=(3, 3), grid=((0, 0), (0, 2)))


def grid_of(sensor: Sensor, fill_passes: int) -> SensorGrid:
    """The layer for a sensor's geometry (the layer itself never sees a Sensor)."""
    return SensorGrid(sensor.grid, sensor.grid_shape, fill_passes)


def test_hand_computed_fill_passes() -> None:
    x = torch.tensor([[1.0], [3.0]])  # (N=2, C=1)
    one = grid_of(tiny_sensor(), 1)(x)[0]
    assert torch.allclose(one, torch.tensor([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]))
    two = grid_of(tiny_sensor(), 2)(x)[0]
    # row 2 is filled in pass 2 from the cells pass 1 filled: (1+2)/2, (1+2+3)/3, (2+3)/2
    assert torch.allclose(two, torch.tensor([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.5, 2.0, 2.5]]))
    zero = grid_of(tiny_sensor(), 0)(x)[0]
    assert torch.equal(zero, torch.tensor([[1.0, 0.0, 3.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))


def test_a_taxel_reading_zero_still_counts_as_filled() -> None:
    # "non-empty" belongs to the cell, not its value: the middle cell averages 0 and 3, not 3 alone
    out = grid_of(tiny_sensor(), 1)(torch.tensor([[0.0], [3.0]]))[0]
    assert out[0, 1].item() == pytest.approx(1.5)


@pytest.mark.parametrize("name", BUILTIN)
@pytest.mark.parametrize("passes", [0, 1, 2, 3])
def test_matches_reference_on_builtin_sensors(name: str, passes: int) -> None:
    sensor = tz.get_sensor(name)
    g = torch.Generator().manual_seed(0)
    x = torch.randn(3, 2, sensor.num_nodes, 2, generator=g, dtype=torch.float64)  # (B, T, N, C)
    out = grid_of(sensor, passes).double()(x)
    assert out.shape == (3, 2, 2, *sensor.grid_shape)
    for b in range(3):
        for t in range(2):
            for ch in range(2):
                ref = reference_image(sensor, x[b, t, :, ch].tolist(), passes)
                assert torch.allclose(out[b, t, ch], torch.tensor(ref, dtype=torch.float64), atol=1e-12)


def test_sensor_default_passes_and_taxel_cells_untouched() -> None:
    biotac = tz.get_sensor("biotac_sp")
    spec = DatasetSpec("biotac", 1, ("a",), 4, biotac.num_nodes, 1, 0, biotac)
    grid = sensor_grid(spec)  # the models' helper: the sensor's geometry and its own fill passes
    assert grid.fill_passes == biotac.grid_fill == 2
    assert sensor_grid(spec, 0).fill_passes == 0
    assert torch.equal(grid.weight_t, grid_of(biotac, 2).weight_t)
    x = torch.randn(5, biotac.num_nodes, 1)
    out = grid(x)  # (5, 1, 12, 11)
    rows, cols = zip(*biotac.grid)
    assert torch.equal(out[:, 0, list(rows), list(cols)], x[..., 0])
    # the BioTac layout is sparse (24 of 132 cells): one pass leaves empty cells, the source's two fill all of them
    def filled(passes: int) -> int:
        return int((grid_weights(biotac.grid, biotac.grid_shape, passes).sum(1) > 0).sum())

    assert biotac.num_nodes < filled(1) < 132 == filled(2)


def test_leading_dims_and_channels_are_independent() -> None:
    sensor = tz.get_sensor("neutouch")
    grid = grid_of(sensor, 1)
    x = torch.randn(4, 6, sensor.num_nodes, 3)
    full = grid(x)
    assert full.is_contiguous()
    assert torch.allclose(full[2, 5], grid(x[2, 5]), atol=1e-6)
    assert torch.allclose(full[..., 1:2, :, :], grid(x[..., 1:2]), atol=1e-6)


@pytest.mark.parametrize("passes", [0, 2])
def test_gradient_is_the_transposed_map(passes: int) -> None:
    sensor = tz.get_sensor("biotac_sp")
    grid = grid_of(sensor, passes)
    x = torch.randn(2, sensor.num_nodes, 1, requires_grad=True)
    weights = torch.randn(2, 1, *sensor.grid_shape)
    (grid(x) * weights).sum().backward()
    m = grid_weights(sensor.grid, sensor.grid_shape, passes).float()  # (H*W, N)
    expected = (weights.flatten(2) @ m).transpose(1, 2)  # (2, N, 1)
    assert torch.allclose(x.grad, expected, atol=1e-5)


def test_buffers_stay_out_of_the_state_dict_and_bad_input_is_named() -> None:
    neutouch = tz.get_sensor("neutouch")
    grid = SensorGrid(neutouch.grid, neutouch.grid_shape)
    assert grid.fill_passes == 0 and grid.state_dict() == {}
    with pytest.raises(ConfigError, match="39"):
        grid(torch.randn(2, 38, 2))
    with pytest.raises(ConfigError, match="fill_passes"):
        grid_of(neutouch, -1)


@pytest.mark.parametrize("grid, shape", [(((0, 0), (0, 0)), (2, 2)), (((0, 0), (2, 0)), (2, 2)), ((), (2, 2)),
                                         (((0, 0),), (2,)), (((0, 0),), (0, 3))])
def test_bad_geometry_is_refused(grid: tuple[tuple[int, int], ...], shape: tuple[int, ...]) -> None:
    with pytest.raises(ConfigError, match="SensorGrid"):
        SensorGrid(grid, shape)
