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

On CPU the fused backend runs as a compiled kernel where it can (:class:`_CompiledLIF`,
:mod:`tactile_zoo.nn._lif_kernel`): the forward and the backward time loop are one numba-compiled call per sequence
each, parallel over blocks of neurons on ``torch.get_num_threads()`` threads, with spikes, membranes and gradients
bit-identical to the torch implementation of ``"fused"`` (tests/nn/test_lif_kernel.py). It applies to float32 CPU
tensors with the ``rect`` or ``atan`` surrogate on x86-64 (ATen's AVX2/AVX512 kernels), numba installed; everything
else, the GPU included, runs the torch implementation. The environment variable ``TACTILE_ZOO_LIF_BACKEND``
(:data:`KERNEL_ENV`) chooses per call: ``auto`` (default), ``torch`` (never the kernel) or ``numba`` (the kernel, and
an error where it is unavailable).
"""

from __future__ import annotations

import functools
import math
import os
import platform
import threading
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType

import torch
from torch import Tensor, nn

from ..errors import ConfigError
from . import memory
from .surrogate import Surrogate, make_surrogate, open_interval_mask

__all__ = ["MultiStepLIF", "LIFConfig", "Surrogate", "make_surrogate"]  # the surrogates live in .surrogate

_RESETS = ("zero", "subtract")
_BACKENDS = ("fused", "snntorch")
#: Environment variable choosing how the fused backend runs on CPU: ``auto`` (default: the compiled kernel where it
#: applies, else torch), ``numba`` (the same, but an error where numba is missing) or ``torch`` (never the kernel).
KERNEL_ENV = "TACTILE_ZOO_LIF_BACKEND"
_KERNEL_CHOICES = ("auto", "numba", "torch")


#: Sequences whose membrane history is at most this large keep it for the backward pass; longer ones keep one
#: checkpoint per block and recompute the block (two kernels per step) instead of allocating, and page-faulting in,
#: a history as large as the input.
SAVE_LIMIT_BYTES = 8 << 20
#: Bytes per block of steps that the vectorised parts of forward and backward process at once (stays in cache).
BLOCK_BYTES = 2 << 20

@functools.lru_cache(maxsize=64)
def _next_up(level: float, dtype: torch.dtype) -> float:
    """The smallest value of ``dtype`` above ``level``: ``u <= level`` is ``u < _next_up(level)`` exactly."""
    return torch.nextafter(torch.tensor(level, dtype=dtype), torch.tensor(math.inf, dtype=dtype)).item()


def _advance(x_t: Tensor, prev: Tensor, out: Tensor, flag: Tensor, ones: Tensor, beta: float, threshold: float,
             th_up: float, subtract: bool) -> Tensor:
    """One LIF step from membrane ``prev`` into ``out``. ``flag`` is scratch for the previous step's reset, ``ones``
    an all-ones tensor of the step's shape (may be expanded), ``th_up = _next_up(threshold)``."""
    if subtract:
        # R[t] = (U > U_thr) as 0/1 in one kernel; it misses U = +inf, whose next membrane is +inf either way
        open_interval_mask(prev, threshold, math.inf, out=flag, ones=ones)
        # one kernel for (beta * U) * 1 + I: exactly the rounding of snnTorch's beta * U + I; R * U_thr is exact, so
        # subtracting it rounds once, as snnTorch's does
        return torch.addcmul(x_t, prev, ones, value=beta, out=out).sub_(flag, alpha=threshold)
    # 1 - R[t] = (U <= U_thr) as 0/1 in one kernel (a comparison into a float tensor takes two)
    open_interval_mask(prev, -math.inf, th_up, out=flag, ones=ones)
    # one kernel for (beta * U) * (1 - R) + I: exactly the rounding of snnTorch's beta * ((1 - R) * U) + I
    return torch.addcmul(x_t, prev, flag, value=beta, out=out)


def _run(x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, for_backward: bool
         ) -> tuple[Tensor, Tensor, Tensor | None, tuple[int, bool, list[int]]]:
    """The forward time loop: spikes ``[T, ...]``, the last membrane, what the backward pass needs (the membrane
    history with ``mem0`` as row 0 when small, else the membrane entering each block) and the block layout."""
    steps, step_bytes = x.shape[0], max(1, mem0.numel() * x.element_size())
    block = max(1, min(steps, BLOCK_BYTES // step_bytes))
    keep_all = for_backward and (steps + 1) * step_bytes <= SAVE_LIMIT_BYTES
    spikes = memory.empty(x.shape, x)  # huge pages when large: its first write would page-fault
    flag, ones = torch.empty_like(mem0), mem0.new_ones(()).expand_as(mem0)
    th_up = _next_up(threshold, x.dtype)
    hist = x.new_empty((steps + 1 if keep_all else block + 1, *mem0.shape))  # row 0: the membrane entering
    hist[0] = mem0
    starts = list(range(0, steps, block))
    ckpts = x.new_empty((len(starts), *mem0.shape)) if for_backward and not keep_all else None
    xs = x.unbind(0)
    for j, t0 in enumerate(starts):
        t1 = min(t0 + block, steps)
        rows = hist[t0:t1 + 1] if keep_all else hist[:t1 - t0 + 1]  # (n + 1, ...) with the entering membrane
        if ckpts is not None:
            ckpts[j].copy_(rows[0])
        out = rows.unbind(0)
        prev = out[0]
        for k in range(t1 - t0):
            prev = _advance(xs[t0 + k], prev, out[k + 1], flag, ones, beta, threshold, th_up, subtract)
        # spikes U > U_thr as 0/1 in one kernel (only an infinite membrane would be missed)
        open_interval_mask(rows[1:], threshold, math.inf, out=spikes[t0:t1], ones=ones.expand_as(rows[1:]))
        if not keep_all and t1 < steps:
            rows[0].copy_(prev)  # the next block reuses the buffer, starting from this block's last membrane
    return spikes, prev.clone(), (hist if keep_all else ckpts), (block, keep_all, starts)


class _FusedLIF(torch.autograd.Function):
    """The whole LIF time loop as one autograd node. Inputs ``x [T, ...]``, ``mem0 [...]``; outputs spikes
    ``[T, ...]`` and the last membrane potential ``[...]``.

    Forward: two kernels per step; spikes are thresholded a block of steps at a time. The membrane history (with
    ``mem0`` as row 0) is saved when small, else only the membrane entering each block. Backward, block by block
    from the end: recompute the block's membranes if needed, evaluate the surrogate derivatives and the step-to-step
    factors ``dU[t]/dU[t-1]`` for the whole block at once, then one multiply-add per step carries dL/dU back.
    Large temporaries are avoided on purpose: on CPU each fresh tensor as large as the input costs about as much in
    page faults as the whole loop. The two that cannot be avoided, the spikes and the input gradient, ask for
    transparent huge pages (:func:`tactile_zoo.nn.memory.empty`): at SGnet's shapes (78 MB each) that took the fused
    forward + backward from 2.1-2.2x to 3.3-3.9x the speed of stepping ``snntorch.Leaky`` (detached reset;
    benchmarks/lif.py on 1 thread, side by side, on a loaded 2-core machine where huge pages come on request).
    """

    @staticmethod
    def forward(ctx, x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, detach_reset: bool,
                surrogate: Surrogate) -> tuple[Tensor, Tensor]:
        spikes, last, saved, layout = _run(x, mem0, beta, threshold, subtract, for_backward=True)
        ctx.save_for_backward(saved, x)
        ctx.cfg = (beta, threshold, subtract, detach_reset, surrogate, *layout)
        ctx.set_materialize_grads(False)  # an unused output needs no zero-filled gradient
        return spikes, last

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_spikes: Tensor | None, grad_mem: Tensor | None) -> tuple[Tensor | None, ...]:
        saved, x = ctx.saved_tensors
        beta, th, subtract, detach_reset, surrogate, block, keep_all, starts = ctx.cfg
        steps, shape = x.shape[0], saved.shape[1:]
        grad = memory.empty((steps, *shape), saved)
        # per-block workspaces, reused (fresh temporaries this size would page-fault on every block)
        u_buf, sg_buf = saved.new_empty((block + 1, *shape)), saved.new_empty((block + 1, *shape))
        decay_buf = saved.new_empty((block, *shape))
        ones, th_up = saved.new_ones(()).expand(block + 1, *shape), _next_up(th, saved.dtype)
        if not keep_all:
            rows_buf = saved.new_empty((block + 1, *shape))
            xs = x.unbind(0)
        carry = grad_mem  # dL/dU[t1 - 1], the gradient reaching the end of the current block from later blocks
        carry_buf = saved.new_empty(shape)
        for j in range(len(starts) - 1, -1, -1):
            t0 = starts[j]
            n = min(t0 + block, steps) - t0
            if keep_all:
                rows = saved[t0:t0 + n + 1]
            else:  # recompute the block's membranes from its checkpoint
                rows = rows_buf[:n + 1]
                out = rows.unbind(0)
                prev = out[0].copy_(saved[j])
                for k in range(n):
                    # the step's reset flags land in decay_buf, where the zero reset's factors start from them
                    prev = _advance(xs[t0 + k], prev, out[k + 1], decay_buf[k], ones[0], beta, th, th_up, subtract)
            u = torch.sub(rows, th, out=u_buf[:n + 1])  # U - U_thr, exactly what snnTorch feeds its surrogate
            sg = surrogate.grad(u, out=sg_buf[:n + 1])  # dS/dU of U[t0-1 .. t0+n-1]
            # dU[t]/dU[t-1] for the block's steps, in units of beta where that helps: the step-to-step path
            if subtract:
                if detach_reset:
                    decay, scale = None, beta
                else:  # beta - U_thr * S'(U[t-1])
                    decay, scale = torch.mul(sg[:-1], -th, out=decay_buf[:n]).add_(beta), 1.0
            else:
                decay = decay_buf[:n]  # 1 - R[t] = (U[t-1] <= U_thr), left there by the recomputation
                if keep_all:
                    open_interval_mask(rows[:-1], -math.inf, th_up, out=decay, ones=ones[:n])
                if not detach_reset:  # beta * (1 - S[t-1]) * U[t-1] also depends on U[t-1] through S[t-1]
                    decay.addcmul_(rows[:-1], sg[:-1], value=-1.0)
                scale = beta
            # grad[t] = dL/dS[t] * S'(U[t]) + grad[t+1] * dU[t+1]/dU[t]
            g = grad[t0:t0 + n]
            if grad_spikes is None:
                g.zero_()
            else:
                torch.mul(grad_spikes[t0:t0 + n], sg[1:], out=g)
            if carry is not None:
                g[-1].add_(carry)
            rows_g = g.unbind(0)
            for k in range(n - 2, -1, -1):
                if decay is None:
                    rows_g[k].add_(rows_g[k + 1], alpha=scale)
                else:
                    rows_g[k].addcmul_(rows_g[k + 1], decay[k + 1], value=scale)
            if decay is None:
                carry = torch.mul(rows_g[0], scale, out=carry_buf)
            else:
                carry = torch.mul(rows_g[0], decay[0], out=carry_buf).mul_(scale)
        return grad, (carry if ctx.needs_input_grad[1] else None), None, None, None, None, None


@functools.cache
def _kernel_module() -> ModuleType | None:
    """:mod:`tactile_zoo.nn._lif_kernel` where it reproduces the fused path bit for bit, else ``None``.

    That is x86-64 with ATen's AVX2 or AVX512 kernels (their FMAs are the ones the kernel copies; the
    ``ATEN_CPU_CAPABILITY=default`` build rounds without them, and other CPUs were not checked) and numba installed.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    if torch.backends.cpu.get_cpu_capability() not in ("AVX2", "AVX512"):
        return None
    try:
        from . import _lif_kernel
    except ImportError:
        return None
    return _lif_kernel


def _kernel_for(x: Tensor, mem: Tensor, surrogate: Surrogate) -> ModuleType | None:
    """The compiled kernel module if it runs this call (see :data:`KERNEL_ENV`), else ``None`` (the torch path)."""
    choice = os.environ.get(KERNEL_ENV, "auto") or "auto"
    if choice not in _KERNEL_CHOICES:
        raise ConfigError(f"{KERNEL_ENV} must be one of {_KERNEL_CHOICES}, got {choice!r}")
    if choice == "torch" or x.device.type != "cpu" or mem.device.type != "cpu":
        return None
    if x.dtype != torch.float32 or mem.dtype != torch.float32 or surrogate.kind not in ("rect", "atan"):
        return None  # float64, and surrogates evaluated by other ATen kernels (sigmoid's exp, custom), stay in torch
    kernels = _kernel_module()
    if kernels is None and choice == "numba":
        raise ConfigError(f"{KERNEL_ENV}=numba, but the compiled LIF kernel is unavailable here (it needs numba, "
                          f"x86-64 and ATen's AVX2 or AVX512 kernels)")
    return kernels


def _kernel_threads(kernels: ModuleType) -> None:
    """Run the kernels on as many threads as torch is given (numba's own pool cannot grow past its start size)."""
    import numba

    n = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    if numba.get_num_threads() != n:
        numba.set_num_threads(n)


#: Serialises kernel launches where numba's threading layer cannot take two at once: its fallback layer
#: ("workqueue", used where neither OpenMP nor TBB loads) aborts the process on concurrent launches from two threads.
_LAUNCH_LOCK = threading.Lock()


def _launch(kernels: ModuleType, name: str, *args: object) -> None:
    """Call compiled kernel ``name`` (``lif_forward`` or ``lif_backward``; ``args[0]`` is the ``(T, N)`` input) on
    torch's thread count: its serial build on one thread, for one block of neurons or for small sequences (a parallel
    launch costs more than it saves there), else the parallel build -- under the lock until numba's threading layer
    is known (it is chosen at the first launch) and for good if that layer is "workqueue"."""
    import numba

    steps, n = args[0].shape
    if torch.get_num_threads() == 1 or n <= kernels.CHUNK or steps * n < kernels.SERIAL_BELOW:
        getattr(kernels, f"{name}_serial")(*args)
        return
    _kernel_threads(kernels)
    try:
        serial = numba.threading_layer() == "workqueue"
    except ValueError:  # no parallel launch yet
        serial = True
    if serial:
        with _LAUNCH_LOCK:
            getattr(kernels, name)(*args)
    else:
        getattr(kernels, name)(*args)


def _kernel_forward(kernels: ModuleType, x: Tensor, mem0: Tensor, beta: float, threshold: float,
                    subtract: bool) -> tuple[Tensor, Tensor]:
    """Spikes ``[T, ...]`` and the last membrane from the compiled forward loop (contiguous float32 CPU inputs)."""
    steps = x.shape[0]
    spikes = memory.empty(x.shape, x)
    last = torch.empty_like(mem0, memory_format=torch.contiguous_format)
    _launch(kernels, "lif_forward", x.detach().view(steps, -1).numpy(), mem0.detach().reshape(-1).numpy(),
            spikes.view(steps, -1).numpy(), last.view(-1).numpy(), *_f32(beta, threshold),
            _f32(_next_up(threshold, torch.float32))[0], subtract, kernels.CHUNK)
    return spikes, last


def _f32(*values: float) -> tuple:
    """Python floats rounded to float32 as ATen rounds a scalar operand of a float32 kernel."""
    import numpy as np

    return tuple(np.float32(v) for v in values)


class _CompiledLIF(torch.autograd.Function):
    """:class:`_FusedLIF` as two compiled calls per sequence (:mod:`tactile_zoo.nn._lif_kernel`): the forward loop,
    and a backward that recomputes the membranes of each block of neurons instead of saving them (the fused path's
    history would be as large as the input). The same inputs, outputs and bit-identical values."""

    @staticmethod
    def forward(ctx, x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, detach_reset: bool,
                surrogate: Surrogate, kernels: ModuleType) -> tuple[Tensor, Tensor]:
        x, mem0 = x.contiguous(), mem0.contiguous()
        spikes, last = _kernel_forward(kernels, x, mem0, beta, threshold, subtract)
        ctx.save_for_backward(x, mem0)
        ctx.cfg = (beta, threshold, subtract, detach_reset, surrogate, kernels)
        ctx.set_materialize_grads(False)
        return spikes, last

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_spikes: Tensor | None, grad_mem: Tensor | None) -> tuple[Tensor | None, ...]:
        import numpy as np

        x, mem0 = ctx.saved_tensors
        beta, th, subtract, detach_reset, surrogate, kernels = ctx.cfg
        steps, n = x.shape[0], mem0.numel()
        # the fused path's block of steps: its gradient crosses block boundaries with a different rounding
        block = max(1, min(steps, BLOCK_BYTES // max(1, n * x.element_size())))
        grad_x = memory.empty(x.shape, x)
        grad_mem0 = torch.empty_like(mem0)
        no_rows, no_row = np.zeros((1, 1), np.float32), np.zeros(1, np.float32)  # stand-ins for absent gradients
        gs = no_rows if grad_spikes is None else grad_spikes.contiguous().view(steps, -1).numpy()
        gm = no_row if grad_mem is None else grad_mem.contiguous().reshape(-1).numpy()
        p = surrogate.param
        if surrogate.kind == "rect":
            kind, lo, hi, c1, c2 = kernels.RECT, *_f32(-p / 2, p / 2), *_f32(0.0, 0.0)
        else:
            kind, lo, hi, c1, c2 = kernels.ATAN, *_f32(0.0, 0.0), *_f32(math.pi / 2 * p, p / 2)
        _launch(kernels, "lif_backward", x.view(steps, -1).numpy(), mem0.view(-1).numpy(), gs,
                grad_spikes is not None, gm, grad_mem is not None, grad_x.view(steps, -1).numpy(),
                grad_mem0.view(-1).numpy(), *_f32(beta, th, _next_up(th, torch.float32)), subtract, detach_reset,
                kind, lo, hi, c1, c2, block, kernels.CHUNK)
        return grad_x, (grad_mem0 if ctx.needs_input_grad[1] else None), None, None, None, None, None, None


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
            see :data:`KERNEL_ENV`) or ``"snntorch"`` (steps ``snntorch.Leaky``).
        input_scale: the input is multiplied by it first (``1/tau`` for the paper's neuron).

    Shapes:
        - input ``x``: ``(T, *)`` time-major, any trailing shape; ``mem``: ``(*)`` or ``None`` (zeros).
        - output: spikes ``(T, *)`` as 0/1 floats; with ``return_mem=True`` also the last membrane ``(*)``, which
          continues the sequence when passed back as ``mem``.
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
        if backend not in _BACKENDS:
            raise ConfigError(f"LIF backend must be one of {_BACKENDS}, got {backend!r}")
        self.beta, self.threshold, self.reset = float(beta), float(threshold), reset
        self.surrogate = make_surrogate(surrogate, surrogate_width, surrogate_alpha, surrogate_slope)
        self.detach_reset, self.backend, self.input_scale = bool(detach_reset), backend, float(input_scale)
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

    def forward(self, x: Tensor, mem: Tensor | None = None, return_mem: bool = False
                ) -> Tensor | tuple[Tensor, Tensor]:
        if x.dim() < 1 or x.shape[0] < 1:
            raise ConfigError(f"MultiStepLIF expects a time-major input (T >= 1, ...), got shape {tuple(x.shape)}")
        if mem is None:
            mem = x.new_zeros(x.shape[1:])
        elif mem.shape != x.shape[1:]:
            raise ConfigError(f"MultiStepLIF: mem has shape {tuple(mem.shape)}, the input's step shape is "
                              f"{tuple(x.shape[1:])}")
        if self.input_scale != 1.0:
            x = x * self.input_scale
        subtract = self.reset == "subtract"
        kernels = _kernel_for(x, mem, self.surrogate) if self.backend == "fused" else None
        grad = torch.is_grad_enabled() and (x.requires_grad or mem.requires_grad)
        if kernels is not None and grad:
            spikes, last = _CompiledLIF.apply(x, mem, self.beta, self.threshold, subtract, self.detach_reset,
                                              self.surrogate, kernels)
        elif kernels is not None:  # nothing to differentiate: the compiled loop without the autograd node
            spikes, last = _kernel_forward(kernels, x.contiguous(), mem.contiguous(), self.beta, self.threshold,
                                           subtract)
        elif self.backend == "fused" and grad:
            spikes, last = _FusedLIF.apply(x, mem, self.beta, self.threshold, subtract, self.detach_reset,
                                           self.surrogate)
        elif self.backend == "fused":  # nothing to differentiate: the same loop without the autograd node
            spikes, last, _, _ = _run(x, mem, self.beta, self.threshold, subtract, False)
        else:
            spikes, last = self._snntorch_loop(x, mem)
        return (spikes, last) if return_mem else spikes

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
