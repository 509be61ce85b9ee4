"""The data contract every dataset and model shares: :class:`TactileSample`, :class:`DatasetSpec`, batching.

A sample is ``x: float32 [T, N, C]`` (time x taxels/electrodes x channels), ``g: float32 [T, G]`` global or
proprioceptive features (``G`` may be 0, then ``g`` is ``[T, 0]``) and an integer label ``y``. A batch stacks them to
``x [B, T, N, C]``, ``g [B, T, G]``, ``y [B]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import torch

if TYPE_CHECKING:
    from .sensors import Sensor

__all__ = ["TactileSample", "DatasetSpec", "collate"]


class TactileSample(NamedTuple):
    """One recording: ``x [T, N, C]``, ``g [T, G]`` and the class label ``y``."""

    x: torch.Tensor
    g: torch.Tensor
    y: int


@dataclass(frozen=True)
class DatasetSpec:
    """What a model needs to know about a dataset to be built for it. Hashable, so it can key caches."""

    name: str
    num_classes: int
    class_names: tuple[str, ...]
    num_steps: int  # T
    num_nodes: int  # N
    num_channels: int  # C
    num_globals: int  # G
    sensor: Sensor

    def __post_init__(self) -> None:
        from ..errors import ConfigError

        if len(self.class_names) != self.num_classes:
            raise ConfigError(f"spec {self.name!r}: {len(self.class_names)} class names for {self.num_classes} classes")
        if self.sensor.num_nodes != self.num_nodes:
            raise ConfigError(f"spec {self.name!r}: sensor {self.sensor.name!r} has {self.sensor.num_nodes} nodes, "
                              f"the data {self.num_nodes}")
        for field_name in ("num_classes", "num_steps", "num_nodes", "num_channels"):
            if getattr(self, field_name) < 1:
                raise ConfigError(f"spec {self.name!r}: {field_name} must be positive")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (the sensor by name)."""
        return {"name": self.name, "num_classes": self.num_classes, "class_names": list(self.class_names),
                "num_steps": self.num_steps, "num_nodes": self.num_nodes, "num_channels": self.num_channels,
                "num_globals": self.num_globals, "sensor": self.sensor.name}


def collate(samples: Sequence[TactileSample]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Stack samples into ``x [B, T, N, C]``, ``g [B, T, G]``, ``y [B]`` (a ``DataLoader`` ``collate_fn``)."""
    x = torch.stack([s.x for s in samples])
    g = torch.stack([s.g for s in samples])
    y = torch.as_tensor([int(s.y) for s in samples], dtype=torch.long)
    return x, g, y
