"""``bench --save-weights``: each computed cell's own trained weights, which reproduce the cell's test predictions."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch
from conftest import run_cli
from safetensors.torch import load_file

import tactile_zoo as tz
from tactile_zoo.engine.evaluate import evaluate


def test_saved_weights_reproduce_the_cells_predictions(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0,1", "--threads", "1",
                    "--no-plots", "--save-weights", "--out", str(out), "-q"]) == 0
    cells = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    assert len(cells) == 2
    test = tz.load_dataset("tiny_blobs", split="test")
    for cell in cells:
        path = out / cell["weights"]["file"]
        assert path.name == f"{cell['cell_id']}.safetensors"
        assert cell["weights"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        model = tz.create_model("tiny_mlp", test.spec)
        model.load_state_dict(load_file(path))
        result = evaluate(model, test)
        assert result.predictions == cell["predictions"]["test"]["predictions"]  # the cell's own model, exactly
    first, second = (load_file(out / c["weights"]["file"]) for c in cells)
    assert any(not torch.equal(first[k], second[k]) for k in first)  # two seeds, two models


def test_without_the_flag_no_weights_are_written(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--threads", "1", "--no-plots", "--out",
                    str(out), "-q"]) == 0
    assert not (out / "weights").exists()
    assert "weights" not in json.loads(next((out / "cells").glob("*.json")).read_text())


def test_the_run_describes_its_weights_in_a_manifest_that_predict_reads(tmp_path: Path, capsys) -> None:
    import numpy as np

    from tactile_zoo.cli import main

    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--threads", "1", "--no-plots",
                    "--save-weights", "--out", str(out), "-q"]) == 0
    cell = json.loads(next((out / "cells").glob("*.json")).read_text())
    manifest = json.loads((out / "weights" / "manifest.json").read_text())
    (entry,) = manifest["weights"]
    assert entry["sha256"] == cell["weights"]["sha256"] and entry["config_hash"] == cell["config_hash"]
    assert entry["accuracy"] == cell["metrics"]["test"]["accuracy"]
    test = tz.load_dataset("tiny_blobs", split="test")
    sample = tmp_path / "sample.npy"
    # one recording as a user would write it: a row per time step, taxel-major channels, then the globals
    np.save(sample, np.concatenate([test.x[0].flatten(1).numpy(), test.g[0].numpy()], axis=1))
    weights = out / cell["weights"]["file"]
    capsys.readouterr()
    assert main(["predict", "tiny_mlp", "--weights", str(weights), "--manifest", str(out / "weights" / "manifest.json"),
                 str(sample), "--json"]) == 0
    (answer,) = json.loads(capsys.readouterr().out)["predictions"]
    # the cell's own prediction for that recording, with the probability the cell stored for it
    assert answer["index"] == cell["predictions"]["test"]["predictions"][0]
    assert abs(answer["probability"] - max(cell["predictions"]["test"]["probabilities"][0])) < 1e-6


def test_the_same_tensors_give_the_same_file(tmp_path: Path) -> None:
    """safetensors writes its metadata map in a random order on each call; a rerun that trained the same tensors
    must still write the same bytes (the weight pack compares files by sha256)."""
    from safetensors import safe_open

    from tactile_zoo.bench.worker import save_weights

    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.BatchNorm1d(4))
    metadata = {"model": "m", "dataset": "d", "cell_id": "m__d__f0__s0__0123", "config_hash": "0123", "note": "é"}
    infos = [save_weights(model, tmp_path / f"{i}.safetensors", metadata) for i in range(8)]
    assert len({info["sha256"] for info in infos}) == 1
    data = (tmp_path / "0.safetensors").read_bytes()
    header = json.loads(data[8:8 + int.from_bytes(data[:8], "little")])
    assert list(header["__metadata__"]) == sorted(metadata)
    with safe_open(tmp_path / "0.safetensors", "pt") as f:  # still a file safetensors reads, metadata intact
        assert f.metadata() == metadata
        assert all(torch.equal(f.get_tensor(k), v) for k, v in model.state_dict().items())
