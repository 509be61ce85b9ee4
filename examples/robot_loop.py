"""Run an exported streaming step frame by frame, as a robot's control loop would: onnxruntime and numpy only.

The robot side needs neither torch nor tactile-zoo. ``tactile-zoo export`` wrote ``MODEL.step.onnx`` and
``MODEL.export.json``; the JSON file names the inputs and outputs and gives every state tensor's shape and initial
value. Each frame goes in as ``x_t (1, N, C)`` (and ``g_t (1, G)`` when the dataset has global features), with the
state the previous call returned; the scores after frame k are the model's answer on the first k frames.

    tactile-zoo export x_tacformer --pretrained ev_objects --out export/
    python examples/robot_loop.py export/ x_tacformer grasp.npy       # a (T, N*C + G) bring-your-own recording

Here the recording stands in for the sensor driver: replace ``frames()`` with your own source of readings, in the
units the weights' dataset feeds its models (the JSON file's ``preprocessing``).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort


class ExportedStep:
    """One exported step and its state: ``update(x_t, g_t)`` -> class scores after this frame."""

    def __init__(self, folder: Path, model: str) -> None:
        self.desc: dict[str, Any] = json.loads((folder / f"{model}.export.json").read_text())
        step = self.desc["step"]
        if step is None:
            raise SystemExit(f"{model} has no exported step: {self.desc.get('step_note')}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1  # one frame at batch 1 is too small to share across threads
        self.session = ort.InferenceSession(str(folder / step["files"]["onnx"]), options,
                                            providers=["CPUExecutionProvider"])
        self.states = step["state"]
        self.classes: list[str] = list(self.desc["spec"]["class_names"])
        self.reset()

    def reset(self) -> None:
        """Back to rest before a new grasp: every state tensor at its initial value ("-inf" reads as a float)."""
        self.state = [np.full(s["shape"], float(s["initial"]), dtype=s["dtype"]) for s in self.states]

    def update(self, x_t: np.ndarray, g_t: np.ndarray | None = None) -> np.ndarray:
        feeds = {"x_t": x_t.astype(np.float32)}
        if g_t is not None:
            feeds["g_t"] = g_t.astype(np.float32)
        feeds.update({s["input"]: v for s, v in zip(self.states, self.state)})
        scores, *self.state = self.session.run(None, feeds)
        return scores


def frames(path: Path, spec: dict[str, Any]) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """The rows of a bring-your-own recording as ``(x_t (1, N, C), g_t (1, G) | None)``."""
    n, c, g = spec["num_nodes"], spec["num_channels"], spec.get("num_globals", 0)
    rows = np.load(path) if path.suffix == ".npy" else np.loadtxt(path, delimiter=",", ndmin=2)
    if rows.ndim != 2 or rows.shape[1] != n * c + g:
        raise SystemExit(f"{path}: expected rows of {n * c + g} values ({n} taxels x {c} channels + {g} globals), "
                         f"got shape {rows.shape}")
    for row in rows:
        yield row[: n * c].reshape(1, n, c), (row[n * c:].reshape(1, g) if g else None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the folder `tactile-zoo export` wrote")
    parser.add_argument("model", help="the exported model's name, e.g. x_tacformer")
    parser.add_argument("recording", type=Path, help="a .npy or .csv recording, one row per frame")
    parser.add_argument("--every", type=int, default=25, help="print every N-th frame (default 25)")
    args = parser.parse_args()

    step = ExportedStep(args.folder, args.model)
    latencies = []
    for k, (x_t, g_t) in enumerate(frames(args.recording, step.desc["spec"]), start=1):
        start = time.perf_counter()
        scores = step.update(x_t, g_t)
        latencies.append(time.perf_counter() - start)
        if k % args.every == 0:
            best = int(scores[0].argmax())
            print(f"frame {k:4d}: {step.classes[best]} (score {scores[0, best]:.3f})")
    print(f"{len(latencies)} frames, median step {1e3 * float(np.median(latencies)):.3f} ms")


if __name__ == "__main__":
    main()
