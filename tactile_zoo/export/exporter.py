"""``export_model``: trace a model's forward and streaming step, write them as TorchScript and ONNX, load them back
and check them against eager PyTorch, and describe them in ``MODEL.export.json`` (see :mod:`tactile_zoo.export`)."""

from __future__ import annotations

import copy
import io
import json
import math
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .. import registry
from .._files import atomic_write_text
from .._signals import terminate_as_interrupt
from .._version import __version__
from ..engine.progress import Progress
from ..errors import ConfigError, ExportError
from .folder import _SUFFIX, ExportFolder, export_targets, write_file
from .graphs import ForwardGraph, StepGraph, _dtype_name, _for_export, _registry_key
from .onnx_io import (
    ONNX_INSTALL,
    check_opset,
    onnx_available,
    onnx_opsets,
    onnx_runner,
    onnxruntime_available,
    opset_of,
    quiet,
    to_onnx,
)

__all__ = ["FORMATS", "EXPORT_FORMAT", "TOLERANCE", "MAX_STEPS", "MAX_INPUT_BYTES", "ExportResult", "export_model",
           "check_shape", "check_steps", "initial_state", "spec_for_dataset"]

#: The formats :func:`export_model` writes.
FORMATS = ("torchscript", "onnx")
#: The ``format`` of ``MODEL.export.json``.
EXPORT_FORMAT = "tactile-zoo-export/1"
#: Largest absolute difference (plus the same relative one) an export may show against eager PyTorch in its checks.
TOLERANCE = 1e-5

#: The most frames (``steps``) a forward is exported for. The forward is unrolled over every frame, so its graph and
#: its export time grow with them (Ev-Objects' 250 frames: 20-35 s); every dataset here has at most 325. A longer
#: stream is what the step (one frame, any number of times) is for.
MAX_STEPS = 4096
#: The largest example input ``x`` (bytes, ``batch * steps * (N * C + G)`` values) an export builds: beyond it the
#: export would exhaust memory before writing anything.
MAX_INPUT_BYTES = 2**30
#: Frames of the short forward traced first to learn whether onnx's version converter can convert the graph to an
#: older opset (the converter's verdict depends on the operators, not on how many frames are unrolled).
_PROBE_STEPS = 4


def check_steps(steps: int | None, what: str = "export steps") -> None:
    """Refuse ``steps`` above :data:`MAX_STEPS` (``what`` names the argument in the message, e.g. ``--steps``)."""
    if steps is not None and steps > MAX_STEPS:
        raise ConfigError(f"{what} {steps} is above the cap of {MAX_STEPS} frames: the forward is unrolled over every "
                          f"frame (its graph and export time grow with them); for longer streams export the step, "
                          f"which takes one frame at a time")


def check_shape(spec: Any, batch: int, steps: int | None) -> None:
    """Refuse, before any work, ``steps`` above :data:`MAX_STEPS` and an example input above
    :data:`MAX_INPUT_BYTES` (it would exhaust memory before anything is written)."""
    check_steps(steps)
    t = spec.num_steps if steps is None else steps
    values = spec.num_nodes * spec.num_channels + spec.num_globals
    size = batch * t * values * 4
    if size > MAX_INPUT_BYTES:
        raise ConfigError(f"export batch {batch} x steps {t} needs an example input of {size / 2**30:.1f} GiB "
                          f"({values} float32 values per frame), above the {MAX_INPUT_BYTES // 2**30} GiB an export "
                          f"allows; lower the batch or the steps")


def initial_state(manifest: Mapping[str, Any] | str | os.PathLike) -> list[Tensor]:
    """The state tensors before the first frame, from an export's JSON file (a path or its parsed dict).

    Example::

        step = torch.jit.load("out/sgnet.step.pt")
        state = initial_state("out/sgnet.export.json")
        for x_t in frames:                        # (1, N, C) each
            scores, *state = step(x_t, *state)
    """
    if not isinstance(manifest, Mapping):
        manifest = json.loads(Path(manifest).read_text())
    step = manifest.get("step")
    if not step:
        raise ExportError(f"export of {manifest.get('model')!r} has no step (the model does not stream, or it was "
                          f"exported with --no-step)")
    return [torch.full(tuple(s["shape"]), float(s["initial"]), dtype=getattr(torch, s["dtype"]))
            for s in step["state"]]


