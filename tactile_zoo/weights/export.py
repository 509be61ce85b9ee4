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
import dataclasses
import json
import math
import os
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .. import registry
from .._version import __version__
from ..errors import ConfigError, TactileZooError
from ..nn.lif import MultiStepLIF

__all__ = ["FORMATS", "EXPORT_FORMAT", "TOLERANCE", "ExportError", "StateTensor", "ForwardGraph", "StepGraph",
           "ExportResult", "export_model", "initial_state", "spec_for_dataset", "onnx_available",
           "onnxruntime_available", "ONNX_INSTALL"]

#: The formats :func:`export_model` writes.
FORMATS = ("torchscript", "onnx")
#: The ``format`` of ``MODEL.export.json``.
EXPORT_FORMAT = "tactile-zoo-export/1"
#: Largest absolute difference (plus the same relative one) an export may show against eager PyTorch in its checks.
TOLERANCE = 1e-5
#: How to install what the ONNX export and its check need.
ONNX_INSTALL = 'pip install "tactile-zoo[export]"  (onnx, onnxscript, onnxruntime)'

_SUFFIX = {"torchscript": "pt", "onnx": "onnx"}
#: Initial values of state tensors that do not start at zero, by registry name and state path: X-Tacformer's online
#: softmax over frames keeps the running maximum of the scores seen so far, which starts at -inf (the identity of
#: max), so that the first bin gives exactly what the eager model computes from no state at all.
_INITIAL_VALUES: dict[str, dict[str, float]] = {"x_tacformer": {"core[1][1]": -math.inf}}


class ExportError(TactileZooError):
    """A model that cannot be exported as asked, or an export whose check against eager PyTorch failed."""


class _PlainLIF(MultiStepLIF):
    """:class:`~tactile_zoo.nn.lif.MultiStepLIF` written with plain tensor operations, what the exported graphs hold.

    The fused backend writes membranes into preallocated buffers, one block of steps at a time, with ``out=``
    kernels; ``torch.export`` functionalises every such write into a scatter, so an unrolled forward over a whole
    recording becomes a graph the ONNX optimiser needs minutes for (SGnet, 50 steps: 167 CPU-s against a few here).
    The same neuron, one comparison, one multiply and one add per step, rounds exactly as the fused kernels do:
    ``(beta * U) * (1 - R) + I`` with ``1 - R`` 0 or 1, so the only rounding is the product and the sum, in that
    order (``addcmul`` with ``value=beta``); the subtract reset rounds ``(beta * U + I) - R * U_thr`` the same way.
    Spikes are ``U > U_thr`` (the fused mask also leaves out ``U = +inf``, which a finite input never gives).
    """

    def forward(self, x: Tensor, mem: Tensor | None = None, return_mem: bool = False
                ) -> Tensor | tuple[Tensor, Tensor]:
        if mem is None:
            mem = x.new_zeros(x.shape[1:])
        if self.input_scale != 1.0:
            x = x * self.input_scale
        spikes = []
        for x_t in x.unbind(0):
            if self.reset == "subtract":
                fired = (mem > self.threshold).to(x.dtype)
                mem = (mem * self.beta + x_t) - fired * self.threshold
            else:
                keep = (mem <= self.threshold).to(x.dtype)  # 1 - R[t]
                mem = (mem * self.beta) * keep + x_t
            spikes.append((mem > self.threshold).to(x.dtype))
        out = torch.stack(spikes)
        return (out, mem) if return_mem else out


def _for_export(model: nn.Module) -> nn.Module:
    """A copy of ``model`` whose LIF layers are :class:`_PlainLIF` (same numbers, compact graphs)."""
    copied = copy.deepcopy(model)
    for module in copied.modules():
        if type(module) is MultiStepLIF:  # a subclass keeps its own forward
            module.__class__ = _PlainLIF
    return copied


