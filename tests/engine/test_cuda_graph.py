"""CUDA-graph training (``tactile_zoo.engine.cuda_graph``): what can be checked without a GPU.

The recording itself needs CUDA (``tests/gpu/test_cuda_graph_training.py`` checks it, gradients against eager); here
the dispatch around it runs on the CPU with a stand-in recorder that counts its calls, and the engine's switches are
checked to refuse or ignore what they must.
"""

from __future__ import annotations

from typing import Any

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine import fit
from tactile_zoo.engine.cuda_graph import CaptureError, GraphedForward
from tactile_zoo.errors import ConfigError


class _Tiny(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.bn = torch.nn.BatchNorm1d(3)
        self.fc = torch.nn.Linear(3, 2)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        h = x.mean(dim=(1, 2))  # (B, C)
        return self.fc(self.bn(h))


class _Recorder:
    """Stands in for ``make_graphed_callables``: runs the warm-up calls as torch does, then returns the callable."""

    def __init__(self, warmups: int = 3) -> None:
        self.warmups, self.calls = warmups, 0

    def __call__(self, module: torch.nn.Module, args: tuple[torch.Tensor, ...], **kwargs: Any) -> Any:
        assert kwargs == {"allow_unused_input": True}
        for _ in range(self.warmups):  # as torch's warm-up, these update running statistics
            module(*args)

        def graphed(*a: torch.Tensor) -> torch.Tensor:
            self.calls += 1
            return module(*a)
        return graphed


def _batch(b: int = 4) -> torch.Tensor:
    return torch.randn(b, 5, 6, 3)  # (B, T, N, C)


def test_batches_of_the_recorded_shape_replay_the_others_run_eagerly() -> None:
    model, rec = _Tiny(), _Recorder()
    graphed = GraphedForward(model, _batch(), capture=rec)
    graphed(_batch())
    assert (rec.calls, graphed.replays) == (1, 1)
    graphed(_batch(3))  # the shorter last batch of an epoch
    assert (rec.calls, graphed.replays) == (1, 1)
    model.eval()  # validation: recorded in training mode, so never replayed here
    graphed(_batch())
    assert rec.calls == 1
    model.train()
    graphed(_batch(), torch.zeros(4, 5, 2))  # global features the recording did not have
    assert rec.calls == 1
    graphed.release()
    graphed(_batch())
    assert rec.calls == 1


def test_the_warm_up_calls_leave_no_trace_in_the_running_statistics() -> None:
    model = _Tiny()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    GraphedForward(model, _batch() * 10 + 3, capture=_Recorder())
    after = model.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before), "capture's warm-up moved the batch-norm buffers"


def test_a_model_that_cannot_be_recorded_is_named() -> None:
    def refuse(module: torch.nn.Module, args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("operation not permitted when stream is capturing")

    with pytest.raises(CaptureError, match="_Tiny's training forward could not be recorded.*not permitted"):
        GraphedForward(_Tiny(), _batch(), capture=refuse)


def _split() -> Any:
    return tz.load_dataset("tiny_blobs", split="train")


def test_cuda_graphs_on_the_cpu_is_refused_before_any_work() -> None:
    with pytest.raises(ConfigError, match="cuda_graphs=True needs a CUDA device; this run trains on cpu"):
        fit("tiny_mlp", _split(), device="cpu", epochs=1, progress=False, cuda_graphs=True)


def test_the_environment_variable_is_ignored_on_the_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_ZOO_CUDA_GRAPHS", "1")
    eager = fit("tiny_mlp", _split(), device="cpu", epochs=2, progress=False, seed=3)
    monkeypatch.delenv("TACTILE_ZOO_CUDA_GRAPHS")
    plain = fit("tiny_mlp", _split(), device="cpu", epochs=2, progress=False, seed=3)
    assert [r["train_loss"] for r in eager.curve] == [r["train_loss"] for r in plain.curve]


def test_a_bad_value_of_the_variable_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo.engine.train import _cuda_graphs

    monkeypatch.setenv("TACTILE_ZOO_CUDA_GRAPHS", "maybe")
    with pytest.raises(ConfigError, match="TACTILE_ZOO_CUDA_GRAPHS"):
        _cuda_graphs(None, torch.device("cuda"))
