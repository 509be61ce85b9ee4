"""Multi-step leaky integrate-and-fire (LIF) neurons: snnTorch's ``Leaky`` over a whole sequence at once.

The neuron is ``snntorch.Leaky`` (snnTorch 1.0), reset to zero or by subtraction, stepped with the reset computed
from the previous step's membrane potential. For ``t = 1..T`` with ``U[0] = mem`` (zeros by default)::

    R[t] = Heaviside(U[t-1] - U_thr)                       # reset of the previous step's spike
    U[t] = beta * (1 - R[t]) * U[t-1] + I[t]               # reset="zero"
    U[t] = beta * U[t-1] + I[t] - R[t] * U_thr             # reset="subtract"
    S[t] = Heaviside(U[t] - U_thr)                         # spike, 1 where U[t] > U_thr (strictly)

Back-propagation replaces dS/dU by a surrogate. snnTorch detaches ``R`` from the graph (``detach_reset=True``);
the TactileSGNet reference (Gu et al., IROS 2020) differentiates through it, ``mem * decay * (1 - spike)``
(``detach_reset=False``). The paper's LIF (X-Tacformer, eqs. 2-4)::

    H(t) = V(t-1) + (X(t) - (V(t-1) - V_reset)) / tau
    S(t) = Heaviside(H(t) - V_th)
    V(t) = H(t) (1 - S(t)) + V_reset S(t)

is the same neuron in the shifted variable ``U = V - V_reset``: ``beta = 1 - 1/tau``, ``U_thr = V_th - V_reset``, fed
``X / tau`` (:meth:`MultiStepLIF.from_tau`); the neuron starts at rest, ``V(0) = V_reset``.

Two backends compute the same thing: ``"snntorch"`` steps ``snntorch.Leaky`` once per time step (the reference
definition; autograd records every step) and ``"fused"`` (default) runs the whole time loop inside one
``torch.autograd.Function`` with a hand-written backward through time: two kernels per step forward, one
multiply-add per step backward, everything else vectorised over cache-sized blocks of steps (see :class:`_FusedLIF`).
On CPU the two give bit-identical spikes (the same rounding, ``(beta * U) * (1 - R) + I``) and the same gradients to
float rounding (tests/nn/test_lif.py); on GPU a fused multiply-add may round a membrane that lands within one ulp of
the threshold differently. Surrogates: :mod:`tactile_zoo.nn.surrogate`.

On CPU the fused backend runs as a compiled kernel where it can (:mod:`tactile_zoo.nn.lif_compiled`; its torch
implementation is :mod:`tactile_zoo.nn.lif_fused`; where each runs is decided in :mod:`tactile_zoo.nn.backend`): the
forward and the backward time loop are one numba-compiled call per sequence each, parallel over blocks of neurons on
``torch.get_num_threads()`` threads, with spikes, membranes and gradients bit-identical to the torch implementation
(tests/nn/test_lif_kernel.py). It applies to float32 CPU tensors with the ``rect`` or ``atan`` surrogate on x86-64
(ATen's AVX2/AVX512 kernels), numba installed; everything else, the GPU included, runs the torch implementation. The
environment variable ``TACTILE_ZOO_LIF_BACKEND`` (:data:`KERNEL_ENV`) chooses per call: ``auto`` (default), ``torch``
(never the kernel) or ``numba`` (the kernel, and an error where it is unavailable). The kernel multiplies the input by
``input_scale`` inside its loops (the same float32 multiplies as a separate pass), and in training both paths write
their spikes and input gradient into reused storages (:func:`tactile_zoo.nn.storage_pool.reusable`).
``return_active=True`` adds the active neurons of every step (:mod:`tactile_zoo.nn.active_neurons`) for event-driven
layers.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ..errors import ConfigError
from . import backend as switch
from .active_neurons import active_spikes
from .backend import LIFBackend
from .lif_compiled import CompiledLIF, compiled_forward
from .lif_fused import FusedLIF, run_forward
from .surrogate import make_surrogate

# the surrogates live in .surrogate, the fused and compiled paths in .lif_fused and .lif_compiled
__all__ = ["MultiStepLIF", "LIFConfig", "KERNEL_ENV"]

#: Environment variable choosing how the fused backend runs on CPU (:data:`tactile_zoo.nn.backend.LIF_KERNEL_ENV`):
#: ``auto`` (default: the compiled kernel where it applies, else torch), ``numba`` (the same, but an error where
#: numba is missing) or ``torch`` (never the kernel).
KERNEL_ENV = switch.LIF_KERNEL_ENV
_RESETS = ("zero", "subtract")


@functools.cache
def _attached_leaky() -> type:
    """``snntorch.Leaky`` whose reset keeps its gradient (the only change): TactileSGNet's ``detach_reset=False``."""
    import snntorch

    class AttachedResetLeaky(snntorch.Leaky):
        def mem_reset(self, mem: Tensor) -> Tensor:
            return self.spike_grad(mem - self.threshold)

    return AttachedResetLeaky


