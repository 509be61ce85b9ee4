"""Batch normalisation whose training-mode statistics are accurate to float64 on the CPU, in any memory layout.

``torch.nn.BatchNorm2d`` on the CPU computes a training batch's statistics (and, in the backward pass, the sums of
the gradient) with kernels whose accuracy depends on the layout. On a channels-last map, whose memory is rows
``(B*H*W, C)``, the kernel adds the rows one after another in float32. For D-CNN's maps (hundreds of thousands of
rows per channel) that gave scores 3.0e-2 from a float64 copy of the same step and weight gradients 9 % off, relative
to the largest (``python -m tools.dcnn_precision``); the NCHW layout, whose kernel sums pairwise, was within 2e-5 and
3e-4.

:class:`BatchNorm1d` and :class:`BatchNorm2d` are ``nn.BatchNorm1d``/``nn.BatchNorm2d`` (same parameters, buffers and
``state_dict``, same evaluation-mode path) with a ``stats`` keyword (:class:`~tactile_zoo.nn.backend.BatchNormStats`)
choosing how a training batch is normalised:

- ``native``: torch's kernel (the default; bit for bit ``nn.BatchNorm``);
- ``two_pass``: float32 sums in torch's pairwise (cascade) reduction over the rows, the variance as the mean square
  of the centred rows (no cancellation), and batch norm's own backward formula with the same sums;
- ``float64``: the same passes with every sum accumulated in float64 (each block of rows is widened on its own).

The two accurate forms work on the rows view of the input (free for a channels-last map), block by block, so they
keep no more than ``nn.BatchNorm`` does for the backward pass (the input, and a mean and an inverse deviation per
channel) and allocate no full-size temporaries besides the output (forward) and the input's gradient (backward).
The running estimates follow the batch statistics as ``nn.BatchNorm``'s do (``momentum``; ``None``: a cumulative
average; the running variance unbiased).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from .backend import BatchNormStats, resolve
from .relu_bn_pool import fusable, relu_bn_pool

__all__ = ["BatchNorm1d", "BatchNorm2d", "batch_norm_rows"]

#: elements per block of rows: the accurate passes widen or multiply one block at a time (4 MiB of float32)
BLOCK = 1 << 20


def _blocks(rows: Tensor) -> tuple[Tensor, ...]:
    return rows.split(max(1, BLOCK // max(1, rows.shape[1])))


def _column_sum(rows: Tensor, acc: torch.dtype, centre: Tensor | None = None, square: bool = False) -> Tensor:
    """Per-column sums of ``rows`` (minus ``centre``, squared with ``square``) accumulated in ``acc``, block by block
    (one block at a time is widened or squared); torch sums each block pairwise, and the block sums are added
    pairwise too."""
    parts = []
    for block in _blocks(rows):
        value = block.to(acc)
        if centre is not None:
            value = value - centre
        parts.append((value.square() if square else value).sum(0))
    return torch.stack(parts).sum(0)


class _AccurateBatchNorm(torch.autograd.Function):
    """Training-mode batch norm of rows ``(M, C)`` with accurate sums; returns ``(y, mean, biased variance)``,
    the statistics in ``acc`` and without gradient."""

    @staticmethod
    def forward(ctx: Any, rows: Tensor, weight: Tensor, bias: Tensor, eps: float,
                acc: torch.dtype) -> tuple[Tensor, Tensor, Tensor]:
        m = rows.shape[0]
        mean = _column_sum(rows, acc) / m
        out = torch.sub(rows, mean.to(rows.dtype))  # the centred rows, scaled in place below
        # the mean square of the centred rows; in float64 centred again in the wide type (the float32 centring rounds)
        var = (_column_sum(out, acc, square=True) if acc == rows.dtype else
               _column_sum(rows, acc, centre=mean, square=True)) / m
        invstd = torch.rsqrt(var + eps)
        out.mul_((weight.to(acc) * invstd).to(rows.dtype)).add_(bias)
        ctx.save_for_backward(rows, mean, invstd, weight)
        ctx.acc = acc
        ctx.mark_non_differentiable(mean, var)
        return out, mean, var

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor, _mean: Tensor, _var: Tensor) -> tuple[Tensor | None, ...]:
        rows, mean, invstd, weight = ctx.saved_tensors
        acc, m = ctx.acc, rows.shape[0]
        grad = grad.contiguous()
        grad_bias = _column_sum(grad, acc)  # sum(dy)
        # sum(dy * (x - mean)), block by block: no full-size product
        dot = torch.stack([((x.to(acc) - mean) * g.to(acc)).sum(0)
                           for x, g in zip(_blocks(rows), _blocks(grad))]).sum(0)
        grad_weight = dot * invstd  # sum(dy * xhat)
        grad_rows = None
        if ctx.needs_input_grad[0]:  # w / std * (dy - mean(dy) - xhat * mean(dy * xhat)): batch norm's own formula
            scale = weight.to(acc) * invstd
            grad_rows = torch.sub(rows, mean.to(rows.dtype))
            grad_rows.mul_((-invstd * grad_weight / m).to(rows.dtype)).add_(grad)
            grad_rows.sub_((grad_bias / m).to(rows.dtype)).mul_(scale.to(rows.dtype))
        return (grad_rows, grad_weight.to(weight.dtype), grad_bias.to(weight.dtype), None, None)


def batch_norm_rows(rows: Tensor, weight: Tensor, bias: Tensor, eps: float,
                    stats: BatchNormStats) -> tuple[Tensor, Tensor, Tensor]:
    """Training-mode batch norm of rows ``(M, C)`` (statistics per column) with the accurate ``stats``
    (``two_pass`` or ``float64``): ``(y, mean, biased variance)``, the statistics without gradient."""
    acc = torch.float64 if stats is BatchNormStats.FLOAT64 else rows.dtype
    return _AccurateBatchNorm.apply(rows.contiguous(), weight, bias, eps, acc)


class _StatsChoice:
    """The ``stats`` choice of the two classes below, on top of an ``nn.BatchNorm`` class."""

    stats: BatchNormStats

    def forward(self, x: Tensor) -> Tensor:
        bn: Any = self
        if self.stats is BatchNormStats.NATIVE or not bn.training or bn.running_mean is None:
            return super().forward(x)  # type: ignore[misc]
        bn._check_input_dim(x)
        c = bn.num_features
        # rows (M, C): a view of a channels-last map ((B, H, W, C) in memory), a copy of an NCHW or (B, C, L) one
        rows = x if x.dim() == 2 else x.movedim(1, -1).reshape(-1, c)
        if rows.shape[0] < 2:
            return super().forward(x)  # type: ignore[misc]  # torch's error: one value per channel
        weight = bn.weight if bn.weight is not None else x.new_ones(c)
        bias = bn.bias if bn.bias is not None else x.new_zeros(c)
        out, mean, var = batch_norm_rows(rows, weight, bias, bn.eps, self.stats)
        self._track(mean, var, rows.shape[0])
        if x.dim() == 2:
            return out
        y = out.view(x.shape[0], *x.shape[2:], c).movedim(-1, 1)  # (B, C, ...) with channels-last strides
        # the input's layout, as nn.BatchNorm keeps it (a copy for an NCHW or (B, C, L) input)
        return y if x.dim() == 4 and x.is_contiguous(memory_format=torch.channels_last) else y.contiguous()

    def _track(self, mean: Tensor, var: Tensor, m: int) -> None:
        """The running statistics' update from a training batch's ``mean`` and biased ``var`` over ``m`` values per
        channel, as ``nn.BatchNorm`` makes it (``momentum``; ``None``: a cumulative average; the variance unbiased)."""
        bn: Any = self
        bn.num_batches_tracked.add_(1)
        momentum = 1.0 / float(bn.num_batches_tracked) if bn.momentum is None else bn.momentum
        with torch.no_grad():
            bn.running_mean.lerp_(mean.to(bn.running_mean.dtype), momentum)
            bn.running_var.lerp_((var * (m / (m - 1))).to(bn.running_var.dtype), momentum)

    def relu_pool(self, x: Tensor) -> Tensor | None:
        """``max_pool2d(self(relu(x)), 2, ceil_mode=True)`` for a training batch, fused where
        :func:`~tactile_zoo.nn.relu_bn_pool.fusable` says it can be (statistics in float64; the running statistics
        updated as :meth:`forward` updates them), else ``None``: the caller then runs the layers apart."""
        bn: Any = self
        m = x.shape[0] * x.shape[2] * x.shape[3] if x.dim() == 4 else 0  # values per channel
        if not bn.training or bn.running_mean is None or m < 2 or not fusable(x, bn.weight):
            return None
        out, mean, var = relu_bn_pool(x, bn.weight, bn.bias, bn.eps)
        self._track(mean, var, m)
        return out


class BatchNorm1d(_StatsChoice, nn.BatchNorm1d):
    """``nn.BatchNorm1d`` (``(B, C)`` or ``(B, C, L)`` inputs) with a choice of training statistics (module
    docstring).

    Args:
        num_features, eps, momentum, affine: as ``nn.BatchNorm1d`` (running statistics are always tracked).
        stats: :class:`~tactile_zoo.nn.backend.BatchNormStats`: ``native``, ``two_pass`` or ``float64``.
    """

    def __init__(self, num_features: int, eps: float = 1e-5, momentum: float | None = 0.1, affine: bool = True,
                 stats: BatchNormStats | str = "native") -> None:
        super().__init__(num_features, eps=eps, momentum=momentum, affine=affine)
        self.stats = resolve(BatchNormStats, stats, "stats", type(self).__name__)


class BatchNorm2d(_StatsChoice, nn.BatchNorm2d):
    """``nn.BatchNorm2d`` with a choice of training statistics (module docstring).

    Args:
        num_features, eps, momentum, affine: as ``nn.BatchNorm2d`` (running statistics are always tracked).
        stats: :class:`~tactile_zoo.nn.backend.BatchNormStats`: ``native``, ``two_pass`` or ``float64``.
    """

    def __init__(self, num_features: int, eps: float = 1e-5, momentum: float | None = 0.1, affine: bool = True,
                 stats: BatchNormStats | str = "native") -> None:
        super().__init__(num_features, eps=eps, momentum=momentum, affine=affine)
        self.stats = resolve(BatchNormStats, stats, "stats", type(self).__name__)

