"""The graphs an export traces: a model's forward, and its streaming step with the state as a flat tuple of tensors.

:class:`StepGraph` turns a streaming model's ``step(x_t, g_t, state)``, whose state is any nesting of tensors and
Python numbers, into ``forward(x_t, [g_t,] *state) -> (scores, *new_state)`` with every piece of state a named tensor
(:class:`StateTensor`), the form TorchScript and ONNX files need; :class:`ForwardGraph` gives the forward the same
calling convention. Models reach the exporter through a copy whose LIF layers are :class:`_PlainLIF` (the same numbers
in a compact graph). :mod:`tactile_zoo.export` writes and checks the files.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from .. import registry
from ..errors import ExportError
from ..nn.lif import MultiStepLIF

__all__ = ["StateTensor", "ForwardGraph", "StepGraph"]

#: Initial values of state tensors that do not start at zero, by registry name and state path: X-Tacformer's online
#: softmax over frames keeps the running maximum of the scores seen so far, which starts at -inf (the identity of
#: max), so that the first bin gives exactly what the eager model computes from no state at all.
_INITIAL_VALUES: dict[str, dict[str, float]] = {"x_tacformer": {"core[1][1]": -math.inf}}


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

