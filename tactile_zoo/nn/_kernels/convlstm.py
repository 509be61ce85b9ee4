"""Per-step ConvLSTM kernels for CPU, compiled by numba: the work of a time step around its one matrix product.

Loaded lazily (:func:`tactile_zoo.nn.backend.convlstm_kernels`) for ConvLSTM's ``backend="compiled"``
(:mod:`tactile_zoo.nn.convlstm_compiled`); nothing here is public. Arrays are channel-major as in the fused backend:
a state is ``(h, N)`` with ``N = B*H*W`` (sample-major, then the cells of the grid row by row), the pre-activations
``(4h, N)`` in gate order i, f, o, g, and the im2col matrix of a state ``(h*k*k, N)``, row ``j*k*k + dr*k + dc``
holding tap ``(dr, dc)`` of channel ``j`` around every cell.

Within one sample's grid, tap ``(dr, dc)`` of the im2col matrix is the state row shifted by ``dr*W + dc``: each im2col
row is one contiguous shifted copy, after which the positions outside the grid ("same" zero padding, where the shift
wrapped into a neighbouring grid row or sample) are zeroed; no index array and no zero column are read.

:func:`forward_step` runs the gate arithmetic of step ``t`` channel by channel and, while that channel's new hidden
row is still in cache, writes its im2col rows for step ``t+1``. :func:`backward_step` does the reverse: per channel
it sums ``dL/dh_t`` from the im2col gradient of step ``t+1`` (the transpose of the gather: the gradient rows' outside
positions zeroed, then one shifted add per tap, in the fused backend's tap order), the gate derivatives, and the
im2col rows of ``h_{t-1}`` for the kernel's gradient. Each channel's work is a few one-loop row helpers rather than
one loop over all its rows, because LLVM vectorises a loop only while its runtime alias checks stay few.

``exp`` and ``tanh`` in float32 are written out (Cody-Waite range reduction and the Cephes polynomials with fused
multiply-adds, within 2 ulp, as tests/nn/test_convlstm_kernel.py checks against float64; tanh below 0.625 by its own
odd polynomial, so small values keep their relative accuracy) so that LLVM vectorises the loops: numba's
``math.exp`` is a scalar libm call per element without Intel SVML. The results are therefore not bit-identical to
ATen's ``sigmoid``/``tanh`` (SLEEF), only equal to float32 rounding. float64 arrays use ``math.exp``/``math.tanh``.
No constant in the kernels is a Python float or int mixed into float32 arithmetic (numba would promote it to
float64). The kernels are single-threaded and release the GIL; they run under the calling thread's floating-point
mode (flush-to-zero where the engine sets it).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic, overload

from .jit import fma, jit

__all__ = ["forward_step", "backward_step", "im2col", "col2im", "im2col_rows", "col2im_rows"]

_F = np.float32


@intrinsic
def _bits_to_float(typingctx: object, n: types.Type) -> tuple | None:
    """The float32 whose bit pattern is the low 32 bits of the integer ``n``."""
    if not isinstance(n, types.Integer):
        return None

    def codegen(context: object, builder: ir.IRBuilder, signature: object, args: list) -> ir.Value:
        value = args[0]
        if n.bitwidth > 32:
            value = builder.trunc(value, ir.IntType(32))
        elif n.bitwidth < 32:
            value = builder.sext(value, ir.IntType(32))
        return builder.bitcast(value, ir.FloatType())

    return types.float32(n), codegen


def _exp32(x: np.float32) -> np.float32:  # pragma: no cover - compiled
    """``exp(x)`` in float32 for ``x`` clamped to [-87, 88] (so ``2^n`` stays a normal number)."""
    x = min(max(x, _F(-87.0)), _F(88.0))
    n = np.floor(fma(x, _F(1.44269504088896341), _F(0.5)))  # round(x / ln 2); float32 (math.floor gives int64)
    x = fma(n, _F(-0.693359375), x)  # minus n ln 2, ln 2 in two parts: the first times n is exact
    x = fma(n, _F(2.12194440e-4), x)
    p = fma(fma(fma(fma(fma(_F(1.9875691500e-4), x, _F(1.3981999507e-3)), x, _F(8.3334519073e-3)), x,
                        _F(4.1665795894e-2)), x, _F(1.6666665459e-1)), x, _F(5.0000001201e-1))
    p = fma(p, x * x, x) + _F(1.0)
    return p * _bits_to_float((np.int32(n) + 127) << 23)  # times 2^n, built from its exponent bits


_exp32 = njit(inline="always", error_model="numpy")(_exp32)


def _tanh32(x: np.float32) -> np.float32:  # pragma: no cover - compiled
    z = x * x
    small = fma(fma(fma(fma(fma(_F(-5.70498872745e-3), z, _F(2.06390887954e-2)), z, _F(-5.37397155531e-2)), z,
                          _F(1.33314422036e-1)), z, _F(-3.33332819422e-1)) * z, x, x)
    large = _F(1.0) - _F(2.0) / (_exp32(_F(2.0) * x) + _F(1.0))
    return small if abs(x) < _F(0.625) else large  # both computed: a select, no branch in the vector loop


_tanh32 = njit(inline="always", error_model="numpy")(_tanh32)


def _sigmoid(x: float) -> float:
    """Logistic function (compiled only, through the overload below)."""
    raise NotImplementedError


def _tanh(x: float) -> float:
    """Hyperbolic tangent (compiled only, through the overload below)."""
    raise NotImplementedError


# the overloads' parameters carry no annotation: numba requires them to match the returned lambdas' exactly
@overload(_sigmoid, inline="always")
def _sigmoid_impl(x):  # type: ignore[no-untyped-def]
    if x == types.float32:
        return lambda x: _F(1.0) / (_F(1.0) + _exp32(-x))
    if x == types.float64:
        return lambda x: 1.0 / (1.0 + math.exp(-x))
    return None


@overload(_tanh, inline="always")
def _tanh_impl(x):  # type: ignore[no-untyped-def]
    if x == types.float32:
        return lambda x: _tanh32(x)
    if x == types.float64:
        return lambda x: math.tanh(x)
    return None


@jit
def _shift_copy(dst: np.ndarray, src: np.ndarray, shift: int) -> None:  # pragma: no cover - compiled
    """``dst[n] = src[n + shift]`` wherever both exist: one long contiguous run, which vectorises (over slices: in
    ``src[p + shift]`` a possibly negative index costs numba's wrap-around test per element, and the vector loop)."""
    n = dst.shape[0]
    lo, hi = max(0, -shift), min(n, n - shift)
    if hi > lo:
        d, s = dst[lo:hi], src[lo + shift:hi + shift]
        for p in range(hi - lo):
            d[p] = s[p]


@jit
def _shift_add(dst: np.ndarray, src: np.ndarray, shift: int) -> None:  # pragma: no cover - compiled
    """``dst[n + shift] += src[n]`` wherever both exist."""
    n = dst.shape[0]
    lo, hi = max(0, shift), min(n, n + shift)
    if hi > lo:
        d, s = dst[lo:hi], src[lo - shift:hi - shift]
        for p in range(hi - lo):
            d[p] = d[p] + s[p]


@jit
def _zero_outside(row: np.ndarray, batch: int, height: int, width: int, dr: int,
                  dc: int) -> None:  # pragma: no cover - compiled
    """Zero the positions of an im2col row whose tap ``(dr, dc)`` (offsets from the centre) falls outside the grid:
    per sample ``|dr|`` whole grid rows (one contiguous run at the top or bottom) and, in the others, ``|dc|``
    cells at the left or right end (one strided run per column)."""
    cells = height * width
    r_lo, r_hi = max(0, -dr), min(height, height - dr)
    c_lo, c_hi = max(0, -dc), min(width, width - dc)
    for s in range(batch):
        grid = row[s * cells:(s + 1) * cells]
        if dr != 0:
            band = grid[:r_lo * width] if dr < 0 else grid[r_hi * width:]
            band[:] = 0
        if dc != 0:
            inner = grid[r_lo * width:r_hi * width]
            for c in range(c_lo):  # dc < 0: the left columns
                inner[c::width] = 0
            for c in range(c_hi, width):  # dc > 0: the right columns
                inner[c::width] = 0


def im2col(src: np.ndarray, cols: np.ndarray, channel: int, batch: int, height: int, width: int,
           kernel: int) -> None:  # pragma: no cover - compiled
    """Channel ``channel``'s ``k*k`` rows of the im2col matrix ``cols (h*k*k, N)`` from its state row ``src (N,)``:
    ``cols[channel*k*k + dr*k + dc, n] = src[n shifted by (dr - k//2, dc - k//2)]`` where that cell is inside the
    grid, else 0.

    Within a sample's grid a tap is a constant shift of the flat index, so each row is one contiguous shifted copy
    of the whole ``src`` (long runs that vectorise, unlike a grid row of 13 at a time); the positions where the
    shift wrapped into a neighbouring row or sample are exactly those outside the grid, and are zeroed after."""
    pad, taps = kernel // 2, kernel * kernel
    for a in range(kernel):
        for b in range(kernel):
            dst = cols[channel * taps + a * kernel + b]
            _shift_copy(dst, src, (a - pad) * width + (b - pad))
            if a != pad or b != pad:
                _zero_outside(dst, batch, height, width, a - pad, b - pad)


def col2im(d_cols: np.ndarray, out: np.ndarray, channel: int, batch: int, height: int, width: int,
           kernel: int) -> None:  # pragma: no cover - compiled
    """The transpose of :func:`im2col` for one channel: adds each of its ``k*k`` gradient rows of ``d_cols`` into
    ``out (N,)`` at the cells they were read from, tap by tap in row order (the order of ``index_add_`` over the
    fused backend's index). The rows' outside positions (the gradient of the zero padding) are zeroed first, in
    place, so that one shifted add per row suffices."""
    pad, taps = kernel // 2, kernel * kernel
    for a in range(kernel):
        for b in range(kernel):
            src = d_cols[channel * taps + a * kernel + b]
            if a != pad or b != pad:
                _zero_outside(src, batch, height, width, a - pad, b - pad)
            _shift_add(out, src, (a - pad) * width + (b - pad))


im2col = jit(im2col)
col2im = jit(col2im)


@jit
def im2col_rows(rows: np.ndarray, cols: np.ndarray, batch: int, height: int, width: int,
                kernel: int) -> None:  # pragma: no cover - compiled
    """:func:`im2col` of every channel in one call: ``rows (h, >= N)`` (a state, of which the first ``N`` columns
    are read) -> ``cols (h*k*k, N)``. The fused loop's gather without its index: a copy, so the same values."""
    n = cols.shape[1]
    for j in range(rows.shape[0]):
        im2col(rows[j, :n], cols, j, batch, height, width, kernel)


@jit
def col2im_rows(d_cols: np.ndarray, out: np.ndarray, batch: int, height: int, width: int,
                kernel: int) -> None:  # pragma: no cover - compiled
    """:func:`col2im` of every channel in one call, from zero: ``out[:, :N]`` becomes the transpose of the gather
    applied to ``d_cols (h*k*k, N)``, summed tap by tap in the order of the fused loop's ``index_add_``; ``d_cols``'
    outside positions are zeroed on the way."""
    n = d_cols.shape[1]
    for j in range(out.shape[0]):
        row = out[j, :n]
        row[:] = 0
        col2im(d_cols, row, j, batch, height, width, kernel)


# Row helpers: each is one loop over a row of N values that reads at most three rows and writes at most two, so
# that LLVM's runtime alias checks between them stay few and it vectorises the loop (one loop over all eight rows of
# a channel does not vectorise and runs several times slower).

@jit
def _sigmoid_row(z: np.ndarray) -> None:  # pragma: no cover - compiled
    for p in range(z.shape[0]):
        z[p] = _sigmoid(z[p])


@jit
def _tanh_row(z: np.ndarray) -> None:  # pragma: no cover - compiled
    for p in range(z.shape[0]):
        z[p] = _tanh(z[p])


@jit
def _cell_row(i: np.ndarray, f: np.ndarray, g: np.ndarray, c_prev: np.ndarray, out: np.ndarray
              ) -> None:  # pragma: no cover - compiled
    for p in range(out.shape[0]):
        out[p] = f[p] * c_prev[p] + i[p] * g[p]


@jit
def _hidden_row(c_tc: np.ndarray, o: np.ndarray, c: np.ndarray, h: np.ndarray) -> None:  # pragma: no cover
    """``c_tc`` holds ``c_t``: it goes to ``c``, its tanh replaces it, and ``h = o tanh(c_t)``."""
    for p in range(h.shape[0]):
        v = c_tc[p]
        c[p] = v
        t = _tanh(v)
        c_tc[p] = t
        h[p] = o[p] * t


def forward_step(z: np.ndarray, c_prev: np.ndarray, c_out: np.ndarray, tc_out: np.ndarray, h_out: np.ndarray,
                 cols: np.ndarray, write_cols: bool, batch: int, height: int, width: int,
                 kernel: int) -> None:  # pragma: no cover - compiled
    """The gate arithmetic of one step, and the im2col matrix of its hidden state for the next.

    ``z (4h, N)``: the pre-activations in, the activated gates out (sigmoid on i, f, o; tanh on g). Then
    ``c_out = f c_prev + i g`` (``c_out`` may be ``c_prev``), ``tc_out = tanh(c_out)``, ``h_out = o tc_out``, each
    ``(h, N)``; with ``write_cols`` channel ``j``'s im2col rows of ``h_out`` go into ``cols (h*k*k, N)`` right after
    its row is computed."""
    hid = c_prev.shape[0]
    for j in range(hid):
        zi, zf, zo, zg = z[j], z[hid + j], z[2 * hid + j], z[3 * hid + j]
        _sigmoid_row(zi)
        _sigmoid_row(zf)
        _sigmoid_row(zo)
        _tanh_row(zg)
        _cell_row(zi, zf, zg, c_prev[j], tc_out[j])  # c_t into tc_out first: c_out may be c_prev
        _hidden_row(tc_out[j], zo, c_out[j], h_out[j])
        if write_cols:
            im2col(h_out[j], cols, j, batch, height, width, kernel)


@jit
def _add_row(acc: np.ndarray, x: np.ndarray) -> None:  # pragma: no cover - compiled
    for p in range(acc.shape[0]):
        acc[p] = acc[p] + x[p]


@jit
def _d_out_row(dh: np.ndarray, o: np.ndarray, tc: np.ndarray, d_o: np.ndarray) -> None:  # pragma: no cover
    """``dL/dz_o = dh tanh(c) o (1 - o)``."""
    for p in range(d_o.shape[0]):
        v = o[p]
        d_o[p] = dh[p] * tc[p] * (v - v * v)


@jit
def _d_cell_row(dh: np.ndarray, o: np.ndarray, tc: np.ndarray, dc: np.ndarray) -> None:  # pragma: no cover
    """``dc += dh o (1 - tanh(c)^2)``: the gradient of ``c_t`` from later steps plus its path through ``h_t``."""
    for p in range(dc.shape[0]):
        d_t = dh[p] * o[p]
        t = tc[p]
        dc[p] = dc[p] + d_t - d_t * t * t


@jit
def _d_input_row(dc: np.ndarray, i: np.ndarray, g: np.ndarray, d_i: np.ndarray) -> None:  # pragma: no cover
    """``dL/dz_i = dc g i (1 - i)``."""
    for p in range(d_i.shape[0]):
        v = i[p]
        d_i[p] = dc[p] * g[p] * (v - v * v)


@jit
def _d_candidate_row(dc: np.ndarray, i: np.ndarray, g: np.ndarray, d_g: np.ndarray) -> None:  # pragma: no cover
    """``dL/dz_g = dc i (1 - g^2)``."""
    for p in range(d_g.shape[0]):
        u = dc[p] * i[p]
        v = g[p]
        d_g[p] = u - u * v * v


@jit
def _d_forget_row(dc: np.ndarray, f: np.ndarray, c_prev: np.ndarray, d_f: np.ndarray) -> None:  # pragma: no cover
    """``dL/dz_f = dc c_{t-1} f (1 - f)``, and ``dc`` becomes ``dL/dc_{t-1} = dc f``."""
    for p in range(d_f.shape[0]):
        v = f[p]
        d = dc[p]
        d_f[p] = d * c_prev[p] * (v - v * v)
        dc[p] = d * v


def backward_step(gates: np.ndarray, c_prev: np.ndarray, tcs: np.ndarray, d_hs: np.ndarray, d_cols: np.ndarray,
                  has_d_cols: bool, d_c: np.ndarray, d_z: np.ndarray, dh: np.ndarray, h_prev: np.ndarray,
                  cols: np.ndarray, write_cols: bool, batch: int, height: int, width: int,
                  kernel: int) -> None:  # pragma: no cover - compiled
    """The gate derivatives of one step, channel by channel.

    ``dL/dh_t = col2im(d_cols) + d_hs`` (``d_cols (h*k*k, N)`` the gradient of step ``t+1``'s im2col matrix, absent
    at the last step) into the scratch row ``dh (N,)``; then, from the step's activated ``gates (4h, N)``, ``c_prev``
    (``c_{t-1}``) and ``tcs`` (``tanh(c_t)``), the pre-activations' gradient into ``d_z (4h, N)``, and ``d_c (h, N)``
    (``dL/dc_t`` from later steps) becomes ``dL/dc_{t-1}``. With ``write_cols`` channel ``j``'s im2col rows of
    ``h_prev`` (``h_{t-1}``) go into ``cols``, for the kernel's gradient."""
    hid = c_prev.shape[0]
    for j in range(hid):
        if has_d_cols:  # the fused backend's order: the taps summed from zero, then the step's own gradient added
            dh[:] = 0
            col2im(d_cols, dh, j, batch, height, width, kernel)
            _add_row(dh, d_hs[j])
        else:
            dh[:] = d_hs[j]
        i, f, o, g = gates[j], gates[hid + j], gates[2 * hid + j], gates[3 * hid + j]
        dc = d_c[j]
        _d_out_row(dh, o, tcs[j], d_z[2 * hid + j])
        _d_cell_row(dh, o, tcs[j], dc)
        _d_input_row(dc, i, g, d_z[j])
        _d_candidate_row(dc, i, g, d_z[3 * hid + j])
        _d_forget_row(dc, f, c_prev[j], d_z[hid + j])
        if write_cols:
            im2col(h_prev[j], cols, j, batch, height, width, kernel)


forward_step = jit(forward_step)
backward_step = jit(backward_step)
