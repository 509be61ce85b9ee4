"""The engine's refusals and edge cases that the training tests do not reach, each with its message: what ``fit``
takes, checkpoints that are not whole, devices this machine lacks, empty and mismatched splits, a model without
parameters, and the evaluation helpers on degenerate input. Tiny tensors only: nothing here trains."""

from __future__ import annotations

import errno
import os
import zipfile
from pathlib import Path

import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.engine import checkpoint, runtime
from tactile_zoo.engine.api import fit
from tactile_zoo.engine.checkpoint import (
    CHECKPOINT_FORMAT,
    build_from_checkpoint,
    is_checkpoint,
    load_checkpoint,
    save_checkpoint,
)
from tactile_zoo.engine.evaluate import EvalResult, earliness, predict_scores, time_inference
from tactile_zoo.engine.metrics import Metric, MetricError, metric_value, tied_top
from tactile_zoo.engine.tensors import TensorSplit, as_split, concat
from tactile_zoo.engine.train import build_optimizer, train_model
from tactile_zoo.errors import ConfigError, DatasetError
from tactile_zoo.recipe import Recipe


@pytest.fixture
def blobs() -> TensorSplit:
    return as_split(tz.load_dataset("tiny_blobs", split="train"))


# ------------------------------------------------------------------------------------------------ fit
def test_fit_takes_a_module_or_a_registered_name(blobs: TensorSplit) -> None:
    with pytest.raises(ConfigError, match="^fit\\(\\) needs a torch.nn.Module or a registered model name, got dict$"):
        fit({"layers": 2}, blobs)
    with pytest.raises(ConfigError, match="^hparams only apply when fit\\(\\) builds the model from its name$"):
        fit(nn.Linear(2, 2), blobs, hparams={"hidden": 4})


def test_fit_of_a_module_on_a_dataset_name_loads_its_splits(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {}

    def train_model(module, train, recipe, seed, val, device, **kw):  # noqa: ANN001, ANN003, ANN202
        seen.update(train=train, val=val, test=kw["test_dataset"], epochs=recipe.max_epochs)
        return "fitted"

    monkeypatch.setattr("tactile_zoo.engine.api.train_model", train_model)
    model = tz.create_model("tiny_mlp", spec=as_split(tz.load_dataset("tiny_blobs", split="train")).spec)
    assert fit(model, "tiny_blobs", epochs=3, progress=False) == "fitted"
    assert (seen["train"].name, seen["val"].split, seen["test"].split, seen["epochs"]) == ("train", "val", "test", 3)
    mine = as_split(tz.load_dataset("tiny_blobs", split="test"))
    fit(model, "tiny_blobs", val_dataset=mine, progress=False)
    assert seen["val"] is mine and seen["test"].split == "test"  # a split given wins over the loaded one


# ------------------------------------------------------------------------------------------------ checkpoints
def _saved(path: Path, blob: object) -> Path:
    torch.save(blob, path)
    return path


def test_is_checkpoint_reads_the_marker_of_a_zip_torch_wrote(tmp_path: Path) -> None:
    ours = save_checkpoint(tmp_path / "m.pt", nn.Linear(2, 2), {"model": "tiny_mlp"})
    assert is_checkpoint(ours)
    assert not is_checkpoint(_saved(tmp_path / "other.pt", {"format": "someone-else/1"}))
    with zipfile.ZipFile(tmp_path / "a.zip", "w") as z:  # a zip archive torch cannot read
        z.writestr("notes.txt", "hello")
    assert not is_checkpoint(tmp_path / "a.zip")
    assert not is_checkpoint(tmp_path)


def test_a_config_that_is_not_plain_json_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="^checkpoint config must hold plain JSON types: Object of type set"):
        save_checkpoint(tmp_path / "m.pt", nn.Linear(2, 2), {"model": "tiny_mlp", "tags": {"a"}})
    assert not (tmp_path / "m.pt").exists()