# ------------------------------------------------------------------------------------------------- the export
@dataclass
class ExportResult:
    """What :func:`export_model` wrote: ``files`` (format and graph -> path, e.g. ``("onnx", "step")``), the JSON
    description (``manifest``, also at ``manifest_path``)."""

    files: dict[tuple[str, str], Path]
    manifest: dict[str, Any]
    manifest_path: Path


def spec_for_dataset(name: str, root: str | os.PathLike | None = None) -> Any:
    """The :class:`~tactile_zoo.data.spec.DatasetSpec` of a registered dataset with its default options: from its
    registry metadata when that lists the whole spec (every built-in dataset: no data needed), else from its
    ``train`` split under ``root``."""
    from ..data.spec import DatasetSpec

    entry = registry.get_dataset_entry(name)
    meta = dict(entry.meta)
    keys = ("sensor", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals")
    if all(meta.get(k) is not None for k in keys):
        return DatasetSpec(entry.qualified_name.rpartition(":")[2], int(meta["num_classes"]),
                           tuple(str(c) for c in meta["class_names"]), int(meta["num_steps"]), int(meta["num_nodes"]),
                           int(meta["num_channels"]), int(meta["num_globals"]), registry.get_sensor(meta["sensor"]))
    return registry.load_dataset(name, root=root, split="train").spec


def _registered_name(model: nn.Module) -> str:
    for name in registry.model_names():
        if registry.get_model_entry(name).obj is type(model):
            return name.rpartition(":")[2]
    return type(model).__name__


def _example(spec: Any, batch: int, steps: int | None, seed: int, dtype: torch.dtype) -> tuple[Tensor, Tensor | None]:
    """Seeded inputs ``x (B, T, N, C)`` in [0, 1) and ``g (B, T, G)`` (``None`` without globals)."""
    gen = torch.Generator().manual_seed(seed)
    t = spec.num_steps if steps is None else steps
    x = torch.rand(batch, t, spec.num_nodes, spec.num_channels, generator=gen, dtype=dtype)
    g = torch.rand(batch, t, spec.num_globals, generator=gen, dtype=dtype) if spec.num_globals else None
    return x, g


def _trace(graph: nn.Module, inputs: tuple[Tensor, ...]) -> torch.jit.ScriptModule:
    with quiet():
        return torch.jit.trace(graph, inputs, check_trace=False)


def _diff(a: Tensor, b: Tensor) -> float:
    """Largest absolute difference, ``inf`` for a shape mismatch or a NaN on one side only."""
    if tuple(a.shape) != tuple(b.shape):
        return math.inf
    a, b = a.double(), b.double()
    if bool((a.isnan() != b.isnan()).any()):
        return math.inf
    both = ~(a.isnan() | (a == b))  # equal entries (infinities included) count 0
    return float((a - b)[both].abs().max()) if bool(both.any()) else 0.0


def _check_forward(run: Callable[..., Any], eager: nn.Module, inputs: tuple[Tensor, ...]) -> dict[str, Any]:
    with torch.no_grad():
        want = eager(*inputs)
        got = run(*inputs)
    got = got[0] if isinstance(got, list | tuple) else got
    diff = _diff(got, want)
    return {"scores_max_abs_diff": diff, "ok": diff <= TOLERANCE * (1 + float(want.abs().max()))}


def _check_step(run: Callable[..., Any], eager: StepGraph, frames: Tensor, globs: Tensor | None) -> dict[str, Any]:
    """Run the exported step and the eager one (through the same flat state) frame by frame from the initial
    state; the largest differences of the scores and of the state tensors over all frames."""
    state_e = state_r = eager.initial_state()
    score_diff = state_diff = 0.0
    worst = 0.0
    with torch.no_grad():
        for t in range(frames.shape[1]):
            extra = () if globs is None else (globs[:, t],)
            out_e = eager(frames[:, t], *extra, *state_e)
            out_r = list(run(frames[:, t], *extra, *state_r))
            score_diff = max(score_diff, _diff(out_r[0], out_e[0]))
            worst = max(worst, float(out_e[0].abs().max()))
            state_diff = max([state_diff, *(_diff(a, b) for a, b in zip(out_r[1:], out_e[1:]))])
            state_e, state_r = tuple(out_e[1:]), tuple(out_r[1:])
    ok = score_diff <= TOLERANCE * (1 + worst) and state_diff <= TOLERANCE * (1 + worst)
    return {"frames": int(frames.shape[1]), "scores_max_abs_diff": score_diff, "state_max_abs_diff": state_diff,
            "ok": ok}


def _check_flat_step(model: nn.Module, flat: StepGraph, frames: Tensor, globs: Tensor | None) -> dict[str, Any]:
    """The flat-state step (what is traced) against the model's own ``step()`` from ``init_state``, frame by frame:
    a model whose step keeps Python-side state the flat state cannot carry (a number steering an ``if``) differs."""
    state, own = flat.initial_state(), model.init_state(frames.shape[0])
    diff = worst = 0.0
    with torch.no_grad():
        for t in range(frames.shape[1]):
            g_t = None if globs is None else globs[:, t]
            want, own = model.step(frames[:, t], g_t, own)
            out = flat(frames[:, t], *(() if g_t is None else (g_t,)), *state)
            diff, worst = max(diff, _diff(out[0], want)), max(worst, float(want.abs().max()))
            state = tuple(out[1:])
    return {"frames": int(frames.shape[1]), "scores_max_abs_diff": diff, "ok": diff <= TOLERANCE * (1 + worst)}


def _score_kind(model: nn.Module) -> str:
    from ..engine.evaluate import model_loss

    return "spike_rates" if model_loss(model) == "mse_rate" else "logits"


def _io(names: Sequence[str], values: Sequence[Tensor]) -> list[dict[str, Any]]:
    return [{"name": n, "shape": list(v.shape), "dtype": _dtype_name(v.dtype)} for n, v in zip(names, values)]


def export_model(model: nn.Module, out: str | os.PathLike, *, name: str | None = None, spec: Any = None,
                 formats: Sequence[str] = FORMATS, batch: int = 1, steps: int | None = None, step: bool = True,
                 forward: bool = True, check: bool = True, seed: int = 0, opset: int | None = None,
                 info: Mapping[str, Any] | None = None, progress: bool = True) -> ExportResult:
    """Write TorchScript and ONNX files of ``model``'s forward and, when it streams, of its step (module docstring),
    check them against the eager model, and describe them in ``<out>/<name>.export.json``.

    Args:
        model: a model of the zoo (or a plugin's), e.g. from :func:`tactile_zoo.create_model`; a CPU copy in eval
            mode is exported, the model itself is not changed.
        out: the folder to write to (created).
        name: the file stem and registry name (default: the registry name of the model's class).
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` it was built for (default ``model.spec``).
        formats: any of :data:`FORMATS`.
        batch: the batch size of both graphs.
        steps: the number of frames of the forward's input (default ``spec.num_steps``).
        step: also export the streaming step (only for models registered with ``streaming=True``).
        forward: export the forward (``False``: the step alone, e.g. to time it; the JSON file then describes no
            forward files).
        check: load the files back and compare them with the eager model on seeded inputs (ONNX: when onnxruntime
            is installed); a difference beyond :data:`TOLERANCE` raises :class:`ExportError`.
        seed: seed of the example and check inputs.
        opset: the ONNX opset (default: the exporter's); :func:`onnx_opsets` gives the range. The file carries it,
            or :class:`ExportError` is raised (the version converter could not convert the graph).
        info: extra JSON-able keys for the description (the weights, the preprocessing, ...).
        progress: report the files (a bar on a terminal, log records otherwise:
            :mod:`tactile_zoo.engine.progress`); ``False``: nothing.

    ``out`` follows the output-folder rule (:mod:`tactile_zoo.export.folder`): a folder holding files but no
    export marker is refused, and the model's files replace its previous export there as one set; one export at a
    time writes into a folder (a second waits), and a full disk, SIGTERM or Ctrl-C leave the folder as it was.

    Returns:
        an :class:`ExportResult`.
    """
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise ConfigError(f"export formats must be among {', '.join(FORMATS)}, got {', '.join(formats) or 'none'}")
    for what, value in (("batch", batch), ("steps", steps)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ConfigError(f"export {what} must be a positive integer, got {value!r}")
    spec = spec if spec is not None else getattr(model, "spec", None)
    if spec is None:
        raise ConfigError("export_model: pass the spec the model was built for (the model has no .spec)")
    check_shape(spec, batch, steps)
    name = name or _registered_name(model)
    key = _registry_key(name)
    try:
        meta = dict(registry.get_model_entry(name).meta)
    except registry.UnknownNameError:
        meta = dict(getattr(model, "zoo_meta", None) or {})
    streams = bool(meta.get("streaming")) and callable(getattr(model, "step", None))
    if "onnx" in formats and not onnx_available():  # before any work
        raise ExportError(f"ONNX export needs onnx and onnxscript: {ONNX_INSTALL}")
    if "onnx" in formats:
        check_opset(opset)
    if not forward and not (step and streams):
        raise ConfigError(f"nothing to export: forward=False, and {name} has no streaming step to export")
    folder, targets = ExportFolder(out), export_targets(name, formats, forward, step and streams)
    folder.check(targets)  # before any work: whose folder is it
    with terminate_as_interrupt(), folder.locked():
        folder.check(targets)  # again holding the lock: an export we waited for may have changed the folder
        folder.remove_stale()  # a killed export's staging folder: no live export has one while we hold the lock
        try:
            return _export(model, folder, name, key, spec, meta, streams, formats, batch, steps, step, forward,
                           check, seed, opset, info, progress)
        except OSError as exc:  # a full disk: one line naming the file, and the folder as it was
            folder.abort()
            raise folder.write_error(exc) from exc
        except BaseException:
            folder.abort()  # the folder as it was: no staging folder, and no new folder of its own
            raise


def _export(model: nn.Module, folder: ExportFolder, name: str, key: str, spec: Any, meta: dict[str, Any],
            streams: bool, formats: Sequence[str], batch: int, steps: int | None, step: bool, forward: bool,
            check: bool, seed: int, opset: int | None, info: Mapping[str, Any] | None, progress: bool) -> ExportResult:
    """:func:`export_model` once its arguments and its folder are checked."""
    # the reference every check compares with, a CPU copy in eval mode (the caller's model is left as it is), and
    # the copy that is traced, whose LIF layers compute the same numbers with plain operations
    eager = copy.deepcopy(model).cpu().eval()
    for p in eager.parameters():
        p.requires_grad_(False)
    traced_model = _for_export(eager)
    dtype = next((p.dtype for p in eager.parameters()), torch.float32)
    full, full_ref = ForwardGraph(traced_model, spec), ForwardGraph(eager, spec)
    x, g = _example(spec, batch, steps, seed, dtype)
    fwd_inputs = (x,) if g is None else (x, g)
    x2, g2 = _example(spec, batch, steps, seed + 1, dtype)  # checks run on other inputs than the traced ones
    check_inputs = (x2,) if g2 is None else (x2, g2)
    graphs: list[tuple[str, nn.Module, tuple[Tensor, ...]]] = [("forward", full, fwd_inputs)] if forward else []
    stepper = stepper_ref = frames = globs = None
    if step and streams:
        stepper, stepper_ref = StepGraph(traced_model, spec, batch, key), StepGraph(eager, spec, batch, key)
        extra = () if g is None else (g[:, 0],)
        graphs.append(("step", stepper, (x[:, 0], *extra, *stepper.initial_state())))
    if "onnx" in formats and opset is not None and opset < onnx_opsets()[0]:
        _probe_opset(graphs, eager, name, spec, batch, steps, seed, dtype, opset)

    files: dict[tuple[str, str], Path] = {}
    checks: dict[str, Any] = {}
    if stepper is not None:  # frames for the step's checks: two bins and more, from inputs other than the traced
        span = max(2 * stepper.bin_size + 1, 4)
        frames = x2[:, :span] if x2.shape[1] >= span else _example(spec, batch, span, seed + 1, dtype)[0]
        globs = None if g2 is None else _example(spec, batch, frames.shape[1], seed + 2, dtype)[1]
        if check:
            checks["eager.step"] = _check_flat_step(eager, stepper_ref, frames, globs)
            if not checks["eager.step"]["ok"]:
                raise ExportError(f"{name}: the step with its state as tensors does not reproduce {name}.step() "
                                  f"({checks['eager.step']}); its state must be tensors and numbers that only enter "
                                  f"arithmetic (see tactile_zoo.export)")
    staging = folder.stage()
    with Progress(len(graphs) * len(formats), f"export {name}", "files", enabled=progress) as bar:
        _write(graphs, formats, name, staging, opset, check, full, full_ref, fwd_inputs, check_inputs, stepper_ref,
               frames, globs, files, checks, bar)
    manifest = _describe(name, spec, meta, eager, files, checks, full, fwd_inputs, stepper, graphs, info)
    manifest_path = staging / f"{name}.export.json"
    atomic_write_text(manifest_path, json.dumps(manifest, indent=2) + "\n")
    folder.commit(name, [*(p.name for p in files.values()), manifest_path.name])
    return ExportResult({k: folder.path / p.name for k, p in files.items()}, manifest,
                        folder.path / manifest_path.name)


def _probe_opset(graphs: list[tuple[str, nn.Module, tuple[Tensor, ...]]], eager: nn.Module, name: str, spec: Any,
                 batch: int, steps: int | None, seed: int, dtype: torch.dtype, opset: int) -> None:
    """Before the long exports: whether onnx's version converter can bring each graph to the older ``opset``; the
    forward is tried short (:data:`_PROBE_STEPS` frames of a copy of the model: the same operators, a fraction of
    the export time), the step as it is. :class:`ExportError` (what the full export would raise, minutes later)
    when it cannot."""
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
        for graph_name, graph, inputs in graphs:
            if graph_name == "forward":
                t = min(_PROBE_STEPS, spec.num_steps if steps is None else steps)
                x, g = _example(spec, batch, t, seed, dtype)
                inputs = (x,) if g is None else (x, g)
                graph = ForwardGraph(_for_export(copy.deepcopy(eager)), spec)
                graph(*inputs)  # fills the copy's caches, as before the real export
            to_onnx(graph, inputs, Path(tmp) / f"{name}.{graph_name}.onnx", opset, optimize=graph_name == "step")


def _write(graphs: list[tuple[str, nn.Module, tuple[Tensor, ...]]], formats: Sequence[str], name: str, folder: Path,
           opset: int | None, check: bool, full: ForwardGraph, full_ref: ForwardGraph, fwd_inputs: tuple[Tensor, ...],
           check_inputs: tuple[Tensor, ...], stepper_ref: StepGraph | None, frames: Tensor | None,
           globs: Tensor | None, files: dict[tuple[str, str], Path], checks: dict[str, Any], bar: Progress) -> None:
    """Trace and write every graph in every format into ``folder``, load each file back and check it."""
    with torch.no_grad():
        full(*fwd_inputs)  # one eager call first: fills the models' caches, which tracing then reads as constants
        for graph_name, graph, inputs in graphs:
            for fmt in formats:
                path = folder / f"{name}.{graph_name}.{_SUFFIX[fmt]}"
                bar.update(0, f"writing {path.name}")
                if fmt == "torchscript":
                    try:  # into memory: torch writing to a full disk aborts the process (folder.py)
                        torch.jit.save(_trace(graph, inputs), buffer := io.BytesIO())
                    except Exception as exc:  # noqa: BLE001 - as for ONNX: say which file and why, in one line
                        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                        raise ExportError(f"TorchScript export of {path.name} failed: {type(exc).__name__}: "
                                          f"{first}") from exc
                    write_file(path, buffer.getvalue())
                else:
                    # the forward is unrolled over all T frames, and the exporter's optimiser (rewrite rules matched
                    # at every node) costs more than the graph grows: SGnet on Ev-Objects, 250 frames, took 500
                    # CPU-s with it, 50 without; onnxruntime optimises the graph when it loads it anyway. The step,
                    # small and the one a robot runs per frame, is optimised.
                    try:
                        to_onnx(graph, inputs, path, opset, optimize=graph_name == "step")
                    except ExportError as exc:
                        if isinstance(exc.__cause__, OSError):  # a full disk: said as for any file
                            raise OSError(exc.__cause__.errno, exc.__cause__.strerror, str(path)) from exc
                        raise
                files[(fmt, graph_name)] = path
                if check:
                    _check_file(fmt, graph_name, path, full_ref, check_inputs, stepper_ref, frames, globs, checks)
                bar.update(1, f"{path.name} {'checked' if check else 'written'}")


def _check_file(fmt: str, graph_name: str, path: Path, full_ref: ForwardGraph, check_inputs: tuple[Tensor, ...],
                stepper_ref: StepGraph | None, frames: Tensor | None, globs: Tensor | None,
                checks: dict[str, Any]) -> None:
    if fmt == "onnx" and not onnxruntime_available():
        checks[f"{fmt}.{graph_name}"] = {"ok": None, "skipped": f"onnxruntime is not installed ({ONNX_INSTALL})"}
        return
    run = torch.jit.load(str(path)) if fmt == "torchscript" else onnx_runner(path)
    if graph_name == "forward":
        result = _check_forward(run, full_ref, check_inputs)
    else:
        assert stepper_ref is not None and frames is not None
        result = _check_step(run, stepper_ref, frames, globs)
    checks[f"{fmt}.{graph_name}"] = result
    if not result["ok"]:
        raise ExportError(f"{path.name} does not reproduce the eager model: {result} (tolerance {TOLERANCE}); please "
                          f"report this")


def _describe(name: str, spec: Any, meta: Mapping[str, Any], eager: nn.Module, files: dict[tuple[str, str], Path],
              checks: dict[str, Any], forward: ForwardGraph, fwd_inputs: tuple[Tensor, ...],
              stepper: StepGraph | None, graphs: list[tuple[str, nn.Module, tuple[Tensor, ...]]],
              info: Mapping[str, Any] | None) -> dict[str, Any]:
    """The JSON description of an export (module docstring)."""
    with torch.no_grad():
        scores = forward(*fwd_inputs)
    k = int(scores.shape[-1])
    batch = int(scores.shape[0])
    desc: dict[str, Any] = {
        "format": EXPORT_FORMAT, "model": name, "revision": meta.get("revision"), "scores": _score_kind(eager),
        "spec": spec.to_dict(), **(dict(info) if info else {}),
        "forward": {"inputs": _io(forward.input_names, fwd_inputs),
                    "outputs": [{"name": "scores", "shape": [batch, k], "dtype": _dtype_name(scores.dtype)}],
                    "files": {fmt: p.name for (fmt, graph), p in files.items() if graph == "forward"}}
        if any(n == "forward" for n, _, _ in graphs) else None,
        "step": None,
        "exporters": {"torchscript": f"torch.jit.trace (torch {torch.__version__})",
                      "onnx": f"torch.onnx.export(dynamo=True) (torch {torch.__version__})"},
        "checks": {"tolerance": TOLERANCE, **checks},
        "tactile_zoo": __version__,
    }
    if stepper is not None:
        inputs = next(i for n, _, i in graphs if n == "step")
        desc["step"] = {
            "inputs": _io(stepper.input_names[:1 + bool(stepper.num_globals)], inputs)
            + [{"name": s.input_name, "shape": list(s.shape), "dtype": s.dtype} for s in stepper.states],
            "outputs": [{"name": "scores", "shape": [batch, k], "dtype": _dtype_name(scores.dtype)}]
            + [{"name": s.output_name, "shape": list(s.shape), "dtype": s.dtype} for s in stepper.states],
            "state": [s.to_dict() for s in stepper.states],
            "bin_size": stepper.bin_size,
            "files": {fmt: p.name for (fmt, graph), p in files.items() if graph == "step"},
        }
    elif not meta.get("streaming"):
        desc["step_note"] = f"{name} does not stream (registered with streaming=False): only the forward is exported"
    else:
        desc["step_note"] = "the streaming step was not exported (--no-step, step=False)"
    onnx_file = next((p for (fmt, _), p in files.items() if fmt == "onnx"), None)
    if onnx_file is not None:
        desc["exporters"]["onnx_opset"] = opset_of(onnx_file)
    return desc
