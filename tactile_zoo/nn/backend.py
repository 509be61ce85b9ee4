"""The one switch for compute paths: every keyword that chooses how a layer or a model computes, and the LIF's
environment override, is resolved here and nowhere else (tests/nn/test_compute_switch.py reads the package's syntax
trees and fails on a second resolver).

- ``backend`` of :class:`~tactile_zoo.nn.lif.MultiStepLIF` and ``LIFConfig`` (models: ``lif_backend``):
  :class:`LIFBackend`, ``fused`` or ``snntorch``;
- ``backend`` of :class:`~tactile_zoo.nn.convlstm.ConvLSTMCell` and ``ConvLSTMConfig`` (the ``convlstm`` model's
  ``backend``): :class:`ConvLSTMBackend`, ``fused``, ``autograd`` or ``compiled``;
- ``backend`` of :class:`~tactile_zoo.nn.graph.FrameGraphConv` (models: ``graph_backend``): :class:`GraphBackend`,
  ``dense`` or ``pyg``; its ``weight_grad`` (SGnet: ``graph_weight_grad``): :class:`WeightGrad`, ``autograd`` or
  ``fast``;
- ``temporal_backend`` of :class:`~tactile_zoo.nn.tgcn.TemporalGraphAttention` and X-Tacformer:
  :class:`TemporalBackend`, ``native`` or ``tgt``;
- ``attention`` of :class:`~tactile_zoo.nn.attention.SpikingSelfAttention`, Tacformer and X-Tacformer:
  :class:`Attention`, ``fused`` or ``explicit``;
- ``compute`` of SGnet: :class:`Compute`, ``dense`` or ``event`` (:func:`resolve_compute`);
- ``stats`` of :class:`~tactile_zoo.nn.batch_norm.BatchNorm1d` and ``BatchNorm2d`` (D-CNN: ``bn_stats``):
  :class:`BatchNormStats`, ``native``, ``two_pass`` or ``float64``;
- ``backend`` of :class:`~tactile_zoo.nn.alif.AdaptiveLIF` (the multi-barrel SNN: ``alif_backend``):
  :class:`ALIFBackend`, ``torch`` or ``compiled``.

The first choice of each is the oldest path; which one a model builds by default is its registered revision's
(registry metadata ``revisions``: SGnet's ``compute="event"`` and the transformers' ``attention="explicit"`` since
revision 3, :func:`tactile_zoo.registry.model_revisions`). :func:`resolve` turns a keyword's value into its
enumeration's member (a ``str``, so it still compares equal to the word) or raises one
:class:`~tactile_zoo.errors.ConfigError` naming the owner, the keyword, the value and the allowed values. Layers keep
the member and branch on it (``self.backend is LIFBackend.FUSED``); no module compares such a keyword with a string of
its own.

The environment variable ``TACTILE_ZOO_LIF_BACKEND`` (:data:`LIF_KERNEL_ENV`; declared with its choices in
:data:`tactile_zoo._env.CHOICE_VARIABLES`, which the command line checks before any work) chooses, per call, how the
LIF's ``fused`` backend runs on CPU: :class:`LIFKernel` ``auto`` (the compiled kernel where it applies, else torch),
``numba`` (the same, but an error where the kernel is unavailable) or ``torch`` (never the kernel). It is read here
only (:func:`lif_kernel_choice`, :func:`lif_kernels_for`).

The compiled (numba) kernels sit in the private package :mod:`tactile_zoo.nn._kernels`; the loaders here import them
on first use (numba's import and first compilation take seconds) and say where they are available:
:func:`lif_kernels`, :func:`event_kernels`, :func:`convlstm_kernels`.
"""

from __future__ import annotations

import functools
import platform
import threading
from enum import StrEnum
from types import ModuleType
from typing import TYPE_CHECKING, TypeVar

import torch
from torch import Tensor

