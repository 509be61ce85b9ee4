"""Per-frame latency of the exported streaming step at batch 1 on 1 thread: TorchScript and onnxruntime against the
eager ``step()``.

For every registered model with ``streaming=True`` metadata: the model is built for Ev-Objects' spec (NeuTouch, 39
taxels, T = 250; weights from a seeded initialisation, which the timing does not depend on) and its step is exported
with :func:`tactile_zoo.export.export_model` (``forward=False``). One Ev-Objects test sample (synthetic
events of the same shape when the zip is absent) is then fed frame by frame, from the initial state, through three
runtimes in turn, each call timed:

- ``eager``: ``model.step(x_t, None, state)`` under ``torch.inference_mode`` (what ``streaming_latency`` times);
- ``torchscript``: the ``MODEL.step.pt`` file (``torch.jit.load``) with its flat state, under ``torch.no_grad``;
- ``onnxruntime``: ``MODEL.step.onnx`` in an ``InferenceSession`` with one intra-op and one inter-op thread,
  subnormals flushed as the eager side does, state kept as NumPy arrays between calls (what a Python robot loop
  would do; the conversion of the frame to NumPy is done beforehand).

Each pass streams the whole sample through every runtime (the order rotates between passes, ``repeats`` passes).
``median_ms`` is the median over all steps of all passes; ``speedup_vs_eager`` is the eager median over the
runtime's. ``max_abs_diff`` compares the runtime's scores after every step with the eager ones. onnxruntime rows
are left out, and said so in the log, when the export extra is not installed.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from .common import Context, ev_objects, write_csv

NAME = "export_latency"
TITLE = "Exported streaming step (TorchScript, onnxruntime) per-frame latency at batch 1 on 1 thread vs eager step()"
COLUMNS = ("model", "runtime", "data", "steps", "batch", "median_ms", "p99_ms", "max_ms", "cpu_median_ms",
           "eager_median_ms", "speedup_vs_eager", "max_abs_diff", "state_tensors", "onnx_opset", "onnxruntime",
           "repeats", "target")
RUNTIMES = ("eager", "torchscript", "onnxruntime")


def _load_note() -> str:
    """The machine's load when the benchmark starts: on a busy machine the absolute times are inflated and noisy,
    while the runtimes of one model, measured in alternating passes, stay comparable."""
    import os

    cores = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except OSError:
        return "load average unknown"
    busy = (" (loaded: other processes held the cores; absolute times are inflated, compare the runtimes of one "
            "model, timed side by side)") if load > 0.5 * cores else ""
    return f"1-min load average {load:.2f} on {cores} cores at the start{busy}"


def _median(values: list[float]) -> float:
    s = sorted(values)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def _ort_session(path: Path) -> Any:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.add_session_config_entry("session.set_denormal_as_zero", "1")  # as the eager side's flush-to-zero
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def _streamers(model: torch.nn.Module, result: Any, with_onnx: bool) -> dict[str, Any]:
    """For each runtime, a function streaming frames ``(T, 1, N, C)`` from the initial state: per-step wall and CPU
    seconds and the scores after every step ``(T, K)``."""
    from tactile_zoo.export import initial_state

    start = initial_state(result.manifest)

    def eager(frames: torch.Tensor) -> tuple[list[float], list[float], torch.Tensor]:
        state, wall, cpu, scores = model.init_state(1), [], [], []
        with torch.inference_mode():
            for x_t in frames:
                c0, w0 = time.process_time(), time.perf_counter()
                out, state = model.step(x_t, None, state)
                wall.append(time.perf_counter() - w0)
                cpu.append(time.process_time() - c0)
                scores.append(out)
        return wall, cpu, torch.cat(scores)

    traced = torch.jit.load(str(result.files[("torchscript", "step")]))

    def torchscript(frames: torch.Tensor) -> tuple[list[float], list[float], torch.Tensor]:
        state, wall, cpu, scores = list(start), [], [], []
        with torch.no_grad():
            for x_t in frames:
                c0, w0 = time.process_time(), time.perf_counter()
                out = traced(x_t, *state)
                wall.append(time.perf_counter() - w0)
                cpu.append(time.process_time() - c0)
                state = out[1:]
                scores.append(out[0])
        return wall, cpu, torch.cat(scores)

    runs = {"eager": eager, "torchscript": torchscript}
    if with_onnx:
        session = _ort_session(result.files[("onnx", "step")])
        names = [i.name for i in session.get_inputs()]
        initial = [t.numpy() for t in start]

        def onnxruntime(frames: torch.Tensor) -> tuple[list[float], list[float], torch.Tensor]:
            state, wall, cpu, scores = initial, [], [], []
            arrays = [x_t.numpy() for x_t in frames]
            for x_t in arrays:
                c0, w0 = time.process_time(), time.perf_counter()
                out = session.run(None, dict(zip(names, [x_t, *state])))
                wall.append(time.perf_counter() - w0)
                cpu.append(time.process_time() - c0)
                state = out[1:]
                scores.append(torch.from_numpy(out[0]))
            return wall, cpu, torch.cat(scores)

        runs["onnxruntime"] = onnxruntime
    return runs


def run(ctx: Context, models: list[str] | None = None, steps: int | None = None) -> Path:
    from tactile_zoo.engine import seed_everything
    from tactile_zoo.export import export_model, onnx_available, onnxruntime_available
    from tactile_zoo.registry import get_model_entry, instantiate_model, model_names

    data = ev_objects(ctx)
    test = data.test
    x = test.x[:1]  # (1, T, N, C)
    if steps is not None:
        x = x[:, :steps]
    frames = x.transpose(0, 1).contiguous()  # (T, 1, N, C)
    with_onnx = onnx_available() and onnxruntime_available()
    if not with_onnx:
        ctx.log('  onnx, onnxscript or onnxruntime missing (pip install "tactile-zoo[export]"): TorchScript only')
    opset, ort_version = "", ""
    if with_onnx:
        import onnxruntime

        ort_version = onnxruntime.__version__
    names = [n for n in (models or model_names()) if get_model_entry(n).meta.get("streaming")]
    note = _load_note()
    rows = []
    with ctx.threads_scope(1), tempfile.TemporaryDirectory() as tmp:
        for name in names:
            seed_everything(0)
            model = instantiate_model(name, test.spec).eval()
            result = export_model(model, Path(tmp) / name, name=name, spec=test.spec, batch=1, forward=False,
                                  formats=("torchscript", "onnx") if with_onnx else ("torchscript",))
            opset = result.manifest["exporters"].get("onnx_opset", "") or ""
            runs = _streamers(model, result, with_onnx)
            order = list(runs)
            for fn in runs.values():  # warm-up: allocator, lazy initialisation, onnxruntime's first run
                fn(frames[:min(len(frames), 10)])
            times: dict[str, tuple[list[float], list[float]]] = {r: ([], []) for r in order}
            scores: dict[str, torch.Tensor] = {}
            passes = ctx.reps(3, 1)
            for p in range(passes):
                for r in order[p % len(order):] + order[:p % len(order)]:
                    wall, cpu, scores[r] = runs[r](frames)
                    times[r][0].extend(wall)
                    times[r][1].extend(cpu)
            eager_median = _median(times["eager"][0])
            for r in order:
                wall = sorted(times[r][0])
                rows.append({
                    "case": f"{name}_{r}", "model": name, "runtime": r, "data": data.source, "steps": len(frames),
                    "batch": 1, "median_ms": _median(wall) * 1e3, "p99_ms": wall[min(len(wall) - 1,
                                                                                      int(0.99 * len(wall)))] * 1e3,
                    "max_ms": wall[-1] * 1e3, "cpu_median_ms": _median(times[r][1]) * 1e3,
                    "eager_median_ms": eager_median * 1e3, "speedup_vs_eager": eager_median / _median(wall),
                    "max_abs_diff": float((scores[r] - scores["eager"]).abs().max()),
                    "state_tensors": len(result.manifest["step"]["state"]), "onnx_opset": opset if r ==
                    "onnxruntime" else "", "onnxruntime": ort_version if r == "onnxruntime" else "",
                    "repeats": passes, "threads": 1, "target": "well under 20 ms per frame; goal < 1 ms",
                    "note": note})
                ctx.log(f"  {name} {r}: median {_median(wall) * 1e3:.3f} ms per frame (p99 {rows[-1]['p99_ms']:.3f}, "
                        f"cpu {rows[-1]['cpu_median_ms']:.3f}), max |diff| vs eager {rows[-1]['max_abs_diff']:.2g}")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE"]