# ---------------------------------------------------------------------------------------------- state as tensors
@dataclass(frozen=True)
class StateTensor:
    """One tensor of an exported step's state.

    Attributes:
        index: its position: inputs ``state_in_<index>``, outputs ``state_out_<index>``.
        path: where it sits in the model's own state (``mems[0]``, ``core[0][1]``, ``pending_x``, ...).
        shape: its shape at the exported batch size.
        dtype: ``"float32"`` (the model's dtype).
        initial: its value before the first frame (every entry the same).
        batch_dim: the dimension that indexes the batch (rows are independent streams).
        kind: ``"tensor"``, or ``"counter"`` for a Python number of the eager state (whole numbers).
    """

    index: int
    path: str
    shape: tuple[int, ...]
    dtype: str
    initial: float
    batch_dim: int
    kind: str = "tensor"

    @property
    def input_name(self) -> str:
        return f"state_in_{self.index}"

    @property
    def output_name(self) -> str:
        return f"state_out_{self.index}"

    def to_dict(self) -> dict[str, Any]:
        return {"name": f"state_{self.index}", "input": self.input_name, "output": self.output_name,
                "path": self.path, "shape": list(self.shape), "dtype": self.dtype,
                "initial": _json_number(self.initial), "batch_dim": self.batch_dim, "kind": self.kind}


def _json_number(value: float) -> float | str:
    """Finite floats as numbers, infinities as ``"inf"``/``"-inf"`` (strict JSON has none; ``float()`` reads them)."""
    return value if math.isfinite(value) else ("inf" if value > 0 else "-inf")


# A state's structure: ("tensor", slot) | ("number", slot) | ("none",) | ("seq", type, children) |
# ("map", keys, children) | ("data", class, field names, children)
_Def = tuple[Any, ...]


def _flatten(obj: Any, path: str, leaves: list[tuple[str, Any]]) -> _Def:
    """The structure of a model's state ``obj``; appends its tensors and numbers, with their paths, to ``leaves``."""
    if isinstance(obj, Tensor):
        leaves.append((path, obj))
        return ("tensor", len(leaves) - 1)
    if obj is None:
        return ("none",)
    if isinstance(obj, bool):  # a flag that steers the step: a tensor could not carry it through a traced graph
        raise ExportError(f"the streaming state holds a bool at {path or 'the top'}, which cannot become a tensor")
    if isinstance(obj, int | float):
        leaves.append((path, obj))
        return ("number", len(leaves) - 1)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        names = [f.name for f in dataclasses.fields(obj)]
        return ("data", type(obj), names,
                [_flatten(getattr(obj, n), f"{path}.{n}" if path else n, leaves) for n in names])
    if isinstance(obj, tuple | list):
        return ("seq", type(obj), [_flatten(v, f"{path}[{i}]", leaves) for i, v in enumerate(obj)])
    if isinstance(obj, Mapping) and all(isinstance(k, str) for k in obj):
        keys = list(obj)
        return ("map", keys, [_flatten(obj[k], f"{path}.{k}" if path else k, leaves) for k in keys])
    raise ExportError(f"the streaming state holds a {type(obj).__name__} at {path or 'the top'}; exportable states "
                      f"are tensors and numbers in tuples, lists, dicts and dataclasses")


def _unflatten(spec: _Def, values: Sequence[Any]) -> Any:
    """The state of structure ``spec`` with ``values`` in its slots."""
    kind = spec[0]
    if kind in ("tensor", "number"):
        return values[spec[1]]
    if kind == "none":
        return None
    if kind == "seq":
        items = [_unflatten(c, values) for c in spec[2]]
        cls = spec[1]
        return cls._make(items) if hasattr(cls, "_make") else cls(items)  # a NamedTuple takes its fields one by one
    if kind == "map":
        return {k: _unflatten(c, values) for k, c in zip(spec[1], spec[2])}
    return spec[1](**{n: _unflatten(c, values) for n, c in zip(spec[2], spec[3])})