from .._env import CHOICE_VARIABLES, env_choice
from ..errors import ConfigError

if TYPE_CHECKING:
    from .surrogate import Surrogate

__all__ = ["LIFBackend", "LIFKernel", "ConvLSTMBackend", "GraphBackend", "WeightGrad", "TemporalBackend", "Attention",
           "Compute", "BatchNormStats", "resolve", "resolve_compute", "LIF_KERNEL_ENV", "lif_kernel_choice",
           "lif_kernels", "lif_kernels_for", "event_kernels", "graph_lif_kernels", "bn_pool_kernels",
           "convlstm_kernels", "ALIFBackend", "alif_kernels_for", "launch"]


class LIFBackend(StrEnum):
    """:class:`~tactile_zoo.nn.lif.MultiStepLIF`'s time loop: one autograd node for the whole sequence (on CPU the
    compiled kernel where it applies), or ``snntorch.Leaky`` stepped once per step (the reference)."""

    FUSED = "fused"
    SNNTORCH = "snntorch"


class LIFKernel(StrEnum):
    """How the fused LIF runs on CPU (:data:`LIF_KERNEL_ENV`): the kernel where it applies, the kernel or an error,
    never the kernel."""

    AUTO = "auto"
    NUMBA = "numba"
    TORCH = "torch"


class ConvLSTMBackend(StrEnum):
    """:class:`~tactile_zoo.nn.convlstm.ConvLSTMCell`'s recurrence: one autograd node with a hand-written backward,
    ordinary differentiable ops stepped in Python (the reference), or the fused loop with numba kernels per step."""

    FUSED = "fused"
    AUTOGRAD = "autograd"
    COMPILED = "compiled"


class GraphBackend(StrEnum):
    """:class:`~tactile_zoo.nn.graph.FrameGraphConv`: precomputed dense hop matrices, or one PyG call per batch."""

    DENSE = "dense"
    PYG = "pyg"


class WeightGrad(StrEnum):
    """How the dense graph convolution forms its weight gradient: autograd's, or the same sums in a faster order."""

    AUTOGRAD = "autograd"
    FAST = "fast"


class TemporalBackend(StrEnum):
    """X-Tacformer's temporal cell: the paper's T-GCN (eqs. 10-13), or torch_geometric_temporal's ``TGCN2``."""

    NATIVE = "native"
    TGT = "tgt"


class Attention(StrEnum):
    """The MSA-SNN's attention product (eq. 8): ``F.scaled_dot_product_attention``, or the explicit score matrix."""

    FUSED = "fused"
    EXPLICIT = "explicit"


class Compute(StrEnum):
    """SGnet's products: dense (revision 2), or over the input events and the first LIF's spikes (CPU; the default
    since revision 3)."""

    DENSE = "dense"
    EVENT = "event"


class BatchNormStats(StrEnum):
    """How a training batch's statistics (and the backward pass's sums) are computed in batch norm: torch's kernel,
    float32 pairwise sums with a two-pass variance, or the same sums accumulated in float64."""

    NATIVE = "native"
    TWO_PASS = "two_pass"
    FLOAT64 = "float64"


class ALIFBackend(StrEnum):
    """:meth:`~tactile_zoo.nn.alif.AdaptiveLIF.step`: a chain of torch operations (revision 1 of the multi-barrel
    SNN), or one compiled kernel forward and one backward on CPU float32 tensors (the same spikes, membranes and
    traces; gradients up to float32 rounding), the torch chain elsewhere."""

    TORCH = "torch"
    COMPILED = "compiled"


_Choice = TypeVar("_Choice", bound=StrEnum)


def resolve(kind: type[_Choice], value: object, keyword: str, owner: str) -> _Choice:
    """``value`` as a member of ``kind``, the enumeration of keyword ``keyword`` of ``owner``.

    Raises:
        ConfigError: ``value`` is none of ``kind``'s words, named with the owner, the keyword and the allowed words.
    """
    if isinstance(value, str):
        try:
            return kind(value)
        except ValueError:
            pass
    allowed = ", ".join(repr(member.value) for member in kind)
    raise ConfigError(f"{owner}: {keyword} must be one of {allowed}, got {value!r}")


