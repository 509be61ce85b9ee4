"""``examples/robot_loop.py``: the exported step, run frame by frame with onnxruntime and numpy only, gives the
eager model's scores on every prefix of a recording."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.export import export_model, onnx_available, onnxruntime_available

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "robot_loop.py"

pytestmark = pytest.mark.skipif(not (onnx_available() and onnxruntime_available()),
                                reason='ONNX export needs the export extra: pip install "tactile-zoo[export]"')


def _load_example() -> object:
    spec = importlib.util.spec_from_file_location("robot_loop", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_robot_loop_reproduces_the_eager_model_frame_by_frame(tmp_path: Path) -> None:
    # 8 global features per frame, and bins of 3 frames (10 frames, max_frames 4), so that the last bin is partial
    data = tz.load_dataset("sim_uskin_textures", root=tmp_path / "data", split="test", num_steps=10)
    torch.manual_seed(0)
    model = tz.create_model("cnn_lstm", data.spec, max_frames=4).eval()
    export_model(model, tmp_path, name="cnn_lstm", formats=["onnx"], forward=False)
    x, g = data.x[1], data.g[1]  # (T, N, C), (T, G)
    table = torch.cat([x.reshape(x.shape[0], -1), g], dim=1).numpy()  # (T, N * C + G): bring-your-own format
    np.save(tmp_path / "grasp.npy", table)

    robot_loop = _load_example()
    step = robot_loop.ExportedStep(tmp_path, "cnn_lstm")
    got = [step.update(x_t, g_t) for x_t, g_t in robot_loop.frames(tmp_path / "grasp.npy", step.desc["spec"])]
    with torch.no_grad():
        want = [model(x[None, :k], g[None, :k]).numpy() for k in range(1, x.shape[0] + 1)]  # every prefix
    assert len(got) == len(want) == 10
    np.testing.assert_allclose(np.concatenate(got), np.concatenate(want), rtol=1e-5, atol=1e-5)
    step.reset()  # a new grasp starts from rest: the first frame's scores again
    first = step.update(x[:1].numpy(), g[:1].numpy())
    np.testing.assert_allclose(first, got[0], rtol=0, atol=0)

    run = subprocess.run([sys.executable, str(EXAMPLE), str(tmp_path), "cnn_lstm", str(tmp_path / "grasp.npy"),
                          "--every", "4"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.count("frame ") == 2 and "10 frames, median step" in run.stdout
    bad = tmp_path / "bad.npy"
    np.save(bad, table[:, :-1])
    run = subprocess.run([sys.executable, str(EXAMPLE), str(tmp_path), "cnn_lstm", str(bad)], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode != 0 and f"{bad}: expected rows of {table.shape[1]} values" in run.stderr
