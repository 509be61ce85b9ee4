"""PyTorch Geometric interop: ``to_pyg()`` on a sample and on a batch gives ``Data`` / ``Batch`` over the sensor graph,
a stock PyG model (``GCNConv`` + ``global_mean_pool``) trains through it on a real loader, and datasets take a
``pre_transform`` (applied once per sample at load, apart from ``transform``)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader
from torch_geometric.data import Batch, Data
from torch_geometric.nn import GCNConv, global_mean_pool

import tactile_zoo as tz
from tactile_zoo.data import TactileSample

SMALL = {"n_train_per_class": 6, "n_test_per_class": 2, "num_steps": 20}


def test_a_sample_becomes_a_graph_of_the_sensor() -> None:
    ds = tz.load_dataset("sim_uskin_textures", split="train", **SMALL)  # 8 global features
    sample = ds[3]
    data = sample.to_pyg(ds.spec)
    assert isinstance(data, Data)
    assert torch.equal(data.edge_index, ds.spec.sensor.edge_index())
    steps, nodes, channels = sample.x.shape
    assert data.num_nodes == nodes and data.x.shape == (nodes, steps * channels)
    # node i's features are its recording, step by step
    assert torch.equal(data.x[5].view(steps, channels), sample.x[:, 5])
    assert data.y.tolist() == [sample.y] and torch.equal(data.g[0], sample.g)
    assert data.pos.shape == (nodes, len(ds.spec.sensor.positions[0]))
    assert torch.equal(tz.data.to_pyg(sample, ds.spec.sensor).x, data.x)  # the sensor alone is enough


def test_a_batch_becomes_a_pyg_batch() -> None:
    ds = tz.load_dataset("sim_uskin_textures", split="train", **SMALL)
    batch = next(iter(DataLoader(ds, batch_size=5, collate_fn=tz.collate)))
    x, g, y = batch  # still unpacks as before
    graphs = batch.to_pyg(ds.spec)
    assert isinstance(graphs, Batch) and graphs.num_graphs == 5
    assert graphs.g.shape == g.shape and torch.equal(graphs.y, y)
    assert torch.equal(graphs.x[graphs.batch == 2], ds[2].to_pyg(ds.spec).x)
    assert graphs.edge_index.shape[1] == 5 * ds.spec.sensor.edge_index().shape[1]


class _GCN(nn.Module):
    """A stock PyG classifier: two GCNConv layers, mean pooling over the taxels, a linear read-out."""

    def __init__(self, features: int, classes: int) -> None:
        super().__init__()
        self.conv1, self.conv2 = GCNConv(features, 32), GCNConv(32, 32)
        self.out = nn.Linear(32, classes)

    def forward(self, data: Batch) -> torch.Tensor:
        h = F.relu(self.conv1(data.x, data.edge_index))
        h = F.relu(self.conv2(h, data.edge_index))
        return self.out(global_mean_pool(h, data.batch))


def test_a_stock_pyg_model_trains_through_to_pyg() -> None:
    ds = tz.load_dataset("sim_evtouch", split="train", n_train_per_class=8, n_test_per_class=2, num_steps=30)
    torch.manual_seed(0)
    loader = DataLoader(ds, batch_size=16, shuffle=True, collate_fn=tz.collate)
    model = _GCN(ds.spec.num_steps * ds.spec.num_channels, ds.spec.num_classes)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    everything = tz.collate([ds[i] for i in range(len(ds))]).to_pyg(ds.spec)

    def loss_on_all() -> float:
        with torch.no_grad():
            return F.cross_entropy(model(everything), everything.y).item()

    before = loss_on_all()
    for _ in range(10):  # ten epochs of 5 steps
        for batch in loader:
            graphs = batch.to_pyg(ds.spec)
            loss = F.cross_entropy(model(graphs), graphs.y)
            opt.zero_grad()
            loss.backward()
            opt.step()
    assert loss_on_all() < 0.8 * before


def test_pre_transform_runs_once_per_sample_at_load_and_transform_on_reading() -> None:
    calls: list[int] = []

    def crop(sample: TactileSample) -> TactileSample:
        calls.append(sample.y)
        return TactileSample(sample.x[:8] * 2, sample.g[:8], sample.y)

    plain = tz.load_dataset("sim_evtouch", split="train", **SMALL)
    ds = tz.load_dataset("sim_evtouch", split="train", pre_transform=crop,
                         transform=lambda s: TactileSample(s.x + 1, s.g, s.y), **SMALL)
    assert len(calls) == len(ds) == len(plain)  # once per sample, at load
    assert ds.spec.num_steps == 8 and ds.x.shape[1] == 8  # what the dataset holds, and its spec
    assert torch.equal(ds.x, plain.x[:, :8] * 2)  # transform is not baked in
    assert torch.equal(ds[0].x, plain.x[0, :8] * 2 + 1)  # transform on reading, on top
    ds[1], ds[2]
    assert len(calls) == len(ds)  # reading never runs it again
    with pytest.raises(tz.ConfigError, match="pre_transform must return TactileSample"):
        tz.load_dataset("sim_evtouch", split="train", pre_transform=lambda s: s.x, **SMALL)


def test_to_pyg_takes_the_graph_builders_parameters_and_knn_has_the_sources_default_k() -> None:
    # issue 38: to_pyg(spec, graph="knn") failed (knn_edges() missing 'k') and to_pyg could not pass k
    ds = tz.load_dataset("sim_evtouch", split="test", n_train_per_class=2, n_test_per_class=1, num_steps=20)
    sensor = ds.spec.sensor
    default_knn = ds[0].to_pyg(ds.spec, graph="knn")
    assert torch.equal(default_knn.edge_index, sensor.edge_index("knn", k=3))  # TactileSGNet's TactileGraph(k=3)
    five = ds[0].to_pyg(ds.spec, graph="knn", k=5)
    assert torch.equal(five.edge_index, sensor.edge_index("knn", k=5))
    assert five.edge_index.shape[1] > default_knn.edge_index.shape[1]
    batch = tz.collate([ds[0], ds[1]]).to_pyg(ds.spec, graph="radius", r=2.0)
    assert batch.edge_index.shape[1] == 2 * sensor.edge_index("radius", r=2.0).shape[1]
    assert torch.equal(tz.data.to_pyg(ds[0], ds.spec, "knn", k=5).edge_index, five.edge_index)
    with pytest.raises(tz.ConfigError, match="knn graph needs an integer 1 <= k < 39, got k=39"):
        ds[0].to_pyg(ds.spec, graph="knn", k=39)
