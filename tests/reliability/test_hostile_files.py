"""Files that carry code: a crafted checkpoint, a poisoned processed cache, and a scan of every loader call.

A pickle runs whatever its ``__reduce__`` names when it is loaded without ``weights_only``. Each payload here
creates a marker file when it runs; each test first proves the payload is live (plain unpickling does create the
marker) and then that tactile-zoo refuses the file without the marker appearing.
"""

from __future__ import annotations

import ast
import pickle
from pathlib import Path

import pytest
import tiny_zoo
import torch

import tactile_zoo
from tactile_zoo.cli import main
from tactile_zoo.data.datasets import RecordingsDataset
from tactile_zoo.errors import ConfigError

PACKAGE = Path(tactile_zoo.__file__).resolve().parent


class Payload:
    """Unpickling this object creates ``marker`` (it could as well delete a home folder)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple:
        return (exec, (f"open({self.marker!r}, 'w').close()",))


class Sneaky(torch.nn.Module):
    """A whole pickled module whose state restoration runs code."""

    def __init__(self, marker: Path) -> None:
        super().__init__()
        self.lin = torch.nn.Linear(2, 2)
        self.marker = str(marker)

    def __setstate__(self, state: dict) -> None:
        Path(state["marker"]).touch()
        super().__setstate__(state)


def _checkpoint(tmp_path: Path) -> Path:
    path = tmp_path / "good.pt"
    assert main(["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--epochs", "1", "--save",
                 str(path), "-q"]) == 0
    return path


def _live(path: Path, marker: Path) -> None:
    """Plain (unsafe) loading of ``path`` runs the payload: the file is a real threat."""
    torch.load(path, weights_only=False)
    assert marker.exists(), "the payload did not run: this test would prove nothing"
    marker.unlink()


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_evaluate_refuses_checkpoints_that_carry_code(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    good = _checkpoint(tmp_path)
    assert main(["evaluate", str(good), "--plugin-module", "tiny_zoo"]) == 0
    assert "accuracy" in capsys.readouterr().out
    blob = torch.load(good, weights_only=True)
    marker = tmp_path / "pwned"
    evil = {
        "config.pt": {**blob, "config": {**blob["config"], "note": Payload(marker)}},
        "weights.pt": {**blob, "state_dict": {**blob["state_dict"], "net.0.weight": Payload(marker)}},
        "toplevel.pt": Payload(marker),
        "module.pt": Sneaky(marker),
    }
    for name, obj in evil.items():
        path = tmp_path / name
        torch.save(obj, path)
        _live(path, marker)
        for debug in ([], ["--debug"]):
            if debug:
                with pytest.raises(ConfigError, match="cannot be loaded safely"):
                    main([*debug, "evaluate", str(path), "tiny_blobs", "--plugin-module", "tiny_zoo"])
                continue
            assert main(["evaluate", str(path), "tiny_blobs", "--plugin-module", "tiny_zoo"]) == 2
            out, err = capsys.readouterr()
            assert out == "" and err.count("\n") == 1 and "Traceback" not in err
            assert err.startswith(f"tactile-zoo: error: checkpoint {path} cannot be loaded safely: it holds Python "
                                  f"objects other than tensors")
        assert not marker.exists(), f"{name}: the payload ran"
    legacy = tmp_path / "legacy.pkl"  # not a torch zip at all: a bare pickle stream
    legacy.write_bytes(pickle.dumps(Payload(marker)))
    assert main(["evaluate", str(legacy), "tiny_blobs"]) == 2
    err = capsys.readouterr().err
    assert "is not a tactile-zoo checkpoint: it is not a zip archive" in err and not marker.exists()


def test_a_poisoned_processed_cache_is_rebuilt_not_run(tmp_path: Path) -> None:
    """The processed cache is a torch file too: one swapped for a payload is discarded and rebuilt."""
    tiny_zoo.write_recordings(tmp_path)
    first = RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1)
    (cache,) = list(first.processed_dir.glob(f"{first._cache_key()}.pt"))
    marker = tmp_path / "pwned"
    torch.save(Payload(marker), cache)
    _live(cache, marker)
    again = RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1)
    assert not marker.exists()
    assert torch.equal(again.x, first.x) and torch.equal(again.y, first.y)
    assert torch.load(cache, weights_only=True)["x"].shape == first.x.shape  # rebuilt in place


def _call_names(tree: ast.AST) -> list[tuple[str, ast.Call]]:
    return [(ast.unparse(node.func), node) for node in ast.walk(tree) if isinstance(node, ast.Call)]


def _keyword(call: ast.Call, key: str) -> object:
    for kw in call.keywords:
        if kw.arg == key:
            return kw.value.value if isinstance(kw.value, ast.Constant) else "<expression>"
    return "<absent>"


UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "marshal", "dill", "joblib", "shelve", "cloudpickle"}


def test_every_loader_call_in_the_package_is_safe() -> None:
    """torch.load only with weights_only=True; numpy never unpickles; no pickle, marshal, yaml.load or eval."""
    torch_loads = 0
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom) else [])
                bad = {str(n).split(".")[0] for n in names} & UNSAFE_MODULES
                assert not bad, f"{path}:{node.lineno}: imports {bad}"
                if isinstance(node, ast.ImportFrom) and node.module in ("torch", "numpy", "yaml"):
                    assert "load" not in {a.name for a in node.names}, f"{path}:{node.lineno}: a bare load()"
        for name, call in _call_names(tree):
            where = f"{path.relative_to(PACKAGE.parent)}:{call.lineno}"
            if name == "torch.load":
                torch_loads += 1
                assert _keyword(call, "weights_only") is True, f"{where}: torch.load without weights_only=True"
            if name.split(".")[0] in ("np", "numpy") and name.split(".")[-1] in ("load", "read_array"):
                assert _keyword(call, "allow_pickle") is False, f"{where}: {name} without allow_pickle=False"
            assert name not in ("yaml.load", "yaml.unsafe_load", "yaml.full_load", "eval", "exec"), f"{where}: {name}"
    assert torch_loads >= 2  # the checkpoint loader and the processed cache, at least
