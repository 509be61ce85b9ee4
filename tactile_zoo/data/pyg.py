"""PyTorch Geometric views of samples and batches: :func:`to_pyg`, ``TactileSample.to_pyg`` and
``TactileBatch.to_pyg``.

One sample becomes one graph, the sensor's taxel graph (``edge_index = spec.sensor.edge_index(graph)``), so a stock
PyG model (``GCNConv`` + ``global_mean_pool``) reads it without glue code:

* ``x``: node features ``[N, T * C]``, each taxel's whole recording (time-major: steps ``0..T-1``, each ``C`` channels);
* ``edge_index``: ``[2, E]``, symmetric, no self-loops;
* ``pos``: the taxel positions ``[N, D]`` (float32);
* ``y``: the label, ``[1]``;
* ``g``: the global features ``[1, T, G]`` (``G`` may be 0), so a ``Batch`` holds them as ``[B, T, G]``;
* ``num_nodes``: ``N``.

A batch becomes a ``torch_geometric.data.Batch`` of ``B`` such graphs (``batch`` maps nodes to samples). PyG is
imported on first use: it is a dependency of tactile-zoo, but a heavy import that listing and the CLI do not need.
"""

from __future__ import annotations

from typing import Any

import torch

from ..errors import ConfigError

__all__ = ["to_pyg"]


def _graph(spec: Any, graph: str, graph_kwargs: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor]:
    sensor = getattr(spec, "sensor", spec)  # a DatasetSpec or a Sensor
    if not hasattr(sensor, "edge_index"):
        raise ConfigError(f"to_pyg needs the dataset spec (or its sensor) for the taxel graph, got {spec!r}")
    return sensor.edge_index(graph, **graph_kwargs), torch.tensor(sensor.positions, dtype=torch.float32)


def _data(x: torch.Tensor, g: torch.Tensor, y: Any, edge_index: torch.Tensor, pos: torch.Tensor) -> Any:
    from torch_geometric.data import Data

    steps, nodes, channels = x.shape
    if nodes != pos.shape[0]:
        raise ConfigError(f"to_pyg: the sample has {nodes} taxels, the sensor graph {pos.shape[0]}")
    features = x.permute(1, 0, 2).reshape(nodes, steps * channels)  # (N, T * C): a node's recording, time-major
    label = torch.as_tensor(y, dtype=torch.long).reshape(1)
    return Data(x=features, edge_index=edge_index, pos=pos, y=label, g=g.unsqueeze(0), num_nodes=nodes)


def to_pyg(item: Any, spec: Any, graph: str = "default", **graph_kwargs: Any) -> Any:
    """``item`` as PyG data over the sensor graph (see the module docstring).

    Args:
        item: a :class:`~tactile_zoo.data.spec.TactileSample` (``x [T, N, C]``), or a batch ``(x [B, T, N, C],
            g [B, T, G], y [B])`` as :func:`~tactile_zoo.data.spec.collate` returns it.
        spec: the dataset's :class:`~tactile_zoo.data.spec.DatasetSpec` (or its sensor), which holds the graph.
        graph: the graph kind (:meth:`~tactile_zoo.data.sensors.Sensor.edge_index`; ``"default"``: the sensor's own).
        **graph_kwargs: the graph builder's parameters, passed to ``edge_index``: ``k=`` for ``"knn"`` (default 3),
            ``r=`` for ``"radius"``, ``threshold=`` for ``"mst"``.

    Returns:
        a ``torch_geometric.data.Data`` for a sample, a ``torch_geometric.data.Batch`` for a batch.
    """
    x, g, y = item
    edge_index, pos = _graph(spec, graph, graph_kwargs)
    if x.dim() == 3:
        return _data(x, g, y, edge_index, pos)
    if x.dim() != 4:
        raise ConfigError(f"to_pyg: x must be a sample [T, N, C] or a batch [B, T, N, C], got {tuple(x.shape)}")
    from torch_geometric.data import Batch

    return Batch.from_data_list([_data(x[i], g[i], y[i], edge_index, pos) for i in range(x.shape[0])])
