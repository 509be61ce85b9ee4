"""The compiled LIF path: the forward and the backward time loops as one numba call per sequence each
(:mod:`tactile_zoo.nn._kernels.lif`), bit-identical to the fused torch path (:mod:`.lif_fused`), which it falls back
to where it does not apply. Where it runs is decided in :func:`tactile_zoo.nn.backend.lif_kernels_for` (the
``TACTILE_ZOO_LIF_BACKEND`` override included)."""

from __future__ import annotations

import math
from types import ModuleType

import torch
from torch import Tensor

from . import backend as switch
from . import hugepages, lif_fused, storage_pool
from .surrogate import Surrogate

__all__ = ["CompiledLIF", "compiled_forward", "surrogate_args", "f32"]


def _launch(kernels: ModuleType, name: str, *args: object) -> None:
    """:func:`~tactile_zoo.nn.backend.launch` of ``lif_forward`` or ``lif_backward`` (``args[0]`` is the ``(T, N)``
    input): serial for one block of neurons or for small sequences, where a parallel launch costs more than it saves."""
    steps, n = args[0].shape
    switch.launch(kernels, name, *args, serial=n <= kernels.CHUNK or steps * n < kernels.SERIAL_BELOW)


def _forward_chunk(kernels: ModuleType, n: int) -> int:
    """Neurons per work item of the forward: whole rows up to ``FORWARD_CHUNK``, split evenly, and at least one item
    per thread (rounded up to 16 neurons: whole 64-byte cache lines)."""
    items = max(-(-n // kernels.FORWARD_CHUNK), torch.get_num_threads() if n > kernels.CHUNK else 1)
    per_item = -(-n // items)  # ceil
    return max(16, -(-per_item // 16) * 16)


def compiled_forward(kernels: ModuleType, x: Tensor, mem0: Tensor, beta: float, threshold: float,
                    subtract: bool, checkpoints: bool = False, input_scale: float = 1.0, reuse: bool = False
                    ) -> tuple[Tensor, Tensor, Tensor | None]:
    """Spikes ``[T, ...]``, the last membrane and, with ``checkpoints``, the membrane checkpoints the compiled backward
    recomputes from (``(rows, N)``), from the compiled forward loop (contiguous float32 CPU inputs); the input current
    is ``x * input_scale``. With ``reuse`` the spikes come from :func:`tactile_zoo.nn.storage_pool.reusable`."""
    import numpy as np

    steps = x.shape[0]
    spikes = storage_pool.reusable(x.shape, x) if reuse else hugepages.empty(x.shape, x)
    last = torch.empty_like(mem0, memory_format=torch.contiguous_format)
    ckpt = torch.empty(kernels.checkpoint_rows(steps), mem0.numel(), dtype=torch.float32) if checkpoints else None
    _launch(kernels, "lif_forward", x.detach().view(steps, -1).numpy(), mem0.detach().reshape(-1).numpy(),
            spikes.view(steps, -1).numpy(), last.view(-1).numpy(),
            np.zeros((1, 1), np.float32) if ckpt is None else ckpt.numpy(), checkpoints, *f32(beta, threshold),
            f32(lif_fused.next_up(threshold, torch.float32))[0], subtract, _forward_chunk(kernels, int(mem0.numel())),
            *f32(input_scale), input_scale != 1.0)
    return spikes, last, ckpt


def surrogate_args(kernels: ModuleType, surrogate: Surrogate) -> tuple:
    """The surrogate as the backward kernels take it: its kind, the ``rect`` window ``(lo, hi)`` and ``atan``'s two
    constants, as float32."""
    p = surrogate.param
    if surrogate.kind == "rect":
        return (kernels.RECT, *f32(-p / 2, p / 2), *f32(0.0, 0.0))
    return (kernels.ATAN, *f32(0.0, 0.0), *f32(math.pi / 2 * p, p / 2))



def f32(*values: float) -> tuple:
    """Python floats rounded to float32 as ATen rounds a scalar operand of a float32 kernel."""
    import numpy as np

    return tuple(np.float32(v) for v in values)


class CompiledLIF(torch.autograd.Function):
    """:class:`~tactile_zoo.nn.lif_fused.FusedLIF` as two compiled calls per sequence (:mod:`._kernels.lif`): the
    forward loop, which also keeps a membrane checkpoint every few steps, and a backward that recomputes the
    membranes between checkpoints instead of saving them all (the fused path's history would be as large as the
    input). The same inputs, outputs and bit-identical values; with ``input_scale`` the input current is ``x *
    input_scale``, folded into both loops (the same float32 multiplies as the separate ``x * input_scale`` and its
    backward, so the same bits, without the two extra passes over tensors as large as ``x``).

    Spikes and input gradient come from :func:`tactile_zoo.nn.storage_pool.reusable`: storages of earlier calls that
    nothing refers to any more, so that training does not page-fault on fresh outputs every batch."""

    @staticmethod
    def forward(ctx, x: Tensor, mem0: Tensor, beta: float, threshold: float, subtract: bool, detach_reset: bool,
                surrogate: Surrogate, kernels: ModuleType, input_scale: float = 1.0) -> tuple[Tensor, Tensor]:
        x, mem0 = x.contiguous(), mem0.contiguous()
        spikes, last, ckpt = compiled_forward(kernels, x, mem0, beta, threshold, subtract, checkpoints=True,
                                             input_scale=input_scale, reuse=True)
        ctx.save_for_backward(x, ckpt)
        ctx.mem_shape = mem0.shape
        ctx.cfg = (beta, threshold, subtract, detach_reset, surrogate, kernels, input_scale)
        ctx.set_materialize_grads(False)
        return spikes, last

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_spikes: Tensor | None, grad_mem: Tensor | None) -> tuple[Tensor | None, ...]:
        import numpy as np

        x, ckpt = ctx.saved_tensors
        beta, th, subtract, detach_reset, surrogate, kernels, input_scale = ctx.cfg
        steps, n = x.shape[0], ckpt.shape[1]
        block = lif_fused.block_steps(steps, n * x.element_size())  # the fused path's blocks: the same rounding
        grad_x = storage_pool.reusable(x.shape, x)
        grad_mem0 = x.new_empty(ctx.mem_shape)
        no_rows, no_row = np.zeros((1, 1), np.float32), np.zeros(1, np.float32)  # stand-ins for absent gradients
        gs = no_rows if grad_spikes is None else grad_spikes.contiguous().view(steps, -1).numpy()
        gm = no_row if grad_mem is None else grad_mem.contiguous().reshape(-1).numpy()
        kind, lo, hi, c1, c2 = surrogate_args(kernels, surrogate)
        _launch(kernels, "lif_backward", x.view(steps, -1).numpy(), ckpt.numpy(), gs,
                grad_spikes is not None, gm, grad_mem is not None, grad_x.view(steps, -1).numpy(),
                grad_mem0.view(-1).numpy(), *f32(beta, th, lif_fused.next_up(th, torch.float32)), subtract,
                detach_reset, kind, lo, hi, c1, c2, block, kernels.CHUNK, *f32(input_scale), input_scale != 1.0)
        return grad_x, (grad_mem0 if ctx.needs_input_grad[1] else None), None, None, None, None, None, None, None


