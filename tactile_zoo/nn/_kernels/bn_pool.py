"""ReLU -> training-mode batch norm -> 2x2 max pool ("same", ceil mode) over a channels-last map, compiled by numba:
the statistics in one pass, the pooled output in a second, the input gradient in one pass backward.

Run by :mod:`tactile_zoo.nn.relu_bn_pool`; nothing here is public. The map is ``(B, H, W, C)`` in memory (a
channels-last ``(B, C, H, W)`` tensor), so every inner loop runs over the ``C`` contiguous channels of one pixel and
vectorises. Work items are images (``prange`` over ``B``); per-image partial sums are added afterwards, in float64.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .jit import CSR_MODE, get_csr, jit, serial_copy, set_csr

__all__ = ["relu_sums", "relu_bn_pool", "picked_sums", "relu_bn_pool_backward", "relu_sums_serial",
           "relu_bn_pool_serial", "picked_sums_serial", "relu_bn_pool_backward_serial"]


def relu_sums(x: np.ndarray, sums: np.ndarray, squares: np.ndarray) -> None:
    """Per image and channel, the float64 sums of ``relu(x)`` and of its square: ``x (B, H, W, C)`` float32 in,
    ``sums`` and ``squares`` ``(B, C)`` float64 out."""
    batch, height, width, chans = x.shape
    for b in prange(batch):
        s = np.zeros(chans, dtype=np.float64)
        q = np.zeros(chans, dtype=np.float64)
        for i in range(height):
            for j in range(width):
                px = x[b, i, j]
                for c in range(chans):
                    v = np.float64(max(px[c], np.float32(0.0)))
                    s[c] += v
                    q[c] += v * v
        sums[b] = s
        squares[b] = q


def relu_bn_pool(x: np.ndarray, scale: np.ndarray, shift: np.ndarray, out: np.ndarray, picked: np.ndarray,
                 which: np.ndarray) -> None:
    """``out = max over each 2x2 window of (relu(x) * scale + shift)``, per channel: the window's largest ``relu(x)``
    where ``scale >= 0``, its smallest where not (the affine map is monotone), the first in scan order on ties.
    ``picked`` receives that ``relu(x)`` and ``which`` its place in the window (``2 * di + dj``); ``out``, ``picked``
    and ``which`` are ``(B, ceil(H / 2), ceil(W / 2), C)``."""
    batch, height, width, chans = x.shape
    zero = np.float32(0.0)
    csr = get_csr() & CSR_MODE
    for b in prange(batch):
        own = get_csr()
        set_csr(csr)  # the caller's denormal and rounding modes
        for oi in range(out.shape[1]):
            for oj in range(out.shape[2]):
                best = picked[b, oi, oj]
                where = which[b, oi, oj]
                first = x[b, 2 * oi, 2 * oj]
                for c in range(chans):
                    best[c] = max(first[c], zero)
                    where[c] = 0
                for k in range(1, 4):
                    i, j = 2 * oi + k // 2, 2 * oj + k % 2
                    if i >= height or j >= width:
                        continue
                    px = x[b, i, j]
                    for c in range(chans):
                        v = max(px[c], zero)
                        better = v > best[c] if scale[c] >= zero else v < best[c]
                        best[c] = v if better else best[c]
                        where[c] = k if better else where[c]
                dst = out[b, oi, oj]
                for c in range(chans):
                    dst[c] = best[c] * scale[c] + shift[c]
        set_csr(own)


def picked_sums(grad: np.ndarray, picked: np.ndarray, mean: np.ndarray, invstd: np.ndarray, sums: np.ndarray,
                products: np.ndarray) -> None:
    """Per image and channel, the float64 sums of the pooled gradient ``grad`` and of ``grad * xhat`` at the picked
    places, ``xhat = (picked - mean) * invstd`` (``mean``, ``invstd`` float64): the only places where the batch
    norm's output gradient is not zero. ``grad`` and ``picked`` are ``(B, H', W', C)``; ``sums``, ``products``
    ``(B, C)``."""
    batch, height, width, chans = grad.shape
    for b in prange(batch):
        s = np.zeros(chans, dtype=np.float64)
        q = np.zeros(chans, dtype=np.float64)
        for i in range(height):
            for j in range(width):
                g, p = grad[b, i, j], picked[b, i, j]
                for c in range(chans):
                    dy = np.float64(g[c])
                    s[c] += dy
                    q[c] += dy * ((np.float64(p[c]) - mean[c]) * invstd[c])
        sums[b] = s
        products[b] = q


def relu_bn_pool_backward(x: np.ndarray, grad: np.ndarray, which: np.ndarray, mean: np.ndarray, invstd: np.ndarray,
                          gain: np.ndarray, mean_grad: np.ndarray, mean_grad_xhat: np.ndarray,
                          grad_x: np.ndarray) -> None:
    """dL/dx of :func:`relu_bn_pool` from the pooled gradient ``grad``: batch norm's training-mode formula
    ``gain * (dy - mean(dy) - xhat * mean(dy * xhat))`` with ``dy`` the pooled gradient at each window's picked
    place and 0 elsewhere, ``xhat = (relu(x) - mean) * invstd`` and ``gain = weight * invstd``, then ReLU's mask
    ``x > 0``. Every argument per channel is float32; ``grad_x`` is ``(B, H, W, C)``."""
    batch, height, width, chans = x.shape
    zero = np.float32(0.0)
    csr = get_csr() & CSR_MODE
    for b in prange(batch):
        own = get_csr()
        set_csr(csr)
        for i in range(height):
            oi = i // 2
            for j in range(width):
                k = 2 * (i % 2) + j % 2
                oj = j // 2
                px, g, w, dst = x[b, i, j], grad[b, oi, oj], which[b, oi, oj], grad_x[b, i, j]
                for c in range(chans):
                    v = px[c]
                    dy = g[c] if w[c] == k else zero
                    xhat = (max(v, zero) - mean[c]) * invstd[c]
                    d = gain[c] * (dy - mean_grad[c] - xhat * mean_grad_xhat[c])
                    dst[c] = d if v > zero else zero
        set_csr(own)


relu_sums_serial = serial_copy(relu_sums)
relu_bn_pool_serial = serial_copy(relu_bn_pool)
relu_bn_pool_backward_serial = serial_copy(relu_bn_pool_backward)
picked_sums_serial = serial_copy(picked_sums)
picked_sums = jit(picked_sums, parallel=True)
relu_sums = jit(relu_sums, parallel=True)
relu_bn_pool = jit(relu_bn_pool, parallel=True)
relu_bn_pool_backward = jit(relu_bn_pool_backward, parallel=True)
