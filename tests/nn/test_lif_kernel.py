"""The compiled LIF kernel (tactile_zoo.nn._kernels.lif) against the fused torch path it replaces on CPU: spikes,
membranes and every gradient bit-identical (torch.equal), over the module's options; and when each path runs."""

from __future__ import annotations

import contextlib
import itertools
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

import tactile_zoo.nn.lif as lif_module
import tactile_zoo.nn.lif_fused as fused
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn import backend
from tactile_zoo.nn.lif import KERNEL_ENV, MultiStepLIF

pytestmark = pytest.mark.skipif(backend.lif_kernels() is None,
                                reason="the compiled LIF kernel needs numba on x86-64 with ATen AVX2/AVX512 kernels")


@pytest.fixture(autouse=True)
def small_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks of 256 neurons instead of the kernel's 8192 (and forward rows of at most 400 instead of whole rows), so
    that small shapes span several chunks, cut differently forward and backward, and reach the parallel builds (the
    chunk is an argument of each call; the checkpoint interval is compiled in)."""
    monkeypatch.setattr(backend.lif_kernels(), "CHUNK", 256)
    monkeypatch.setattr(backend.lif_kernels(), "FORWARD_CHUNK", 400)


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Counts the compiled forward and backward calls (so a comparison cannot pass by running torch twice)."""
    kernels, counts = backend.lif_kernels(), {"forward": 0, "backward": 0}
    parallel = [0]  # launches of the parallel builds (the others run the serial ones)
    monkeypatch.setattr(lif_module, "_parallel_launches", parallel, raising=False)
    for name, build in itertools.product(("forward", "backward"), ("", "_serial")):
        fn = getattr(kernels, f"lif_{name}{build}")

        def counted(*args: object, _fn=fn, _name=name, _parallel=not build) -> None:  # noqa: ANN001
            counts[_name] += 1
            parallel[0] += _parallel
            _fn(*args)

        monkeypatch.setattr(kernels, f"lif_{name}{build}", counted)
    return counts


def _run(lif: MultiStepLIF, x: torch.Tensor, mem0: torch.Tensor, w_s: torch.Tensor | None, w_m: torch.Tensor | None,
         path: str, monkeypatch: pytest.MonkeyPatch) -> list[torch.Tensor]:
    """Spikes, last membrane, and the gradients w.r.t. input and initial membrane of ``sum(S w_s) + sum(U w_m)``
    (a term left out when its weight is None: that output then gets no gradient at all)."""
    monkeypatch.setenv(KERNEL_ENV, path)
    x = x.detach().clone().requires_grad_(True)
    mem0 = mem0.detach().clone().requires_grad_(True)
    spikes, mem = lif(x, mem0, return_mem=True)
    loss = sum(((out * w).sum() for out, w in ((spikes, w_s), (mem, w_m)) if w is not None), torch.zeros(()))
    return [spikes, mem, *torch.autograd.grad(loss, [x, mem0])]


def _same(kw: dict, shape: tuple[int, ...], monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], seed: int = 0,
          spike_grad: bool = True, mem_grad: bool = True, scale: float = 0.6, offset: float = 0.3) -> None:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(shape, generator=gen) * scale + offset
    mem0 = torch.randn(shape[1:], generator=gen) * 0.5
    w_s = torch.randn(shape, generator=gen) if spike_grad else None
    w_m = torch.randn(shape[1:], generator=gen) if mem_grad else None
    lif = MultiStepLIF(**kw)
    before = dict(calls)
    compiled = _run(lif, x, mem0, w_s, w_m, "numba", monkeypatch)
    assert calls["forward"] == before["forward"] + 1 and calls["backward"] == before["backward"] + 1
    fused = _run(lif, x, mem0, w_s, w_m, "torch", monkeypatch)
    assert calls == {k: before[k] + 1 for k in calls}  # the torch path did not call the kernel
    for name, a, b in zip(("spikes", "membrane", "input gradient", "initial-membrane gradient"), compiled, fused):
        assert torch.equal(a, b), f"{name} differs: max {float((a - b).abs().max()):g}"


OPTIONS = list(itertools.product(["rect", "atan"], [False, True], ["zero", "subtract"]))


@contextlib.contextmanager
def _threads(n: int) -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("surrogate,detach_reset,reset", OPTIONS)
@pytest.mark.parametrize("shape,beta,threshold,threads", [
    ((40, 3, 5), 0.2, 0.5, 1), ((1, 4), 0.9, 0.3, 1), ((9, 2, 3, 4), 0.5, 1.0, 2), ((33, 7, 301), 0.75, 0.35, 1),
    ((33, 7, 301), 0.75, 0.35, 2)])
