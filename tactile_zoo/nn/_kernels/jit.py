"""The numba helpers every kernel module shares: :func:`jit` (how each kernel is compiled and cached),
:func:`serial_copy` (a second, serial build of a parallel kernel), :func:`fma` (one rounding for ``a * b + c``) and the
MXCSR intrinsics :func:`get_csr` / :func:`set_csr` (the calling thread's floating-point mode).

Compiled code is cached on disk (``cache=True``): in ``__pycache__`` beside the kernel's file when writable, else in
numba's per-user cache directory (``NUMBA_CACHE_DIR`` overrides both); where neither is writable the kernels are
compiled in memory on first use instead.
"""

from __future__ import annotations

from collections.abc import Callable
from types import FunctionType

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["jit", "serial_copy", "fma", "get_csr", "set_csr", "CSR_MODE"]

#: MXCSR without its sticky exception flags (bits 0-5): the floating-point mode a parallel chunk copies from its caller.
CSR_MODE = np.uint32(0xFFFFFFC0)


def jit(fn: Callable, parallel: bool = False) -> Callable:
    """``njit`` with an on-disk cache where one can be written (see the module docstring), in memory otherwise.

    ``error_model="numpy"``: a float division by zero gives inf as in torch, never a Python exception."""
    opts = dict(nogil=True, error_model="numpy", parallel=parallel)
    try:
        return njit(cache=True, **opts)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available" (read-only install and home)
        return njit(cache=False, **opts)(fn)


def serial_copy(fn: Callable) -> Callable:
    """``fn`` under the name ``<name>_serial``: compiled without ``parallel``, its ``prange`` is a plain loop. The
    cache files are named after the function, so the serial build needs a name of its own."""
    copy = FunctionType(fn.__code__, fn.__globals__, f"{fn.__name__}_serial", fn.__defaults__)
    copy.__qualname__ = f"{fn.__qualname__}_serial"
    return jit(copy)


@intrinsic
def fma(typingctx: object, a: types.Type, b: types.Type, c: types.Type) -> tuple | None:
    """``a * b + c`` rounded once (``llvm.fma.f32``): what ATen's ``fmadd`` and GCC's contraction compute."""
    if not (a == b == c == types.float32):
        return None

    def codegen(context: object, builder: ir.IRBuilder, signature: object, args: list) -> ir.Value:
        flt = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [flt], ir.FunctionType(flt, [flt, flt, flt]))
        return builder.call(fn, args)

    return types.float32(types.float32, types.float32, types.float32), codegen


def _csr_fn(builder: ir.IRBuilder, name: str) -> tuple[ir.Function, ir.Type]:
    ptr = ir.IntType(8).as_pointer()
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [ptr]), name), ptr


@intrinsic
def get_csr(typingctx: object) -> tuple:
    """The calling thread's MXCSR (x86 SSE control and status register)."""

    def codegen(context: object, builder: ir.IRBuilder, signature: object, args: list) -> ir.Value:
        slot = cgutils.alloca_once(builder, ir.IntType(32))
        fn, ptr = _csr_fn(builder, "llvm.x86.sse.stmxcsr")
        builder.call(fn, [builder.bitcast(slot, ptr)])
        return builder.load(slot)

    return types.uint32(), codegen


@intrinsic
def set_csr(typingctx: object, value: types.Type) -> tuple | None:
    """Load ``value`` (an integer, truncated to 32 bits) into the calling thread's MXCSR."""
    if not isinstance(value, types.Integer):
        return None

    def codegen(context: object, builder: ir.IRBuilder, signature: object, args: list) -> ir.Value:
        slot = cgutils.alloca_once(builder, ir.IntType(32))
        builder.store(context.cast(builder, args[0], value, types.uint32), slot)
        fn, ptr = _csr_fn(builder, "llvm.x86.sse.ldmxcsr")
        builder.call(fn, [builder.bitcast(slot, ptr)])
        return context.get_dummy_value()

    return types.void(value), codegen
