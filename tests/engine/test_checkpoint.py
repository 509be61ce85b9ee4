from __future__ import annotations

import pickle
from pathlib import Path

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine import build_from_checkpoint, load_checkpoint, save_checkpoint
from tactile_zoo.errors import ConfigError


def _model() -> torch.nn.Module:
    torch.manual_seed(0)
    return tz.create_model("tiny_mlp", tz.load_dataset("tiny_blobs", split="test").spec, hidden=8)


def test_roundtrip_rebuilds_the_model_through_the_registry(tmp_path: Path) -> None:
    model = _model()
    spec = tz.load_dataset("tiny_blobs", split="test").spec
    path = save_checkpoint(tmp_path / "m.pt", model, {"model": "tiny_mlp", "hparams": {"hidden": 8},
                                                       "spec": spec.to_dict(), "recipe": {"loss": "ce"}})
    blob = torch.load(path, weights_only=True)  # plain types only
    assert set(blob) == {"format", "state_dict", "config"}
    again = build_from_checkpoint(load_checkpoint(path), spec)
    for (k, v), (k2, v2) in zip(model.state_dict().items(), again.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    assert not list(tmp_path.glob("*.tmp"))


class _Evil:
    def __reduce__(self) -> tuple:
        return (print, ("pwned",))


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_a_pickle_with_code_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "evil.pt"
    torch.save({"format": "tactile-zoo-checkpoint/1", "state_dict": {}, "config": {"model": "x"}, "x": _Evil()},
               path)
    with pytest.raises(ConfigError, match="cannot be loaded safely"):
        load_checkpoint(path)
    path.write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(ConfigError):
        load_checkpoint(path)
    torch.save({"weights": {}}, path)
    with pytest.raises(ConfigError, match="not a tactile-zoo checkpoint"):
        load_checkpoint(path)
    with pytest.raises(ConfigError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.pt")


def test_a_checkpoint_for_another_spec_is_a_clear_error(tmp_path: Path) -> None:
    spec = tz.load_dataset("tiny_blobs", split="test").spec
    path = save_checkpoint(tmp_path / "m.pt", _model(), {"model": "tiny_mlp", "hparams": {"hidden": 8},
                                                           "spec": {**spec.to_dict(), "num_classes": 7}})
    with pytest.raises(ConfigError, match="num_classes=7"):
        build_from_checkpoint(load_checkpoint(path), spec)