def resolve_compute(compute: object, graph_backend: object, owner: str) -> Compute:
    """SGnet's ``compute``: :attr:`Compute.EVENT` needs ``graph_backend="dense"`` (the event product is built from the
    dense hop matrices).

    Raises:
        ConfigError: an unknown value, or ``compute="event"`` with another graph backend.
    """
    chosen = resolve(Compute, compute, "compute", owner)
    graph = resolve(GraphBackend, graph_backend, "graph_backend", owner)
    if chosen is Compute.EVENT and graph is not GraphBackend.DENSE:
        raise ConfigError(f"{owner}: compute='event' needs graph_backend='dense' (the event product is built from the "
                          f"dense hop matrices), got graph_backend={graph_backend!r}; with it, pass compute='dense'")
    return chosen


#: Environment variable choosing how the fused LIF runs on CPU (:class:`LIFKernel`).
LIF_KERNEL_ENV = "TACTILE_ZOO_LIF_BACKEND"


def lif_kernel_choice() -> LIFKernel:
    """The value of :data:`LIF_KERNEL_ENV` now (``auto`` when unset).

    Raises:
        ConfigError: a value other than auto, numba or torch (any case), named with the variable.
    """
    return LIFKernel(env_choice(LIF_KERNEL_ENV, CHOICE_VARIABLES[LIF_KERNEL_ENV]))


