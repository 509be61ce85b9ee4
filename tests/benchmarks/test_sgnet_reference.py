"""benchmarks/sgnet_reference.py: the pieces that make the side-by-side fair (the reference's data layout, targets,
batching and graph) and the skip without a reference folder. With ``$TACTILESGNET_DIR`` naming a checkout of
https://github.com/clear-nus/TactileSGNet, the reference's network is also checked against ours with the same
weights; without it those tests are skipped (the reference's code is not part of this repository)."""

from __future__ import annotations

import os
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor, nn

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, common, run, sgnet_reference  # noqa: E402

_REFERENCE = sgnet_reference.reference_dir()
needs_reference = pytest.mark.skipif(_REFERENCE is None or not (_REFERENCE / "tactileSGNet.py").is_file(),
                                     reason="set $TACTILESGNET_DIR to a checkout of clear-nus/TactileSGNet")


def test_layout_gives_the_reference_our_frames_at_real_shapes() -> None:
    """Ev-Objects' shapes (T 250, 39 taxels, 2 polarities): the reference's own frame slicing of the converted
    sample (``split(1, dim=-1)[t].squeeze()``) gives back our frame ``t``."""
    spec = common.ev_spec()
    x = common.synthetic_events(spec, 3, seed=0).x  # (3, 250, 39, 2)
    ref = sgnet_reference.to_reference_layout(x)
    assert ref.shape == (3, 39, 2, 250) and ref.dtype == torch.float32 and ref.is_contiguous()
    for s in range(3):
        frames = ref[s].split(1, dim=-1)  # what the reference's forward does to one sample
        assert len(frames) == 250
        for t in (0, 1, 137, 249):
            assert torch.equal(frames[t].squeeze(), x[s, t])
    with pytest.raises(ValueError, match="S, T, N, C"):
        sgnet_reference.to_reference_layout(x[0])


def test_layout_is_the_released_files_layout() -> None:
    """Our converted Ev-Objects samples are the released ``sample_*.npy`` arrays as the reference's loader reads
    them (``np.load``: taxel x polarity x time, float32), each with its label."""
    ctx = common.Context(threads=1, quick=True, log=lambda _msg: None)
    root = common.data_root(ctx)
    archive = root / "ev_objects" / "raw" / "Ev-Objects.zip" if root is not None else None
    if archive is None or not archive.exists():
        pytest.skip("Ev-Objects.zip is not in the data home")
    split = common.ev_objects(ctx).train
    ref = sgnet_reference.to_reference_layout(split.x)  # (576, 39, 2, 250)
    flat = ref.reshape(ref.shape[0], -1)
    with zipfile.ZipFile(archive) as zf:
        names = sorted(n for n in zf.namelist() if "/train/" in n and n.endswith(".npy"))[:6]
        assert names
        for name in names:
            with zf.open(name) as fh:
                arr = torch.from_numpy(np.load(fh))
            assert arr.shape == ref.shape[1:] and arr.dtype == ref.dtype
            hits = (flat == arr.reshape(1, -1)).all(dim=1).nonzero().flatten().tolist()
            label = int(name.rsplit("_label_", 1)[1].split(".")[0])
            assert hits and any(int(split.y[i]) == label for i in hits), name


def test_targets_and_loss_are_the_recipes() -> None:
    """The reference's one-hot targets under ``nn.MSELoss()`` give our registered recipe's loss."""
    from tactile_zoo.engine.train import compute_loss

    y = torch.tensor([3, 0, 35, 3])
    target = sgnet_reference.reference_targets(y, 36)
    assert target.shape == (4, 36) and torch.equal(target.sum(1), torch.ones(4))
    assert torch.equal(target.argmax(1), y)
    rates = torch.rand(4, 36, generator=torch.Generator().manual_seed(0))
    recipe = common.model_recipe("sgnet")
    assert float(nn.MSELoss()(rates, target)) == pytest.approx(float(compute_loss(rates, y, recipe)), rel=1e-6)


class _PerSample(nn.Module):
    """A stand-in with the reference's calling convention: one sample ``(N, C, T)`` in, rates ``(K,)`` out."""

    def __init__(self) -> None:
        super().__init__()
        self.fc = nn.Linear(39 * 2, 36)
        self.calls = 0

    def forward(self, sample: Tensor) -> Tensor:
        assert sample.shape == (39, 2, 250)  # one sample at a time, never a batch
        self.calls += 1
        return torch.sigmoid(self.fc(sample.mean(-1).reshape(-1)))


