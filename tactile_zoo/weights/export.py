"""Export to TorchScript and ONNX: every model's full forward and, for streaming models, one step with its state as
explicit tensors, so that a robot can run the model outside Python's training loop, one frame at a time.

Two graphs per model, each as TorchScript (``torch.jit.trace``, ``.pt``) and ONNX (``.onnx``)::

    MODEL.forward.{pt,onnx}   x (B, T, N, C) [, g (B, T, G)]                     -> scores (B, K)
    MODEL.step.{pt,onnx}      x_t (B, N, C) [, g_t (B, G)], state_in_0 .. state_in_{S-1}
                              -> scores (B, K), state_out_0 .. state_out_{S-1}
    MODEL.export.json         names, shapes, dtypes, the state tensors and their initial values, the dataset spec,
                              the preprocessing, and the checks against eager PyTorch

Names, as the ONNX graphs and the JSON file carry them:

- ``x``, ``g``: a whole recording, taxel readings and global features (``g`` only when the dataset has ``G > 0``);
- ``x_t``, ``g_t``: one frame of them;
- ``scores``: the class scores, logits for models trained with cross-entropy, output spike rates in [0, 1] for
  SGnet (``"scores"`` in the JSON file says which); after step k they equal the forward on the first k frames;
- ``state_in_i`` / ``state_out_i``: state tensor ``i``; ``state_out_i`` of one call is ``state_in_i`` of the next.
  Before the first frame each holds its initial value, ``"initial"`` in the JSON file (``0.0``, or ``"-inf"`` for
  X-Tacformer's running maximum of its frame scores; ``float()`` reads both), which :func:`initial_state` fills in.
  Its ``"path"`` says what it is in the model's own state: ``mems[0]`` (SGnet's first LIF membrane), ``count``
  (output spikes so far), ``core[...]`` (a binned model's state after its last complete bin: LIF membranes, spike
  sums, LSTM ``(h, c)``, ...), ``pending_x`` / ``pending_g`` (the sums of the frames of the bin being filled).

Python-side counters become tensors. SGnet's step count, a binned model's number of frames in its open bin
(``pending``) and Tacformer's count of bins are ``(B, 1)`` float32 tensors holding whole numbers (exact up to
2**24 frames), with ``"kind": "counter"``. The eager ``step()`` decides with a Python ``if`` when a bin is complete;
the exported step computes both outcomes' states and picks one per row with ``torch.where``, which gives the same
numbers and makes every row of the batch its own stream: to start a new grasp in row i, reset row i of every state
tensor to its initial value (the batch dimension of each is ``"batch_dim"`` in the JSON file).

Shapes are fixed at export: the batch size (``batch``, default 1) and, for the forward, the number of steps
(``steps``, default the spec's ``num_steps``). Tracing records the Python arithmetic on shapes as constants (how
many bins the frames make, the loops over frames, unrolled), so another shape needs another export.

Exporters. Both formats are traced from a copy of the model whose LIF layers are written with plain tensor
operations (``_PlainLIF``: the fused loop's numbers bit for bit, in a graph a fraction of the size). TorchScript
files come from ``torch.jit.trace`` and compute what eager PyTorch computes, bit for bit (tested for every model).
ONNX files come from ``torch.onnx.export(..., dynamo=True)``, the exporter built on :func:`torch.export.export` (it
needs ``onnxscript``: ``pip install "tactile-zoo[export]"``); the step's graph is optimised, the forward's (unrolled
over all T frames, where the optimiser's cost outgrows the graph) is left to onnxruntime's optimisation at load.
The older TorchScript-based exporter (``dynamo=False``) got four of the six forwards wrong when tried on the models
as they are: the fused LIF and ConvLSTM loops write into preallocated buffers with ``out=`` kernels, which it
dropped, leaving graphs whose output no longer depends on ``x`` (SGnet, ConvLSTM: onnxruntime rejects the input
as unused), and it exported the floor division that counts frame bins, ``-(-T // k)``, as a truncating one
(Tacformer, X-Tacformer: a negative padding length). The ``torch.export`` path functionalises such kernels and
keeps shape arithmetic as Python integers.

Every export is checked before it is reported: the files are loaded back and run on seeded inputs other than the
ones traced, the forward once and the step frame by frame over two bins and more, against the eager model (the
ONNX files under onnxruntime when it is installed). The largest differences go into the JSON file; beyond
:data:`TOLERANCE` the export fails with :class:`ExportError`.
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
import math
import os
import tempfile
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .. import registry
from .._files import atomic_write_text
from .._version import __version__
from ..errors import ConfigError, ExportError
from .graphs import ForwardGraph, StateTensor, StepGraph, _dtype_name, _for_export, _registry_key

__all__ = ["FORMATS", "EXPORT_FORMAT", "TOLERANCE", "ExportError", "StateTensor", "ForwardGraph", "StepGraph",
           "ExportResult", "export_model", "initial_state", "spec_for_dataset", "onnx_available",
           "onnxruntime_available", "onnx_opsets", "check_opset", "ONNX_INSTALL"]

#: The formats :func:`export_model` writes.
FORMATS = ("torchscript", "onnx")
#: The ``format`` of ``MODEL.export.json``.
EXPORT_FORMAT = "tactile-zoo-export/1"
#: Largest absolute difference (plus the same relative one) an export may show against eager PyTorch in its checks.
TOLERANCE = 1e-5
#: How to install what the ONNX export and its check need.
ONNX_INSTALL = 'pip install "tactile-zoo[export]"  (onnx, onnxscript, onnxruntime)'

_SUFFIX = {"torchscript": "pt", "onnx": "onnx"}


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


def onnx_available() -> bool:
    """Whether the ONNX exporter's dependencies (onnx, onnxscript) are installed."""
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in ("onnx", "onnxscript"))