@functools.cache
def lif_kernels() -> ModuleType | None:
    """The compiled LIF kernels (:mod:`tactile_zoo.nn._kernels.lif`) where they reproduce the fused path bit for
    bit, else ``None``.

    That is x86-64 with ATen's AVX2 or AVX512 kernels (their FMAs are the ones the kernel copies; the
    ``ATEN_CPU_CAPABILITY=default`` build rounds without them, and other CPUs were not checked) and numba installed.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    if torch.backends.cpu.get_cpu_capability() not in ("AVX2", "AVX512"):
        return None
    try:
        from ._kernels import lif
    except ImportError:
        return None
    return lif


def lif_kernels_for(x: Tensor, mem: Tensor, surrogate: Surrogate) -> ModuleType | None:
    """The compiled LIF kernels if they run this call of the fused backend, else ``None`` (the torch path).

    They run on plain float32 CPU tensors with the ``rect`` or ``atan`` surrogate, outside tracers, where
    :func:`lif_kernels` has them and :data:`LIF_KERNEL_ENV` is not ``torch``.

    Raises:
        ConfigError: :data:`LIF_KERNEL_ENV` is ``numba`` and the kernels would run this call but are unavailable;
            or its value is refused.
    """
    choice = lif_kernel_choice()
    if choice is LIFKernel.TORCH or x.device.type != "cpu" or mem.device.type != "cpu":
        return None
    # a tracer's tensors (torch.export's fake and functional tensors, torch.compile's) hold no memory numba can read:
    # traced graphs record the torch path, which computes the same numbers
    if type(x) is not torch.Tensor or type(mem) is not torch.Tensor or torch.compiler.is_compiling():
        return None
    if x.dtype != torch.float32 or mem.dtype != torch.float32 or surrogate.kind not in ("rect", "atan"):
        return None  # float64, and surrogates evaluated by other ATen kernels (sigmoid's exp, custom), stay in torch
    kernels = lif_kernels()
    if kernels is None and choice is LIFKernel.NUMBA:
        raise ConfigError(f"{LIF_KERNEL_ENV}=numba, but the compiled LIF kernel is unavailable here (it needs numba, "
                          f"x86-64 and ATen's AVX2 or AVX512 kernels)")
    return kernels


@functools.cache
def event_kernels() -> ModuleType | None:
    """The compiled event-list kernels (:mod:`tactile_zoo.nn._kernels.events`), or ``None`` where numba is missing
    (the callers then use ``torch.nonzero``, with the same lists)."""
    try:
        from ._kernels import events
    except ImportError:
        return None
    return events


def _kernel_threads(kernels: ModuleType) -> None:
    """Run the kernels on as many threads as torch is given (numba's own pool cannot grow past its start size)."""
    import numba

    n = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    if numba.get_num_threads() != n:
        numba.set_num_threads(n)


#: Serialises kernel launches where numba's threading layer cannot take two at once: its fallback layer
#: ("workqueue", used where neither OpenMP nor TBB loads) aborts the process on concurrent launches from two threads.
_LAUNCH_LOCK = threading.Lock()


def launch(kernels: ModuleType, name: str, *args: object, serial: bool) -> None:
    """Call compiled kernel ``name`` of module ``kernels`` (built twice, ``name`` and ``name_serial``: see
    :func:`tactile_zoo.nn._kernels.jit.serial_copy`) on torch's thread count: the serial build on one thread or where
    the caller says the work is too small to split (``serial``), else the parallel build -- under a lock until numba's
    threading layer is known (it is chosen at the first launch) and for good if that layer is "workqueue"."""
    import numba

    if torch.get_num_threads() == 1 or serial:
        getattr(kernels, f"{name}_serial")(*args)
        return
    _kernel_threads(kernels)
    try:
        locked = numba.threading_layer() == "workqueue"
    except ValueError:  # no parallel launch yet
        locked = True
    if locked:
        with _LAUNCH_LOCK:
            getattr(kernels, name)(*args)
    else:
        getattr(kernels, name)(*args)


def graph_lif_kernels() -> ModuleType | None:
    """SGnet's fused graph convolution -> LIF kernels (:mod:`tactile_zoo.nn._kernels.graph_lif`), or ``None`` where
    numba is missing (the caller then runs the two layers apart, with the same numbers)."""
    try:
        from ._kernels import graph_lif
    except ImportError:
        return None
    return graph_lif


def bn_pool_kernels() -> ModuleType | None:
    """D-CNN's fused ReLU -> batch norm -> max pool kernels (:mod:`tactile_zoo.nn._kernels.bn_pool`), or ``None``
    where numba is missing (the caller then runs the layers apart)."""
    try:
        from ._kernels import bn_pool
    except ImportError:
        return None
    return bn_pool


def convlstm_kernels() -> ModuleType:
    """The numba kernels of ConvLSTM's ``"compiled"`` backend (:mod:`tactile_zoo.nn._kernels.convlstm`), imported on
    first use (numba's import takes a while).

    Raises:
        ImportError: numba is not installed.
    """
    from ._kernels import convlstm

    return convlstm


@functools.cache
def _alif_kernels() -> ModuleType | None:
    try:
        from ._kernels import alif
    except ImportError:
        return None
    return alif


def alif_kernels_for(*tensors: Tensor) -> ModuleType | None:
    """The compiled ALIF step (:mod:`tactile_zoo.nn._kernels.alif`) if it runs on ``tensors``, else ``None`` (the
    torch path, which computes the same forward): plain float32 CPU tensors outside tracers, with numba installed.
    Its operations are IEEE single-precision multiplies, adds and subtractions, each rounded once, so unlike the LIF
    kernel's FMAs they do not depend on ATen's CPU capability."""
    for t in tensors:
        if type(t) is not torch.Tensor or t.device.type != "cpu" or t.dtype != torch.float32:
            return None
    # a tracer (torch.export, torch.compile, a TorchScript trace) records the torch chain: it could not replay numba
    if torch.compiler.is_compiling() or torch.jit.is_tracing() or torch.onnx.is_in_onnx_export():
        return None
    return _alif_kernels()
