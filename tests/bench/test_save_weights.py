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