def test_a_checkpoint_that_cannot_be_written_names_the_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def full(path: Path, data: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(checkpoint, "atomic_write_bytes", full)
    with pytest.raises(ConfigError) as caught:
        save_checkpoint(tmp_path / "m.pt", nn.Linear(2, 2), {"model": "tiny_mlp"}, flag="--save")
    assert str(caught.value) == (f"--save {tmp_path / 'm.pt'}: cannot write the checkpoint (No space left on "
                                 f"device); nothing was written there")


@pytest.mark.parametrize(("blob", "message"), [
    ({"format": CHECKPOINT_FORMAT, "state_dict": [1], "config": {"model": "tiny_mlp"}},
     "lacks its state_dict or config"),
    ({"format": CHECKPOINT_FORMAT, "state_dict": {}}, "lacks its state_dict or config"),
    ({"format": CHECKPOINT_FORMAT, "state_dict": {}, "config": {"model": 3}}, ": config has no model name"),
])
def test_a_checkpoint_missing_a_part_is_refused(tmp_path: Path, blob: dict, message: str) -> None:
    path = _saved(tmp_path / "m.pt", blob)
    with pytest.raises(ConfigError, match=f"^checkpoint {path}.*{message}$"):
        load_checkpoint(path)


def test_a_checkpoint_that_cannot_be_read_says_why(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = save_checkpoint(tmp_path / "m.pt", nn.Linear(2, 2), {"model": "tiny_mlp"})

    def denied(self: Path, *args: object, **kwargs: object) -> object:
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(Path, "open", denied)
    with pytest.raises(ConfigError, match=f"^checkpoint {path} cannot be read: Permission denied$"):
        load_checkpoint(path)


def test_weights_that_do_not_fit_the_model_are_refused_naming_it(blobs: TensorSplit) -> None:
    blob = {"format": CHECKPOINT_FORMAT, "state_dict": {"head.weight": torch.zeros(1, 1)},
            "config": {"model": "tiny_mlp"}}
    with pytest.raises(ConfigError, match="^m.pt does not fit model 'tiny_mlp': Error"):
        build_from_checkpoint(blob, blobs.spec, where="m.pt")


# ------------------------------------------------------------------------------------------------ devices, threads
def test_a_device_that_is_not_a_name_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"^--device must be a device name \(auto, cpu, cuda, cuda:N, mps\), got 0$"):
        runtime.resolve_device(0)


def test_a_gpu_index_this_machine_lacks_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    with pytest.raises(ConfigError, match=r"^--device 'cuda:2': this machine has 2 CUDA device\(s\), cuda:0 to "
                                          r"cuda:1$"):
        runtime.resolve_device("cuda:2")
    assert runtime.resolve_device("cuda:1") == torch.device("cuda:1")
    assert runtime.resolve_device("cuda:7", here=False) == torch.device("cuda:7")  # another machine's GPU


def test_mps_is_refused_where_it_is_missing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    with pytest.raises(ConfigError, match="^--device 'mps': Apple's MPS is not available on this machine; use "
                                          "--device cpu$"):
        runtime.resolve_device("mps")
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: True)
    assert runtime.resolve_device("MPS") == torch.device("mps")


def test_set_threads_changes_torchs_count_only_when_asked() -> None:
    before = torch.get_num_threads()
    try:
        runtime.set_threads(None)
        runtime.set_threads(0)
        assert torch.get_num_threads() == before
        runtime.set_threads(before + 1)
        assert torch.get_num_threads() == before + 1
    finally:
        torch.set_num_threads(before)


def test_keep_denormals_turns_flushing_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_ZOO_KEEP_DENORMALS", "1")
    tiny = torch.tensor([1e-40])  # a float32 subnormal
    with runtime.flush_denormals() as on:
        assert on is False and float(tiny * 1) != 0.0


def test_peak_memory_falls_back_when_proc_is_unreadable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(runtime, "_STATUS", tmp_path / "no-status")
    assert runtime._vm_hwm_kb() is None
    with runtime.PeakMemory() as peak:
        pass
    assert peak.source == "ru_maxrss" and peak.mb is not None and peak.mb > 0


