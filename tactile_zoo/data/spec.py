"""The data contract every dataset and model shares: :class:`TactileSample`, :class:`DatasetSpec`, batching.

A sample is ``x: float32 [T, N, C]`` (time x taxels/electrodes x channels), ``g: float32 [T, G]`` global or
proprioceptive features (``G`` may be 0, then ``g`` is ``[T, 0]``) and an integer label ``y``. A batch stacks them to
``x [B, T, N, C]``, ``g [B, T, G]``, ``y [B]``. ``to_pyg(spec)`` on either gives PyTorch Geometric data over the
sensor graph (:mod:`tactile_zoo.data.pyg`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import torch

if TYPE_CHECKING:
    from .sensors import Sensor

__all__ = ["TactileSample", "TactileBatch", "DatasetSpec", "collate"]


class TactileSample(NamedTuple):
    """One recording: ``x [T, N, C]``, ``g [T, G]`` and the class label ``y``."""

    x: torch.Tensor
    g: torch.Tensor
    y: int

    def to_pyg(self, spec: DatasetSpec | Sensor, graph: str = "default", **graph_kwargs: Any) -> Any:
        """This sample as a ``torch_geometric.data.Data`` over the sensor graph (:func:`tactile_zoo.data.pyg.to_pyg`;
        the sample does not carry its sensor, so pass the dataset's ``spec``; ``graph_kwargs`` such as ``k=`` go to
        the graph builder)."""
        from .pyg import to_pyg

        return to_pyg(self, spec, graph, **graph_kwargs)


class TactileBatch(NamedTuple):
    """A batch as :func:`collate` returns it: ``x [B, T, N, C]``, ``g [B, T, G]``, ``y [B]`` (a tuple, so ``x, g, y =
    batch`` works as before)."""

    x: torch.Tensor
    g: torch.Tensor
    y: torch.Tensor

    def to_pyg(self, spec: DatasetSpec | Sensor, graph: str = "default", **graph_kwargs: Any) -> Any:
        """This batch as a ``torch_geometric.data.Batch`` of sensor graphs (:func:`tactile_zoo.data.pyg.to_pyg`)."""
        from .pyg import to_pyg

        return to_pyg(self, spec, graph, **graph_kwargs)


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

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], where: str = "spec") -> DatasetSpec:
        """The inverse of :meth:`to_dict`: the sensor is looked up by name in the registry.

        Args:
            values: a dict as :meth:`to_dict` writes it (a cell record's or a weights manifest's ``spec``).
            where: what the dict belongs to, named in the error for a missing or malformed key.
        """
        from ..errors import ConfigError
        from ..registry import get_sensor

        if not isinstance(values, Mapping):
            raise ConfigError(f"{where}: a dataset spec must be a dict, got {type(values).__name__}")
        missing = [k for k in _SPEC_KEYS if k not in values]
        if missing:
            raise ConfigError(f"{where}: the dataset spec lacks {', '.join(missing)}")
        try:
            counts = {k: int(values[k]) for k in ("num_classes", "num_steps", "num_nodes", "num_channels",
                                                  "num_globals")}
        except (TypeError, ValueError):
            given = {k: values[k] for k in _SPEC_KEYS if k.startswith("num_")}
            raise ConfigError(f"{where}: the spec's counts must be integers, got {given}") from None
        names = values["class_names"]
        if isinstance(names, str) or not isinstance(names, Sequence):
            raise ConfigError(f"{where}: class_names must be a list of names, got {names!r}")
        return cls(name=str(values["name"]), class_names=tuple(str(c) for c in names),
                   sensor=get_sensor(str(values["sensor"])), **counts)


_SPEC_KEYS = ("name", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals", "sensor")


def collate(samples: Sequence[TactileSample]) -> TactileBatch:
    """Stack samples into ``x [B, T, N, C]``, ``g [B, T, G]``, ``y [B]`` (a ``DataLoader`` ``collate_fn``)."""
    x = torch.stack([s.x for s in samples])
    g = torch.stack([s.g for s in samples])
    y = torch.as_tensor([int(s.y) for s in samples], dtype=torch.long)
    return TactileBatch(x, g, y)
