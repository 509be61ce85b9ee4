"""What the image and sequence models share about their inputs: one clear error for a wrongly shaped ``x`` or
``g``, and the sensor image layer built from a spec's sensor geometry."""

from __future__ import annotations

from torch import Tensor

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn.sensor_grid import SensorGrid

__all__ = ["check_inputs", "sensor_grid"]


def sensor_grid(spec: DatasetSpec, fill_passes: int | None = None) -> SensorGrid:
    """The :class:`~tactile_zoo.nn.sensor_grid.SensorGrid` of ``spec``'s sensor: its ``grid`` and ``grid_shape``, and
    ``fill_passes`` empty-cell fill passes (``None``: the sensor's ``grid_fill``)."""
    sensor = spec.sensor
    return SensorGrid(sensor.grid, sensor.grid_shape, sensor.grid_fill if fill_passes is None else fill_passes)


def check_inputs(name: str, spec: DatasetSpec, x: Tensor, g: Tensor | None, per_step: bool = False) -> Tensor | None:
    """Validate ``x [B, T, N, C]`` (``[B, N, C]`` with ``per_step``) and ``g``; returns ``g``, ``None`` when G = 0."""
    want = (spec.num_nodes, spec.num_channels)
    dims = 3 if per_step else 4
    if x.dim() != dims or tuple(x.shape[-2:]) != want:
        shape = "(B, N, C)" if per_step else "(B, T, N, C)"
        raise ConfigError(f"{name}: x must be {shape} with N, C = {want}, got {tuple(x.shape)}")
    if not per_step and x.shape[1] < 1:
        raise ConfigError(f"{name}: x has no time steps (T = 0)")
    if spec.num_globals == 0:
        return None
    lead = x.shape[:dims - 2]
    if g is None or tuple(g.shape) != (*lead, spec.num_globals):
        raise ConfigError(f"{name}: this dataset has {spec.num_globals} global features; g must be "
                          f"{(*lead, spec.num_globals)}, got {None if g is None else tuple(g.shape)}")
    return g