class MultiStepLIF(nn.Module):
    """A layer of LIF neurons run over a time-major sequence; state is reset at every call.

    Args:
        beta: membrane decay per step, in [0, 1] (snnTorch clamps it there).
        threshold: firing threshold ``U_thr``.
        reset: ``"zero"`` (TactileSGNet, the paper) or ``"subtract"``.
        surrogate: ``"rect"``, ``"atan"``, ``"sigmoid"`` or an ``snntorch.surrogate`` callable.
        surrogate_width: full width of the ``rect`` window (1.0: gradient 1 where ``|U - U_thr| < 0.5``).
        surrogate_alpha: ``atan`` alpha (snnTorch default 2).
        surrogate_slope: ``sigmoid`` slope (snnTorch default 25).
        detach_reset: ``True`` detaches the reset from the graph (snnTorch); ``False`` back-propagates through it
            (TactileSGNet).
        backend: ``"fused"`` (one autograd node for the whole loop; on CPU the compiled kernel where it applies,
            see :data:`KERNEL_ENV`) or ``"snntorch"`` (steps ``snntorch.Leaky``); :class:`~.backend.LIFBackend`.
        input_scale: the input is multiplied by it first (``1/tau`` for the paper's neuron).

    Shapes:
        - input ``x``: ``(T, *)`` time-major, any trailing shape; ``mem``: ``(*)`` or ``None`` (zeros).
        - output: spikes ``(T, *)`` as 0/1 floats; with ``return_mem=True`` also the last membrane ``(*)``, which
          continues the sequence when passed back as ``mem``; with ``return_active=True`` (last) the active neurons
          as :class:`~tactile_zoo.nn.active_neurons.ActiveSpikes`.
    """

    def __init__(self, beta: float = 0.2, threshold: float = 0.5, reset: str = "zero",
                 surrogate: str | Callable[[Tensor], Tensor] = "rect", surrogate_width: float = 1.0,
                 surrogate_alpha: float = 2.0, surrogate_slope: float = 25.0, detach_reset: bool = False,
                 backend: str = "fused", input_scale: float = 1.0) -> None:
        super().__init__()
        if not 0.0 <= beta <= 1.0:
            raise ConfigError(f"LIF beta must lie in [0, 1], got {beta}")
        if reset not in _RESETS:
            raise ConfigError(f"LIF reset must be one of {_RESETS}, got {reset!r}")
        self.backend = switch.resolve(LIFBackend, backend, "backend", "MultiStepLIF")
        self.beta, self.threshold, self.reset = float(beta), float(threshold), reset
        self.surrogate = make_surrogate(surrogate, surrogate_width, surrogate_alpha, surrogate_slope)
        self.detach_reset, self.input_scale = bool(detach_reset), float(input_scale)
        self._leaky: dict[tuple, nn.Module] = {}  # snnTorch neurons, built on first use; kept out of the state_dict

    @classmethod
    def from_tau(cls, tau: float, v_th: float, v_reset: float = 0.0, **kw: object) -> MultiStepLIF:
        """The paper's LIF (eqs. 2-4) with time constant ``tau`` > 1, threshold ``v_th`` and reset ``v_reset``.

        The membrane it returns is ``V - v_reset`` (zero at rest)."""
        if not tau >= 1.0:
            raise ConfigError(f"LIF tau must be >= 1, got {tau}")
        if not v_th > v_reset:
            raise ConfigError(f"LIF v_th ({v_th}) must exceed v_reset ({v_reset})")
        return cls(beta=1.0 - 1.0 / tau, threshold=v_th - v_reset, reset="zero", input_scale=1.0 / tau, **kw)

    def extra_repr(self) -> str:
        return (f"beta={self.beta:g}, threshold={self.threshold:g}, reset={self.reset}, surrogate={self.surrogate}, "
                f"detach_reset={self.detach_reset}, backend={self.backend}"
                + (f", input_scale={self.input_scale:g}" if self.input_scale != 1.0 else ""))

    def forward(self, x: Tensor, mem: Tensor | None = None, return_mem: bool = False, return_active: bool = False
                ) -> Tensor | tuple:
        """Spikes ``(T, *)``; with ``return_mem`` also the last membrane, with ``return_active`` also the active
        neurons of every step as :class:`~tactile_zoo.nn.active_neurons.ActiveSpikes` (rows ``(t, b)``, columns the
        last dimension), in that order. ``return_active`` costs one pass over the spikes; without it, nothing."""
        if x.dim() < 1 or x.shape[0] < 1:
            raise ConfigError(f"MultiStepLIF expects a time-major input (T >= 1, ...), got shape {tuple(x.shape)}")
        if mem is None:
            mem = x.new_zeros(x.shape[1:])
        elif mem.shape != x.shape[1:]:
            raise ConfigError(f"MultiStepLIF: mem has shape {tuple(mem.shape)}, the input's step shape is "
                              f"{tuple(x.shape[1:])}")
        subtract = self.reset == "subtract"
        fused = self.backend is LIFBackend.FUSED
        kernels = switch.lif_kernels_for(x, mem, self.surrogate) if fused else None
        scale = self.input_scale
        if kernels is None and scale != 1.0:
            x = x * scale  # the compiled kernel multiplies inside its loops instead, with the same rounding
        grad = torch.is_grad_enabled() and (x.requires_grad or mem.requires_grad)
        if kernels is not None and grad:
            spikes, last = CompiledLIF.apply(x, mem, self.beta, self.threshold, subtract, self.detach_reset,
                                              self.surrogate, kernels, scale)
        elif kernels is not None:  # nothing to differentiate: the compiled loop without the autograd node
            spikes, last, _ = compiled_forward(kernels, x.contiguous(), mem.contiguous(), self.beta, self.threshold,
                                              subtract, input_scale=scale)
        elif fused and grad:
            spikes, last = FusedLIF.apply(x, mem, self.beta, self.threshold, subtract, self.detach_reset,
                                           self.surrogate)
        elif fused:  # nothing to differentiate: the same loop without the autograd node
            spikes, last, _, _ = run_forward(x, mem, self.beta, self.threshold, subtract, False)
        else:
            spikes, last = self._snntorch_loop(x, mem)
        out = (spikes, last) if return_mem else (spikes,)
        if return_active:
            out = (*out, active_spikes(spikes))
        return out if len(out) > 1 else spikes

    def step(self, x_t: Tensor, mem: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """One time step: ``x_t (*)`` and the membrane ``(*)`` -> ``(spike (*), membrane (*))``; the arithmetic of
        :meth:`forward` (it is ``forward`` on a length-1 sequence)."""
        spikes, mem = self.forward(x_t.unsqueeze(0), mem, return_mem=True)
        return spikes.squeeze(0), mem

    def _snntorch_loop(self, x: Tensor, mem: Tensor) -> tuple[Tensor, Tensor]:
        key = (x.device, x.dtype)
        leaky = self._leaky.get(key)
        if leaky is None:  # one neuron per device and dtype, built from float64 constants (as_tensor(0.2) would
            import snntorch  # round beta to float32 even for float64 inputs)

            leaky_cls = snntorch.Leaky if self.detach_reset else _attached_leaky()
            exact = dict(dtype=torch.float64)
            leaky = leaky_cls(beta=torch.tensor(self.beta, **exact), threshold=torch.tensor(self.threshold, **exact),
                              spike_grad=self.surrogate.spike_fn, reset_mechanism=self.reset).to(*key)
            self._leaky[key] = leaky
        spikes = []
        for x_t in x.unbind(0):  # never x[t]: each x[t] backward would materialise a full-size gradient
            spk, mem = leaky(x_t, mem)
            spikes.append(spk.to(x.dtype))  # snnTorch's spike functions return float32 whatever the input
        leaky.mem = torch.zeros(0, device=x.device)  # do not keep the last graph alive in snnTorch's buffer
        return torch.stack(spikes), mem


@dataclass(frozen=True)
class LIFConfig:
    """How every LIF of a block is built: the paper's neuron (eqs. 2-4) with time constant ``tau`` and threshold
    ``v_th``, reset to zero; ``surrogate`` and ``detach_reset`` are open points (see the model cards)."""

    tau: float = 2.0
    v_th: float = 1.0
    surrogate: str = "atan"
    detach_reset: bool = True
    backend: str = "fused"

    def build(self) -> MultiStepLIF:
        return MultiStepLIF.from_tau(self.tau, self.v_th, surrogate=self.surrogate, detach_reset=self.detach_reset,
                                     backend=self.backend)