def test_compiled_equals_fused(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], surrogate: str,
                               detach_reset: bool, reset: str, shape: tuple[int, ...], beta: float,
                               threshold: float, threads: int) -> None:
    """Shapes below, at and above one chunk of neurons (chunks of 256 here: 2107 = 8 chunks + 59), sequences of one,
    two and a half checkpoint windows (T = 33: windows of 16, 16 and 1 steps), thresholds that float32 rounds; the
    serial builds (one thread, small sequences) and the parallel ones (two threads, 33 x 2107 steps x neurons)."""
    kw = dict(beta=beta, threshold=threshold, surrogate=surrogate, detach_reset=detach_reset, reset=reset)
    with _threads(threads):
        _same(kw, shape, monkeypatch, calls)
    assert lif_module._parallel_launches[0] == (2 if threads == 2 and shape[0] == 33 else 0)


@pytest.mark.parametrize("surrogate,detach_reset,reset", OPTIONS)
@pytest.mark.parametrize("block_bytes", [1, 3 * 15 * 4, 7 * 15 * 4])
def test_block_boundaries(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], surrogate: str,
                          detach_reset: bool, reset: str, block_bytes: int) -> None:
    """The fused backward rounds differently where it carries the gradient from one block of steps to the next."""
    monkeypatch.setattr(fused, "BLOCK_BYTES", block_bytes)
    monkeypatch.setattr(fused, "SAVE_LIMIT_BYTES", 0)  # and recomputes its blocks
    _same(dict(surrogate=surrogate, detach_reset=detach_reset, reset=reset), (23, 3, 5), monkeypatch, calls, seed=1)


@pytest.mark.parametrize("spike_grad,mem_grad", [(True, False), (False, True)])
@pytest.mark.parametrize("reset", ["zero", "subtract"])
def test_one_output_without_gradient(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], spike_grad: bool,
                                     mem_grad: bool, reset: str) -> None:
    monkeypatch.setattr(fused, "BLOCK_BYTES", 4 * 15 * 4)
    _same(dict(surrogate="atan", reset=reset), (17, 3, 5), monkeypatch, calls, spike_grad=spike_grad,
          mem_grad=mem_grad)


@pytest.mark.parametrize("surrogate,detach_reset,reset", OPTIONS)
def test_under_flush_to_zero_with_denormals(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int], surrogate: str,
                                            detach_reset: bool, reset: str) -> None:
    """Training runs under flush-to-zero; silent neurons' membranes and gradients decay into denormals (beta 0.2:
    after about 55 steps), which the kernel must flush exactly where the fused path does."""
    if not torch.set_flush_denormal(True):
        pytest.skip("no flush-to-zero on this CPU")
    try:
        kw = dict(surrogate=surrogate, detach_reset=detach_reset, reset=reset, threshold=0.5, beta=0.2)
        for threads in (1, 2):  # serial and parallel builds
            with _threads(threads):
                _same(kw, (120, 2, 300), monkeypatch, calls, scale=0.3, offset=0.0)  # sparse spikes, quiet stretches
        assert lif_module._parallel_launches[0] == 2
    finally:
        torch.set_flush_denormal(False)


def test_flush_to_zero_reaches_the_kernel(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int]) -> None:
    """A membrane decaying into denormals is kept without flush-to-zero and flushed with it, by both paths alike, on
    every thread the kernel runs (numba's worker threads do not inherit the caller's flag)."""
    x = torch.zeros(40, 2048)  # 8 chunks of neurons, shared by the threads (the parallel build)
    mem0 = torch.full((2048,), 1e-37)  # 0.9 ** 40 * 1e-37 = 1.5e-39: denormal (from step 21 on)
    out, threads = {}, torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for flush, path in itertools.product([False, True], ["numba", "torch"]):
            monkeypatch.setenv(KERNEL_ENV, path)
            if flush and not torch.set_flush_denormal(True):
                pytest.skip("no flush-to-zero on this CPU")
            out[flush, path] = MultiStepLIF(beta=0.9)(x, mem0, return_mem=True)[1]
            torch.set_flush_denormal(False)
    finally:
        torch.set_flush_denormal(False)
        torch.set_num_threads(threads)
    assert lif_module._parallel_launches[0] == 2
    assert bool((out[False, "numba"] > 0).all()) and bool((out[True, "numba"] == 0).all())
    assert torch.equal(out[False, "numba"], out[False, "torch"]) and torch.equal(out[True, "numba"], out[True, "torch"])


def test_no_grad_and_non_contiguous_inputs(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int]) -> None:
    gen = torch.Generator().manual_seed(5)
    x = (torch.randn(7, 20, 11, generator=gen) + 0.4).transpose(1, 2)  # (T, 11, 20), not contiguous
    mem0 = torch.randn(20, 11, generator=gen).t()
    lif = MultiStepLIF(surrogate="atan", reset="subtract")
    out = {}
    for path in ("numba", "torch"):
        monkeypatch.setenv(KERNEL_ENV, path)
        with torch.no_grad():
            out[path] = lif(x, mem0, return_mem=True)
    assert calls["forward"] == 1 and calls["backward"] == 0
    assert all(torch.equal(a, b) for a, b in zip(out["numba"], out["torch"]))
    _same(dict(surrogate="rect"), (7, 11, 20), monkeypatch, calls)  # and the backward of a fresh pair


