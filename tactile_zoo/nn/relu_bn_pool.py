"""ReLU -> batch norm (training mode, statistics in float64) -> 2x2 max pool, fused: D-CNN's block without its
full-map passes.

D-CNN stacks conv -> ReLU -> batch norm -> 2x2 "same" max pool three times; on Ev-Objects the first two maps are
about 310 MiB each at batch 128. Apart, the three layers pass over such a map about nine times forward (ReLU in
place, the statistics, centring, scaling, pooling) and a dozen times backward, each pass a fresh full-size tensor
whose pages fault in. Fused (:mod:`tactile_zoo.nn._kernels.bn_pool`), on a channels-last map::

    r     = relu(x)                                   # never written
    mean  = sum(r) / M,  var = sum(r^2) / M - mean^2  # one pass, accumulated in float64 per channel
    y     = r * a + s,   a = w / sqrt(var + eps), s = b - mean * a
    out   = max over each 2x2 window of y             # = a * (the window's largest r) + s where a >= 0 (its
                                                      #   smallest where a < 0): the affine map is monotone
    dx    = [x > 0] * a * (dy - mean(dy) - xhat * mean(dy * xhat)),  xhat = (r - mean) / sqrt(var + eps)

with ``dy`` the pooled gradient at each window's picked place and zero elsewhere, so its two means are sums over the
pooled map. Forward: two reads of the map and a quarter-size output; backward: one read and one write.

Not bit for bit the layers apart: the statistics are sums in float64 of one pass (``E[r^2] - E[r]^2`` in float64,
exact to far below float32's rounding for these maps) where the ``two_pass`` path sums pairwise in float32, and ``y``
rounds as ``r * a + s``. So D-CNN takes it as a revision of its own; its accuracy is checked against a float64 copy
(tests/nn/test_relu_bn_pool.py). CPU, float32, channels-last input, affine batch norm; elsewhere the caller runs the
layers apart.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from . import backend as switch
from .hugepages import empty

__all__ = ["relu_bn_pool", "fusable"]


def fusable(x: Tensor, weight: Tensor | None) -> bool:
    """Whether :func:`relu_bn_pool` runs for this input: a plain float32 CPU map, channels-last, affine weights, and
    the compiled kernels present."""
    return (type(x) is Tensor and x.device.type == "cpu" and x.dtype == torch.float32 and x.dim() == 4
            and x.is_contiguous(memory_format=torch.channels_last) and weight is not None
            and not torch.compiler.is_compiling() and not torch.jit.is_tracing()
            and switch.bn_pool_kernels() is not None)


def relu_bn_pool(x: Tensor, weight: Tensor, bias: Tensor, eps: float) -> tuple[Tensor, Tensor, Tensor]:
    """``max_pool2d(batch_norm(relu(x)), 2, ceil_mode=True)`` in training mode, fused (module docstring).

    Args:
        x: the map, channels-last (:func:`fusable`).
        weight, bias: the batch norm's affine parameters ``(C,)``.
        eps: added to the variance.

    Returns:
        The pooled output ``(B, C, ceil(H / 2), ceil(W / 2))`` (channels-last), and the batch's mean and biased
        variance ``(C,)`` in float64, without gradient (for the running statistics).
    """
    return _ReLUBNPool.apply(x, weight, bias, eps)


def _run(name: str, batch: int, *args: Any) -> None:
    switch.launch(switch.bn_pool_kernels(), name, *args, serial=batch == 1)


class _ReLUBNPool(torch.autograd.Function):

    @staticmethod
    def forward(ctx: Any, x: Tensor, weight: Tensor, bias: Tensor, eps: float) -> tuple[Tensor, Tensor, Tensor]:
        batch, chans, height, width = x.shape
        pixels = x.detach().permute(0, 2, 3, 1)  # (B, H, W, C): the channels-last memory itself
        sums, squares = torch.empty(batch, chans, dtype=torch.float64), torch.empty(batch, chans, dtype=torch.float64)
        _run("relu_sums", batch, pixels.numpy(), sums.numpy(), squares.numpy())
        count = batch * height * width
        mean = sums.sum(0) / count
        var = (squares.sum(0) / count - mean * mean).clamp_min_(0.0)
        invstd = (var + eps).rsqrt()
        scale = weight.detach().double() * invstd
        shift = bias.detach().double() - mean * scale
        pooled = (batch, -(-height // 2), -(-width // 2), chans)  # (B, H', W', C)
        out, picked = torch.empty(pooled), torch.empty(pooled)
        which = torch.empty(pooled, dtype=torch.int8)
        _run("relu_bn_pool", batch, pixels.numpy(), scale.float().numpy(), shift.float().numpy(), out.numpy(),
             picked.numpy(), which.numpy())
        ctx.save_for_backward(x, picked, which, mean, invstd, weight)
        ctx.mark_non_differentiable(mean, var)
        return out.permute(0, 3, 1, 2), mean, var  # (B, C, H', W') with channels-last strides

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: Any, grad: Tensor, _mean: Tensor, _var: Tensor) -> tuple[Tensor | None, ...]:
        x, picked, which, mean, invstd, weight = ctx.saved_tensors
        batch, chans, height, width = x.shape
        g = grad.permute(0, 2, 3, 1).contiguous()  # (B, H', W', C)
        sums, products = torch.empty(batch, chans, dtype=torch.float64), torch.empty(batch, chans, dtype=torch.float64)
        _run("picked_sums", batch, g.numpy(), picked.numpy(), mean.numpy(), invstd.numpy(), sums.numpy(),
             products.numpy())
        grad_bias, grad_weight = sums.sum(0), products.sum(0)  # sum(dy), sum(dy * xhat)
        count = batch * height * width
        grad_x = None
        if ctx.needs_input_grad[0]:
            gain = weight.detach().double() * invstd
            grad_x = empty((batch, height, width, chans), x)  # huge pages where granted: it is written whole
            _run("relu_bn_pool_backward", batch, x.detach().permute(0, 2, 3, 1).numpy(), g.numpy(), which.numpy(),
                 mean.float().numpy(), invstd.float().numpy(), gain.float().numpy(),
                 (grad_bias / count).float().numpy(), (grad_weight / count).float().numpy(), grad_x.numpy())
            grad_x = grad_x.permute(0, 3, 1, 2)  # (B, C, H, W), channels-last
        return grad_x, grad_weight.to(weight.dtype), grad_bias.to(weight.dtype), None