def test_reference_train_steps_once_per_batch_on_the_batch_mean_loss() -> None:
    torch.manual_seed(0)
    x = sgnet_reference.to_reference_layout(common.synthetic_events(common.ev_spec(), 16, seed=0).x)
    y = torch.arange(16) % 36
    net = _PerSample()
    before = net.fc.weight.detach().clone()
    with torch.no_grad():  # the script's per-sample loss (rates (K,) against one one-hot row), averaged over a batch
        expected = float(torch.stack([nn.MSELoss()(net(s), sgnet_reference.reference_targets(y[i:i + 1], 36)[0])
                                      for i, s in enumerate(x[:8])]).mean())
    steps: list[int] = []
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    opt.register_step_post_hook(lambda *_: steps.append(1))
    assert sgnet_reference.reference_train(net, opt, x[:8], y[:8], 8) == pytest.approx(expected, rel=1e-5)
    assert len(steps) == 1 and not torch.equal(before, net.fc.weight)
    net.calls, steps[:] = 0, []
    sgnet_reference.reference_train(net, opt, x, y, 8)
    assert net.calls == 16 and len(steps) == 2  # every sample forwarded alone; one optimiser step per batch of 8


def test_same_graph_compares_edge_sets() -> None:
    from tactile_zoo.registry import instantiate_model

    model = instantiate_model("sgnet", common.ev_spec(num_steps=4))
    edges = model.gc.edge_index

    class _Graph:
        def __init__(self, e: Tensor) -> None:
            self.e = e

        def getEdge(self) -> Tensor:  # noqa: N802 - the reference's name
            return self.e

    net = nn.Module()
    net.graph = _Graph(edges.flip(1))  # the same edges in another order
    assert sgnet_reference.same_graph(model, net)
    net.graph = _Graph(edges[:, 1:])  # one edge missing
    assert not sgnet_reference.same_graph(model, net)


def test_without_a_reference_folder_it_is_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv(sgnet_reference.REFERENCE_ENV, raising=False)
    assert sgnet_reference.reference_dir() is None
    with pytest.raises(common.BenchmarkSkipped, match="TACTILESGNET_DIR"):
        sgnet_reference.load_reference(None)
    (tmp_path / "tactileSGNet.py").write_text("")
    with pytest.raises(common.BenchmarkSkipped, match="to_graph.py"):
        sgnet_reference.load_reference(tmp_path)
    assert BENCHMARKS["sgnet_reference"] == "sgnet_reference"
    assert run.main(["--only", "sgnet_reference", "--threads", "1", "--out", str(tmp_path / "out")]) == 0
    assert "[sgnet_reference] skipped: no TactileSGNet reference folder" in capsys.readouterr().out
    assert not (tmp_path / "out" / "sgnet_reference.csv").exists()
    assert sgnet_reference.main(["--out", str(tmp_path / "out")]) == 0
    assert "sgnet_reference skipped" in capsys.readouterr().err


@needs_reference
def test_reference_network_with_our_weights_is_our_network() -> None:
    """The public code's network holding our dense SGnet's weights gives the same output rates (not all zero)."""
    from tactile_zoo.engine.runtime import flush_denormals
    from tactile_zoo.registry import instantiate_model

    ref = sgnet_reference.load_reference(_REFERENCE)
    spec = common.ev_spec(num_steps=30)
    x = common.synthetic_events(spec, 2, seed=0, density=0.5).x
    torch.manual_seed(0)
    model = instantiate_model("sgnet", spec).eval()
    net = sgnet_reference.reference_network(ref, spec.num_classes, torch.device("cpu")).eval()
    assert sgnet_reference.same_graph(model, net)
    sgnet_reference.copy_weights(model, net)
    with torch.no_grad(), flush_denormals():
        ours, theirs = model(x), sgnet_reference.reference_rates(net, sgnet_reference.to_reference_layout(x))
    assert float(ours.sum()) > 0 and torch.equal(ours, theirs)


@needs_reference
def test_run_writes_every_row(tmp_path: Path) -> None:
    ctx = common.Context(threads=1, quick=True, repeats=1, out=tmp_path, log=lambda _msg: None)
    path = sgnet_reference.run(ctx, reference=os.environ[sgnet_reference.REFERENCE_ENV], samples=16,
                               reference_samples=8, check_samples=2)
    import csv

    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["benchmark", "case", *sgnet_reference.COLUMNS, "note", *common.ENV_COLUMNS]
    assert [r["case"] for r in rows] == ["epoch_event", "epoch_dense", "event_vs_dense"]
    assert all(r["same_graph"] == "True" and float(r["max_rate_diff"]) == 0.0 for r in rows)
    assert rows[0]["fast_samples_timed"] == "16" and rows[0]["naive_samples_timed"] == "8"
    assert all(float(r["ratio"]) > 0 for r in rows)
