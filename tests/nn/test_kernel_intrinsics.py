"""The numba intrinsics and overloads the compiled kernels are built from (``tactile_zoo.nn._kernels``), each compiled
here afresh (``cache=False``: a cached kernel never runs their code generation again) and checked against what they
stand for: ``fma`` rounds once, the MXCSR round-trips, ``_bits_to_float`` is a bit cast, and the float32 logistic and
tanh the ConvLSTM kernels inline stay within a few float32 ulps of float64 (and the float64 ones are libm's)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from tactile_zoo.nn._kernels import convlstm, jit

F32 = np.float32


def test_fma_rounds_once() -> None:
    @njit(cache=False)
    def fused(a: float, b: float, c: float) -> float:
        return jit.fma(a, b, c)

    a = F32(1 + 2.0**-12)  # a * a = 1 + 2^-11 + 2^-24: float32 drops the 2^-24 in the product
    assert fused(a, a, F32(-(1 + 2.0**-11))) == F32(2.0**-24)
    assert a * a + F32(-(1 + 2.0**-11)) == 0.0  # two roundings, where one keeps it
    with pytest.raises(Exception, match="fma"):  # float64 has no overload: a typing error, not a silent cast
        fused(1.0, 2.0, 3.0)


def test_the_mxcsr_round_trips_and_keeps_the_mode() -> None:
    @njit(cache=False)
    def flip_ftz() -> tuple:
        before = jit.get_csr()
        jit.set_csr(before | np.uint32(0x8040))  # flush-to-zero and denormals-are-zero on
        during = jit.get_csr()
        jit.set_csr(before)
        return before, during, jit.get_csr()

    before, during, after = flip_ftz()
    assert during == before | 0x8040 and after == before
    assert before & jit.CSR_MODE == before & 0xFFFFFFC0


def test_bits_to_float_is_a_bit_cast() -> None:
    @njit(cache=False)
    def cast32(n: int) -> float:
        return convlstm._bits_to_float(np.int32(n))

    @njit(cache=False)
    def cast64(n: int) -> float:
        return convlstm._bits_to_float(np.int64(n))

    for value in (1.0, -2.5, 2.0**-126, 3.4e38):
        bits = int(np.array(value, dtype=F32).view(np.int32))
        assert cast32(bits) == F32(value) and cast64(bits) == F32(value)
    assert cast32((127 + 3) << 23) == F32(8.0)  # 2^3 from its exponent bits, as the kernels' exp builds it


def test_the_inlined_sigmoid_and_tanh_are_float32_close_and_float64_exact() -> None:
    @njit(cache=False)
    def both(x32: np.ndarray, x64: np.ndarray) -> tuple:
        s32, t32 = np.empty_like(x32), np.empty_like(x32)
        s64, t64 = np.empty_like(x64), np.empty_like(x64)
        for i in range(x32.size):
            s32[i], t32[i] = convlstm._sigmoid(x32[i]), convlstm._tanh(x32[i])
            s64[i], t64[i] = convlstm._sigmoid(x64[i]), convlstm._tanh(x64[i])
        return s32, t32, s64, t64

    x = np.linspace(-30, 30, 2001)
    s32, t32, s64, t64 = both(x.astype(F32), x)
    assert s32.dtype == t32.dtype == F32 and s64.dtype == t64.dtype == np.float64
    assert np.allclose(s64, 1 / (1 + np.exp(-x)), rtol=1e-15, atol=0)
    assert np.allclose(t64, np.tanh(x), rtol=1e-15, atol=0)
    want_s, want_t = 1 / (1 + np.exp(-x.astype(F32).astype(np.float64))), np.tanh(x.astype(F32).astype(np.float64))
    assert np.abs(s32 - want_s).max() <= 4e-7 and np.abs(t32 - want_t).max() <= 4e-7