def onnxruntime_available() -> bool:
    """Whether onnxruntime (the check of the ONNX files) is installed."""
    import importlib.util

    return importlib.util.find_spec("onnxruntime") is not None


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
    for name in registry.list_models():
        if registry.get_model_entry(name).obj is type(model):
            return name.rpartition(":")[2]
    return type(model).__name__


#: The loggers the exporters talk through. What they say goes to tactile-zoo's debug log (``-v``), never straight to
#: stderr: the ONNX version converter, for one, logs a whole traceback when it cannot convert and then carries on.
_EXPORTER_LOGGERS = ("torch.onnx", "torch.export", "torch._export", "onnxscript", "onnx_ir", "onnx")
logger = logging.getLogger(__name__)


class _Collect(logging.Handler):
    """Keeps the records' text, logged once the streams are restored (logging them at once would write into the
    redirected stderr)."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if record.exc_info:
            text += "\n" + logging.Formatter().formatException(record.exc_info)
        self.lines.append(f"{record.name}: {text}")


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Keep the exporters' chatter off the user's terminal: torch.jit's deprecation and tracer warnings (every export
    is checked against eager on other inputs instead), the progress lines the ONNX exporter prints, and the log
    records of the exporters and the version converter, all moved to the debug log."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    handler = _Collect()
    saved = []
    for name in _EXPORTER_LOGGERS:
        other = logging.getLogger(name)
        saved.append((other, other.handlers[:], other.propagate))
        other.handlers[:] = [handler]
        other.propagate = False  # not to the root logger's handlers, nor to logging.lastResort (stderr)
    out, err = io.StringIO(), io.StringIO()
    try:
        with warnings.catch_warnings(record=True) as caught, redirect_stdout(out), redirect_stderr(err):
            warnings.simplefilter("always")
            yield
    finally:
        for other, handlers, propagate in saved:
            other.handlers[:] = handlers
            other.propagate = propagate
        for line in handler.lines:
            logger.debug("%s", line)
        for w in caught:
            logger.debug("exporter warning: %s: %s", w.category.__name__, w.message)
        for stream, text in (("stdout", out.getvalue()), ("stderr", err.getvalue())):
            if text.strip():
                logger.debug("exporter %s:\n%s", stream, text.rstrip())


def _example(spec: Any, batch: int, steps: int | None, seed: int, dtype: torch.dtype) -> tuple[Tensor, Tensor | None]:
    """Seeded inputs ``x (B, T, N, C)`` in [0, 1) and ``g (B, T, G)`` (``None`` without globals)."""
    gen = torch.Generator().manual_seed(seed)
    t = spec.num_steps if steps is None else steps
    x = torch.rand(batch, t, spec.num_nodes, spec.num_channels, generator=gen, dtype=dtype)
    g = torch.rand(batch, t, spec.num_globals, generator=gen, dtype=dtype) if spec.num_globals else None
    return x, g


def _trace(graph: nn.Module, inputs: tuple[Tensor, ...]) -> torch.jit.ScriptModule:
    with _quiet():
        return torch.jit.trace(graph, inputs, check_trace=False)


def onnx_opsets() -> tuple[int, int]:
    """The ONNX opsets :func:`export_model` writes: from the one torch's exporter writes natively (18) to the newest
    the installed ``onnx`` knows. Older ones are attempted through onnx's version converter and refused when it
    cannot convert the graph."""
    import onnx

    try:
        from torch.onnx._internal.exporter._constants import TORCHLIB_OPSET as native
    except ImportError:  # a torch that moved it: the value of torch 2.x
        native = 18
    return int(native), int(onnx.defs.onnx_opset_version())


#: The oldest opset the version converter is asked for at all (torch's legacy exporter's minimum).
_OLDEST_OPSET = 7


def check_opset(opset: int | None, what: str = "ONNX opset") -> None:
    """Refuse, before any work, an opset no exporter here can write (``what`` names it in the message)."""
    if opset is None:
        return
    lo, hi = onnx_opsets()
    if isinstance(opset, bool) or not isinstance(opset, int) or not _OLDEST_OPSET <= opset <= hi:
        raise ConfigError(f"{what} {opset!r} is not supported: choose {lo} to {hi} (older ones down to "
                          f"{_OLDEST_OPSET} only where onnx's version converter can convert the graph)")


def _to_onnx(graph: nn.Module, inputs: tuple[Tensor, ...], path: Path, opset: int | None, optimize: bool) -> None:
    if not onnx_available():
        raise ExportError(f"ONNX export needs onnx and onnxscript: {ONNX_INSTALL}")
    try:
        with _quiet():
            torch.onnx.export(graph, inputs, str(path), dynamo=True, input_names=graph.input_names,
                              output_names=graph.output_names, external_data=False, opset_version=opset,
                              optimize=optimize, verbose=False)
    except Exception as exc:  # noqa: BLE001 - the exporter raises many types; the message says which model and why
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ExportError(f"ONNX export of {path.name} failed: {type(exc).__name__}: {first}") from exc
    if opset is not None:
        # the exporter writes opset 18 and converts; when the conversion fails it logs and keeps 18 (or whatever it
        # reached): a file that does not carry the opset asked for is removed and refused, not shipped to a robot
        # whose onnxruntime cannot load it
        got = _opset_of(path)
        if got != opset:
            path.unlink(missing_ok=True)
            lo, hi = onnx_opsets()
            raise ExportError(f"ONNX export of {path.name} at opset {opset} failed: onnx's version converter could "
                              f"not convert the graph (it stayed at opset {got}); supported opsets are {lo} to {hi}")


def _onnx_runner(path: Path) -> Callable[..., list[Tensor]]:
    """A function running an ONNX file under onnxruntime on one CPU thread, tensors in and out."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]

    def run(*inputs: Tensor) -> list[Tensor]:
        feeds = {n: v.detach().cpu().numpy() for n, v in zip(names, inputs)}
        return [torch.from_numpy(o) for o in session.run(None, feeds)]

    return run


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
                 info: Mapping[str, Any] | None = None) -> ExportResult:
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
    name = name or _registered_name(model)
    key = _registry_key(name)
    try:
        meta = dict(registry.get_model_entry(name).meta)
    except registry.UnknownNameError:
        meta = dict(getattr(model, "zoo_meta", None) or {})
    streams = bool(meta.get("streaming")) and callable(getattr(model, "step", None))
    # the reference every check compares with, a CPU copy in eval mode (the caller's model is left as it is), and
    # the copy that is traced, whose LIF layers compute the same numbers with plain operations
    eager = copy.deepcopy(model).cpu().eval()
    for p in eager.parameters():
        p.requires_grad_(False)
    traced_model = _for_export(eager)
    dtype = next((p.dtype for p in eager.parameters()), torch.float32)
    if "onnx" in formats and not onnx_available():  # before any work
        raise ExportError(f"ONNX export needs onnx and onnxscript: {ONNX_INSTALL}")
    if "onnx" in formats:
        check_opset(opset)

    if not forward and not (step and streams):
        raise ConfigError(f"nothing to export: forward=False, and {name} has no streaming step to export")
    full, full_ref = ForwardGraph(traced_model, spec), ForwardGraph(eager, spec)
    x, g = _example(spec, batch, steps, seed, dtype)
    fwd_inputs = (x,) if g is None else (x, g)
    x2, g2 = _example(spec, batch, steps, seed + 1, dtype)  # checks run on other inputs than the traced ones
    check_inputs = (x2,) if g2 is None else (x2, g2)
    graphs: list[tuple[str, nn.Module, tuple[Tensor, ...]]] = [("forward", full, fwd_inputs)] if forward else []
    stepper = None
    if step and streams:
        stepper, stepper_ref = StepGraph(traced_model, spec, batch, key), StepGraph(eager, spec, batch, key)
        extra = () if g is None else (g[:, 0],)
        graphs.append(("step", stepper, (x[:, 0], *extra, *stepper.initial_state())))

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
                                  f"arithmetic (see tactile_zoo.weights.export)")
    folder = Path(out)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the export folder {folder}: {exc.strerror or exc}") from None
    try:  # an existing read-only folder: say so now, not through torch's message about a file inside it
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise ConfigError(f"the export folder {folder} is not writable ({exc.strerror or exc})") from None
    with torch.no_grad():
        full(*fwd_inputs)  # one eager call first: fills the models' caches, which tracing then reads as constants
        for graph_name, graph, inputs in graphs:
            for fmt in formats:
                path = folder / f"{name}.{graph_name}.{_SUFFIX[fmt]}"
                if fmt == "torchscript":
                    try:
                        traced = _trace(graph, inputs)
                        torch.jit.save(traced, str(path))
                    except Exception as exc:  # noqa: BLE001 - as for ONNX: say which file and why, in one line
                        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                        raise ExportError(f"TorchScript export of {path.name} failed: {type(exc).__name__}: "
                                          f"{first}") from exc
                else:
                    # the forward is unrolled over all T frames, and the exporter's optimiser (rewrite rules matched
                    # at every node) costs more than the graph grows: SGnet on Ev-Objects, 250 frames, took 500
                    # CPU-s with it, 50 without; onnxruntime optimises the graph when it loads it anyway. The step,
                    # small and the one a robot runs per frame, is optimised.
                    _to_onnx(graph, inputs, path, opset, optimize=graph_name == "step")
                files[(fmt, graph_name)] = path
                if not check:
                    continue
                if fmt == "onnx" and not onnxruntime_available():
                    checks[f"{fmt}.{graph_name}"] = {"ok": None, "skipped": f"onnxruntime is not installed "
                                                                           f"({ONNX_INSTALL})"}
                    continue
                run = torch.jit.load(str(path)) if fmt == "torchscript" else _onnx_runner(path)
                if graph_name == "forward":
                    result = _check_forward(run, full_ref, check_inputs)
                else:
                    result = _check_step(run, stepper_ref, frames, globs)
                checks[f"{fmt}.{graph_name}"] = result
                if not result["ok"]:
                    raise ExportError(f"{path.name} does not reproduce the eager model: {result} (tolerance "
                                      f"{TOLERANCE}); please report this")

    manifest = _describe(name, spec, meta, eager, files, checks, full, fwd_inputs, stepper, graphs, info)
    manifest_path = folder / f"{name}.export.json"
    atomic_write_text(manifest_path, json.dumps(manifest, indent=2) + "\n")
    return ExportResult(files, manifest, manifest_path)


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
        desc["exporters"]["onnx_opset"] = _opset_of(onnx_file)
    return desc


def _opset_of(path: Path) -> int | None:
    try:
        import onnx

        model = onnx.load(str(path), load_external_data=False)
        return next((int(o.version) for o in model.opset_import if o.domain in ("", "ai.onnx")), None)
    except Exception:  # noqa: BLE001 - the opset is informative; a file onnx cannot read was already checked
        return None