def test_cpu_count_without_affinity_is_the_machines(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delattr(os, "sched_getaffinity")
    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert runtime.cpu_count() == 6
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert runtime.cpu_count() == 1


# ------------------------------------------------------------------------------------------------ splits
def test_a_split_as_samples_and_as_tensors(blobs: TensorSplit) -> None:
    x, g, y = blobs.tensors()
    assert x is blobs.x and g is blobs.g and y is blobs.y
    sample = blobs[2]
    assert torch.equal(sample.x, blobs.x[2]) and torch.equal(sample.g, blobs.g[2]) and sample.y == int(blobs.y[2])


def test_an_empty_plain_dataset_is_refused_naming_it(blobs: TensorSplit) -> None:
    empty = type("Empty", (torch.utils.data.Dataset,), {"spec": blobs.spec, "split": "val", "__len__": lambda s: 0})()
    with pytest.raises(DatasetError, match=r"^tiny_blobs \[val\] is empty$"):
        as_split(empty)


def test_splits_of_different_shapes_do_not_join(blobs: TensorSplit) -> None:
    shorter = TensorSplit(blobs.x[:, :5], blobs.g[:, :5], blobs.y, blobs.spec)
    with pytest.raises(DatasetError, match=r"^cannot join splits of shapes \(12, 3, 4\) and \(5, 3, 4\)$"):
        concat(blobs, shorter)


# ------------------------------------------------------------------------------------------------ training
def test_a_model_without_trainable_parameters_is_refused() -> None:
    frozen = nn.Linear(2, 2).requires_grad_(False)
    with pytest.raises(ConfigError, match="^Linear has no trainable parameters$"):
        build_optimizer(frozen, Recipe())


def test_sgd_takes_the_recipes_momentum_and_nesterov() -> None:
    opt = build_optimizer(nn.Linear(2, 2), Recipe(optimizer="sgd", lr=0.05, momentum=0.5, nesterov=True,
                                                  weight_decay=0.01))
    assert isinstance(opt, torch.optim.SGD)
    group = opt.param_groups[0]
    assert (group["lr"], group["momentum"], group["nesterov"], group["weight_decay"]) == (0.05, 0.5, True, 0.01)


def test_an_empty_training_split_is_refused(blobs: TensorSplit) -> None:
    empty = TensorSplit(blobs.x[:0], blobs.g[:0], blobs.y[:0], blobs.spec)
    with pytest.raises(ConfigError, match="^the training split is empty$"):
        train_model(nn.Linear(2, 2), empty, Recipe(), progress=False)


# ------------------------------------------------------------------------------------------------ evaluation
def test_eval_result_as_a_dict() -> None:
    result = EvalResult({"accuracy": 0.5}, [1, 0], [[0.2, 0.8], [0.6, 0.4]], [1, 1], loss=0.7)
    assert result.to_dict() == {"metrics": {"accuracy": 0.5}, "predictions": [1, 0],
                                "probabilities": [[0.2, 0.8], [0.6, 0.4]], "targets": [1, 1], "loss": 0.7}


def test_a_forward_of_the_wrong_shape_is_refused_naming_the_model() -> None:
    class Flat(nn.Module):
        def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
            return x.sum(dim=(1, 2, 3))  # (B,), not (B, K)

    with pytest.raises(RuntimeError, match=r"^Flat.forward returned shape \(3,\); expected \[batch=3, num_classes\]$"):
        predict_scores(Flat(), torch.zeros(3, 2, 1, 1), None)


def test_a_parameterless_model_runs_on_the_cpu(blobs: TensorSplit) -> None:
    class Mean(nn.Module):
        def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
            return x.mean(dim=(1, 2))  # (B, C): C = 4 scores

    scores = predict_scores(Mean(), blobs.x[:5], blobs.g[:5])
    torch.testing.assert_close(scores, blobs.x[:5].mean(dim=(1, 2)))
    assert time_inference(Mean(), TensorSplit(blobs.x[:0], blobs.g[:0], blobs.y[:0], blobs.spec)) is None


def test_earliness_is_none_when_no_prefix_reaches_the_ratio() -> None:
    assert earliness([0.5, 1.0], [0.2, 0.8], 0.8) == 1.0
    assert earliness([0.5, 1.0], [0.2, None], 0.8) is None
    assert earliness([0.25, 0.5], [0.75, 0.9], 0.8, ratio=0.9) == 0.25


def test_a_metric_returning_infinity_is_an_error_naming_it() -> None:
    metric = Metric("boundless", "predictions", lambda y, p: float("inf"), "Boundless")
    with pytest.raises(MetricError, match="^metric 'boundless' returned inf on cell x; expected a finite number$"):
        metric_value(metric, {"targets": [0, 1], "predictions": [0, 1]}, "cell x")


def test_one_class_is_never_a_tie() -> None:
    assert tied_top(torch.zeros(3, 1)).tolist() == [False, False, False]
    assert tied_top(torch.zeros(2, 2)).tolist() == [True, True]