def _slots(spec: _Def, obj: Any, path: str, out: dict[int, Any]) -> None:
    """The values of ``obj`` (a state the model returned) in the slots of ``spec``; a mismatch is an ExportError."""
    kind = spec[0]
    where = path or "the top"
    if kind in ("tensor", "number"):
        if not isinstance(obj, Tensor | int | float) or isinstance(obj, bool):
            raise ExportError(f"the streaming state changed structure: {where} was a tensor, now "
                              f"{type(obj).__name__}")
        out[spec[1]] = obj
    elif kind == "none":
        if obj is not None:
            raise ExportError(f"the streaming state changed structure: {where} was None, now {type(obj).__name__}")
    elif kind == "seq":
        if not isinstance(obj, tuple | list) or len(obj) != len(spec[2]):
            raise ExportError(f"the streaming state changed structure at {where}")
        for i, (c, v) in enumerate(zip(spec[2], obj)):
            _slots(c, v, f"{path}[{i}]", out)
    elif kind == "map":
        if not isinstance(obj, Mapping) or list(obj) != spec[1]:
            raise ExportError(f"the streaming state changed structure at {where}")
        for k, c in zip(spec[1], spec[2]):
            _slots(c, obj[k], f"{path}.{k}" if path else k, out)
    else:
        for n, c in zip(spec[2], spec[3]):
            _slots(c, getattr(obj, n), f"{path}.{n}" if path else n, out)


def _batch_dims(small: list[tuple[str, Any]], large: list[tuple[str, Any]], batch: int) -> list[int]:
    """The batch dimension of each tensor leaf: the one whose size follows the batch size between two templates."""
    dims = []
    for (path, a), (_, b) in zip(small, large):
        if not isinstance(a, Tensor):
            dims.append(0)  # a number becomes a (B, 1) counter
            continue
        moved = [d for d, (p, q) in enumerate(zip(a.shape, b.shape)) if p == batch and q == batch + 1]
        if len(moved) != 1 or a.dim() != b.dim():
            raise ExportError(f"state tensor {path} {tuple(a.shape)} has no single batch dimension")
        dims.append(moved[0])
    return dims


def _constant(path: str, value: Tensor) -> float:
    """The one value every entry of an initial state tensor holds (an exported state's start must be described by
    one number, see :class:`StateTensor`)."""
    flat = value.detach().reshape(-1)
    if flat.numel() == 0:
        raise ExportError(f"state tensor {path} is empty; zero-size inputs do not export")
    first = float(flat[0])
    if not bool((flat == flat[0]).all()):
        raise ExportError(f"the initial state tensor {path} is not constant; the export describes each initial "
                          f"state by one value")
    return first


# --------------------------------------------------------------------------------------------- exported graphs
class ForwardGraph(nn.Module):
    """The forward of a model as an export takes it: ``forward(x)`` or ``forward(x, g)`` -> ``scores``.

    Args:
        model: a model built for ``spec`` (in eval mode).
        spec: its :class:`~tactile_zoo.data.spec.DatasetSpec`.

    Shapes:
        ``x (B, T, N, C)``, ``g (B, T, G)`` (only when ``G > 0``) -> ``scores (B, K)``.
    """

    def __init__(self, model: nn.Module, spec: Any) -> None:
        super().__init__()
        self.model, self.num_globals = model, int(spec.num_globals)

    @property
    def input_names(self) -> list[str]:
        return ["x", "g"] if self.num_globals else ["x"]

    @property
    def output_names(self) -> list[str]:
        return ["scores"]

    def forward(self, *inputs: Tensor) -> Tensor:
        return self.model(inputs[0], inputs[1] if self.num_globals else None)