def test_paths_that_stay_in_torch(monkeypatch: pytest.MonkeyPatch, calls: dict[str, int]) -> None:
    """float64, surrogates evaluated by other ATen kernels (sigmoid, snnTorch callables) and the snntorch backend."""
    monkeypatch.setenv(KERNEL_ENV, "auto")
    x = torch.randn(6, 3, requires_grad=True)
    MultiStepLIF()(x.double()).sum().backward()
    MultiStepLIF(surrogate="sigmoid")(x).sum().backward()
    MultiStepLIF(backend="snntorch")(x).sum().backward()
    assert calls == {"forward": 0, "backward": 0}
    MultiStepLIF()(x).sum().backward()  # auto: the kernel
    assert calls == {"forward": 1, "backward": 1}


def test_backend_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KERNEL_ENV, "fast")
    with pytest.raises(ConfigError, match=KERNEL_ENV):
        MultiStepLIF()(torch.randn(3, 2))
    monkeypatch.setenv(KERNEL_ENV, "numba")
    monkeypatch.setattr(backend, "lif_kernels", lambda: None)  # as where numba is not installed
    with pytest.raises(ConfigError, match="unavailable"):
        MultiStepLIF()(torch.randn(3, 2))
    monkeypatch.setenv(KERNEL_ENV, "auto")  # auto falls back to torch quietly
    assert MultiStepLIF()(torch.full((2, 1), 0.7)).flatten().tolist() == [1.0, 1.0]


def test_threads_follow_torch(monkeypatch: pytest.MonkeyPatch) -> None:
    import numba

    kernels, before = backend.lif_kernels(), torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        backend._kernel_threads(kernels)
        assert numba.get_num_threads() == 1
        torch.set_num_threads(64)  # more than numba's pool: capped there
        backend._kernel_threads(kernels)
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    finally:
        torch.set_num_threads(before)


@pytest.mark.slow  # a fresh process (loads the cached kernels)
def test_concurrent_calls_under_the_workqueue_layer() -> None:
    """numba's fallback threading layer aborts the process when two threads launch at once; the launches are
    serialised there, so training or inference from several Python threads keeps working."""
    script = ("import threading, torch\n"
              "from tactile_zoo.nn.lif import MultiStepLIF\n"
              "torch.set_num_threads(2)\n"
              "x = torch.randn(50, 4, 2100, requires_grad=True)  # 8400 neurons: two chunks of the kernel's 8192\n"
              "ref = MultiStepLIF()(x)\n"
              "def work(out):\n"
              "    for _ in range(40):\n"
              "        y = MultiStepLIF()(x); y.sum().backward(); out.append(torch.equal(y, ref))\n"
              "outs = [[], []]\n"
              "threads = [threading.Thread(target=work, args=(o,)) for o in outs]\n"
              "[t.start() for t in threads]; [t.join() for t in threads]\n"
              "import numba; print(numba.threading_layer(), all(outs[0] + outs[1]), len(outs[0] + outs[1]))")
    env = {**os.environ, "NUMBA_THREADING_LAYER": "workqueue", "TACTILE_ZOO_LIF_BACKEND": "numba"}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.split() == ["workqueue", "True", "80"]


@pytest.mark.slow  # compiles the forward kernel from scratch in a fresh process (several seconds)
def test_read_only_install_compiles_in_memory(tmp_path: Path) -> None:
    """No cache folder can be made (beside the module, nor a per-user one): the kernel still compiles, in memory.
    Blocked by files where the folders would go, which stops root as well as anyone else."""
    pkg, blocker = tmp_path / "pkg", tmp_path / "not-a-folder"
    kernels = pkg / "_kernels"  # the kernel package's files that the LIF kernels need, as a top-level package
    kernels.mkdir(parents=True)
    for name in ("__init__.py", "jit.py", "lif.py"):
        (kernels / name).write_text((Path(backend.__file__).parent / "_kernels" / name).read_text())
    (kernels / "__pycache__").write_text("")
    blocker.write_text("")
    script = ("import numpy as np, _kernels.lif as k\n"
              "x = np.full((3, 2), 0.7, np.float32); s = np.empty_like(x); m = np.empty(2, np.float32)\n"
              "k.lif_forward(x, np.zeros(2, np.float32), s, m, np.zeros((1, 1), np.float32), False,\n"
              "              *map(np.float32, (0.2, 0.5, 0.50000006)), False, 256, np.float32(1), False)\n"
              "print(k.lif_forward._cache.__class__.__name__, s[:, 0].tolist())")
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(pkg), "HOME": str(blocker / "home"),
           "XDG_CACHE_HOME": str(blocker / "cache"), "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    # 0.7 spikes, is reset to zero and charged to 0.7 again; NullCache: compiled without a disk cache
    assert proc.stdout.split() == ["NullCache", "[1.0,", "1.0,", "1.0]"]
