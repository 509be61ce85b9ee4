"""Threshold-dependent batch normalisation (tdBN) for spiking networks, over every frame of a sequence at once.

Zheng, Wu, Deng, Hu and Li, "Going Deeper With Directly-Trained Larger Spiking Neural Networks", AAAI 2021. A
spiking layer's pre-activations ``x (T, *, F)`` are normalised per feature channel over the time steps as well as
the batch and the spatial positions, then scaled to the neurons' firing threshold::

    x_hat = alpha * V_th * (x - E[x]) / sqrt(Var[x] + eps)      statistics over every dimension but F
    y     = lambda * x_hat + beta                               lambda, beta learned per channel (1 and 0 at start)

In training mode ``E[x]`` and ``Var[x]`` (biased) are the batch's own, and the running estimates follow them with
``momentum`` (the running variance unbiased), exactly as ``nn.BatchNorm`` does; in evaluation mode the running
estimates are used, which makes the layer an affine map per channel, frame by frame (so a network built from it can
stream). Because the statistics pool over all dimensions but the last, the layout of the leading dimensions
(time-major or batch-major, nodes or pixels) does not matter.

The parameters and buffers (``weight``, ``bias``, ``running_mean``, ``running_var``, ``num_batches_tracked``) are
those of an ``nn.BatchNorm1d``, whose ``state_dict`` the layer shares. In evaluation mode it runs
``torch.nn.functional.batch_norm`` with the weight ``alpha * V_th * lambda``. In training mode it does not: on CPU,
``batch_norm`` of rows ``(M, F)`` (the channels-last case) sums the statistics in float32 one row after another, and
on rows of a tactile sequence batch (M = 39000 rows: T = 250, batch 4, 39 taxels, 176 channels) its variance was off by
1.3e-5 relative and its outputs by 1.5e-5 (measured against float64), 40x worse than a two-pass sum. So the
statistics are computed in two passes over the rows (the mean, then the mean square of the centred rows: 3e-7
relative, about as accurate as ``batch_norm`` of the ``(1, F, M)`` layout, without its transposed copies, and faster
than ``torch.var_mean``, whose reduction over rows runs scalar), and the backward is batch norm's own formula
(:class:`_TdBNTrain`).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from ..errors import ConfigError

__all__ = ["TdBatchNorm"]


class TdBatchNorm(nn.BatchNorm1d):
    """Threshold-dependent batch normalisation: batch norm per channel over time, batch and space, scaled by
    ``alpha * threshold``.

    Args:
        num_features: channels ``F`` (the last dimension of the input).
        threshold: the firing threshold ``V_th`` of the neurons the layer feeds.
        alpha: the extra factor of the paper (1 for a layer that feeds a neuron directly; the paper uses
            ``1 / sqrt(2)`` before a residual sum).
        eps: added to the variance.
        momentum: of the running estimates (``nn.BatchNorm``'s convention: ``new = (1 - m) old + m batch``).
        affine: learn ``lambda`` and ``beta``.

    Shapes:
        - input: ``(*, F)``, any leading dimensions (e.g. ``T, B, N``); at least two rows in training mode.
        - output: ``(*, F)``.
    """

    def __init__(self, num_features: int, threshold: float = 0.5, alpha: float = 1.0, eps: float = 1e-5,
                 momentum: float = 0.1, affine: bool = True) -> None:
        if not threshold > 0 or not alpha > 0:
            raise ConfigError(f"TdBatchNorm needs threshold > 0 and alpha > 0, got {threshold!r} and {alpha!r}")
        super().__init__(num_features, eps=eps, momentum=momentum, affine=affine, track_running_stats=True)
        self.threshold, self.alpha = float(threshold), float(alpha)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, threshold={self.threshold:g}, alpha={self.alpha:g}"

    def forward(self, x: Tensor) -> Tensor:
        if x.dim() < 1 or x.shape[-1] != self.num_features:
            raise ConfigError(f"TdBatchNorm expects (..., {self.num_features}) inputs, got {tuple(x.shape)}")
        scale = self.alpha * self.threshold
        if self.weight is None:  # not affine: the scale alone, as a constant weight
            weight = x.new_full((self.num_features,), scale)
        else:
            weight = self.weight * scale
        bias = self.bias if self.bias is not None else x.new_zeros(self.num_features)
        rows = x.reshape(-1, self.num_features)  # (M, F): the statistics pool over every leading dimension
        if not self.training:
            return F.batch_norm(rows, self.running_mean, self.running_var, weight, bias, False, 0.0,
                                self.eps).view(x.shape)
        if rows.shape[0] < 2:
            raise ConfigError(f"TdBatchNorm in training mode needs at least 2 values per channel, got input "
                              f"{tuple(x.shape)}")
        out, mean, var = _TdBNTrain.apply(rows, weight, bias, self.eps)
        self.num_batches_tracked.add_(1)
        # nn.BatchNorm's convention: momentum None is a cumulative average; the running variance is unbiased
        momentum = 1.0 / float(self.num_batches_tracked) if self.momentum is None else self.momentum
        m = rows.shape[0]
        with torch.no_grad():
            self.running_mean.lerp_(mean.to(self.running_mean.dtype), momentum)
            self.running_var.lerp_((var * (m / (m - 1))).to(self.running_var.dtype), momentum)
        return out.view(x.shape)


class _TdBNTrain(torch.autograd.Function):
    """Training-mode batch norm of rows ``(M, F)`` with accurate statistics (see the module docstring); returns
    ``(y, mean, biased variance)``, the last two without gradient."""

    @staticmethod
    def forward(ctx: Any, rows: Tensor, weight: Tensor, bias: Tensor, eps: float) -> tuple[Tensor, Tensor, Tensor]:
        m = rows.shape[0]
        mean = rows.sum(0).div_(m)
        xhat = rows - mean  # centred first, then squared: the two-pass variance, no cancellation
        var = xhat.square().sum(0).div_(m)
        invstd = torch.rsqrt(var + eps)
        xhat.mul_(invstd)
        ctx.save_for_backward(xhat, invstd, weight)
        ctx.mark_non_differentiable(mean, var)
        return torch.addcmul(bias, xhat, weight), mean, var

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor, _mean: Tensor, _var: Tensor) -> tuple[Tensor | None, ...]:
        xhat, invstd, weight = ctx.saved_tensors
        m = xhat.shape[0]
        grad_bias = grad.sum(0)
        grad_weight = (grad * xhat).sum(0)
        grad_rows = None
        if ctx.needs_input_grad[0]:  # w / std * (dy - mean(dy) - xhat * mean(dy * xhat)): batch norm's own formula
            grad_rows = torch.addcmul(grad, xhat, grad_weight / -m).sub_(grad_bias / m).mul_(weight * invstd)
        return grad_rows, grad_weight, grad_bias, None