class StepGraph(nn.Module):
    """A streaming model's ``step`` with its state as a flat tuple of tensors, for tracing and export.

    ``forward(x_t, [g_t,] *state) -> (scores, *new_state)``; :attr:`states` describes each state tensor and
    :meth:`initial_state` builds the state before the first frame. Two kinds of model are supported:

    - models built on the zoo's frame bins (``BinnedStreamer``: ConvLSTM, CNN-LSTM, Tacformer, X-Tacformer), which
      have ``_advance(bins, globals, core)`` and ``bin_size``: the state is the core after the last complete bin
      (initial values: zeros, see ``_INITIAL_VALUES`` for the exceptions), plus the open bin's frame sums and its
      frame count when ``bin_size > 1``; a full bin is committed per row with ``torch.where``;
    - any other model with ``init_state(batch)`` and ``step(x_t, g_t, state)`` (SGnet, the TCN plugin): its state
      is flattened as it is, numbers becoming ``(B, 1)`` counters; it must start from constant tensors.

    Args:
        model: a streaming model in eval mode.
        spec: the spec it was built for.
        batch_size: the batch the state is sized for.
        name: the model's registry name (initial values that are not zero are looked up by it).

    Shapes:
        ``x_t (B, N, C)``, ``g_t (B, G)`` (only when ``G > 0``), state tensors as :attr:`states` ->
        ``scores (B, K)`` and the state tensors.
    """

    def __init__(self, model: nn.Module, spec: Any, batch_size: int = 1, name: str = "") -> None:
        super().__init__()
        if not (callable(getattr(model, "init_state", None)) and callable(getattr(model, "step", None))):
            raise ExportError(f"{name or type(model).__name__} has no init_state/step methods: it does not stream")
        self.model, self.num_globals, self.batch_size = model, int(spec.num_globals), int(batch_size)
        self.num_nodes, self.num_channels = int(spec.num_nodes), int(spec.num_channels)
        self.binned = callable(getattr(model, "_advance", None)) and isinstance(getattr(model, "bin_size", None), int)
        self.bin_size = int(model.bin_size) if self.binned else 1
        ref = next((p for p in model.parameters()), None)
        self._dtype = ref.dtype if ref is not None else torch.float32
        with torch.no_grad():
            small, self._def = self._template(self.batch_size)
            large, _ = self._template(self.batch_size + 1)
        dims = _batch_dims(small, large, self.batch_size)
        overrides = _INITIAL_VALUES.get(_registry_key(name), {}) if name else {}
        self._core_slots = sum(1 for path, _ in small if path.startswith("core")) if self.binned else len(small)
        states = []
        for i, ((path, value), dim) in enumerate(zip(small, dims)):
            if self.binned and i < self._core_slots:  # the template is the core after one bin; it starts from rest
                initial = overrides.get(path, 0.0)
            elif isinstance(value, Tensor):
                initial = overrides.get(path, _constant(path, value))
            else:
                initial = float(value)
            if isinstance(value, Tensor):
                states.append(StateTensor(i, path, tuple(value.shape), _dtype_name(self._dtype), initial, dim))
            else:
                states.append(StateTensor(i, path, (self.batch_size, 1), _dtype_name(self._dtype), initial, 0,
                                          "counter"))
        self.states: tuple[StateTensor, ...] = tuple(states)

    # ------------------------------------------------------------------------------------------------ layout
    def _template(self, batch: int) -> tuple[list[tuple[str, Any]], _Def]:
        """The state's leaves at ``batch`` (core after one bin for binned models, else ``init_state``), and the
        structure of the part the model sees (the core, or the whole state)."""
        leaves: list[tuple[str, Any]] = []
        if not self.binned:
            spec = _flatten(self.model.init_state(batch), "", leaves)
            return leaves, spec
        p = self._dtype
        xb = torch.zeros(1, batch, self.num_nodes, self.num_channels, dtype=p)
        gb = torch.zeros(1, batch, self.num_globals, dtype=p) if self.num_globals else None
        _, core = self.model._advance(xb, gb, None)
        spec = _flatten(core, "core", leaves)
        if self.bin_size > 1:  # the open bin: sums of its frames and of their globals, and how many frames it has
            leaves.append(("pending_x", torch.zeros(batch, self.num_nodes, self.num_channels, dtype=p)))
            if self.num_globals:
                leaves.append(("pending_g", torch.zeros(batch, self.num_globals, dtype=p)))
            leaves.append(("pending", 0))
        return leaves, spec

    @property
    def input_names(self) -> list[str]:
        return ["x_t", *(["g_t"] if self.num_globals else []), *(s.input_name for s in self.states)]

    @property
    def output_names(self) -> list[str]:
        return ["scores", *(s.output_name for s in self.states)]

    def initial_state(self) -> tuple[Tensor, ...]:
        """The state before the first frame (on the model's device)."""
        ref = next((t for t in (*self.model.parameters(), *self.model.buffers())), torch.zeros(()))
        return tuple(torch.full(s.shape, s.initial, dtype=self._dtype, device=ref.device) for s in self.states)

    # ------------------------------------------------------------------------------------------------ the step
    def forward(self, *inputs: Tensor) -> tuple[Tensor, ...]:
        x_t = inputs[0]
        g_t = inputs[1] if self.num_globals else None
        state = inputs[1 + bool(self.num_globals):]
        if not self.binned:
            scores, new = self.model.step(x_t, g_t, _unflatten(self._def, state))
            return (scores, *self._leaves(new))
        k = self._core_slots
        core = _unflatten(self._def, state[:k])
        if self.bin_size == 1:  # every frame is a whole bin: eager step commits each, as _advance does here
            scores, new = self.model._advance(x_t[None], None if g_t is None else g_t[None], core)
            return (scores, *self._leaves(new))
        pending_x, pending_g, pending = state[k], (state[k + 1] if self.num_globals else None), state[-1]
        px = pending_x + x_t  # (B, N, C): the open bin's sum so far
        pg = None if g_t is None else pending_g + g_t
        n = pending + 1  # (B, 1) frames in the open bin, this one included
        # the open bin scored from the state after the last complete bin, as BinnedStreamer.step does
        scores, new = self.model._advance(px[None], None if pg is None else (pg / n)[None], core)
        full = n == self.bin_size  # (B, 1): rows whose bin is complete commit it and open the next
        committed = [torch.where(_along(full, s.batch_dim, v.dim()), v, old)
                     for s, v, old in zip(self.states[:k], self._leaves(new), state[:k])]
        zero_x = torch.where(full[:, :, None], torch.zeros_like(px), px)
        out = [*committed, zero_x]
        if pg is not None:
            out.append(torch.where(full, torch.zeros_like(pg), pg))
        out.append(torch.where(full, torch.zeros_like(n), n))
        return (scores, *out)

    def _leaves(self, new: Any) -> list[Tensor]:
        """The tensors of a state the model returned, in slot order; numbers become ``(B, 1)`` counters."""
        found: dict[int, Any] = {}
        _slots(self._def, new, "core" if self.binned else "", found)
        out = []
        for slot in range(len(found)):
            value = found[slot]
            if not isinstance(value, Tensor):
                value = torch.full((self.batch_size, 1), float(value), dtype=self._dtype)
            out.append(value)
        return out


def _along(mask: Tensor, dim: int, rank: int) -> Tensor:
    """A ``(B, 1)`` row mask shaped to broadcast over a tensor of ``rank`` dimensions whose batch is ``dim``."""
    shape = [1] * rank
    shape[dim] = mask.shape[0]
    return mask.reshape(shape)


def _dtype_name(dtype: torch.dtype) -> str:
    return str(dtype).removeprefix("torch.")


def _registry_key(name: str) -> str:
    """The registry name of ``name`` (its plain form, e.g. ``x_tacformer``), or ``name`` if it is not registered."""
    try:
        return registry.get_model_entry(name).qualified_name.rpartition(":")[2]
    except registry.UnknownNameError:
        return name


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


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the exporters' chatter: torch.jit's deprecation and tracer warnings (every export is checked against
    eager on other inputs instead) and the progress lines the ONNX exporter prints."""
    import io
    import logging
    from contextlib import redirect_stdout

    onnx_logger = logging.getLogger("torch.onnx")
    level = onnx_logger.level
    onnx_logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            yield
    finally:
        onnx_logger.setLevel(level)


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
        opset: the ONNX opset (default: the exporter's).
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
    tmp = manifest_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    tmp.replace(manifest_path)
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
