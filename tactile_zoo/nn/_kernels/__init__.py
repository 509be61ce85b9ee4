"""The compiled (numba) kernels of the package's CPU paths; nothing here is public.

- :mod:`.jit`: the shared numba helpers: :func:`~.jit.jit` (``njit`` with an on-disk cache where one can be written),
  the fused multiply-add :func:`~.jit.fma` and the MXCSR intrinsics (the calling thread's floating-point mode).
- :mod:`.lif`: the whole-sequence LIF forward and backward loops (the fused LIF's compiled path).
- :mod:`.convlstm`: ConvLSTM's per-step gate, gather and scatter kernels (``backend="compiled"``).
- :mod:`.events`: the nonzero entries of a spike or event matrix as lists (event-driven products, active neurons).

Importing this package costs nothing; each kernel module imports numba and compiles (or loads from its cache) on
first import, so the layers import them lazily, through the loaders of :mod:`tactile_zoo.nn.backend`, which decide
where a compiled path runs.
"""
