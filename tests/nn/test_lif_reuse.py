"""Issue 40's LIF paths: reused output storages (tactile_zoo.nn.storage_pool.reusable), the time-major forward, the
input scale folded into the kernel, and the active-neuron CSR -- each bit-identical (torch.equal) to the fused torch
path, and a live output never overwritten."""

from __future__ import annotations

import threading

import pytest
import torch

import tactile_zoo.nn.lif_compiled as compiled
from tactile_zoo.nn import backend, storage_pool
from tactile_zoo.nn.lif import KERNEL_ENV, LIFConfig, MultiStepLIF, active_spikes

needs_kernel = pytest.mark.skipif(backend.lif_kernels() is None, reason="the compiled LIF kernel needs numba on "
                                  "x86-64 with ATen AVX2/AVX512 kernels")


@pytest.fixture(autouse=True)
def fresh_pool(monkeypatch: pytest.MonkeyPatch) -> None:
    """An empty pool that pools small tensors too (these tests' outputs are kilobytes)."""
    storage_pool.clear_pool()
    monkeypatch.setattr(storage_pool, "POOL_MIN_BYTES", 1)
    yield
    storage_pool.clear_pool()


# ------------------------------------------------------------------------------------------------------ the pool
def test_a_storage_is_handed_out_again_only_when_nothing_refers_to_it() -> None:
    like = torch.zeros(1)
    a = storage_pool.reusable((10, 30), like)
    ptr = a.data_ptr()
    for hold in (lambda t: t[2:5], lambda t: t.numpy(), lambda t: t.untyped_storage(), lambda t: t.t()):
        held = hold(a)  # a view, a numpy array, the storage itself, a transposed view
        del a
        b = storage_pool.reusable((30, 10), like)
        assert b.data_ptr() != ptr  # something still reaches the first storage
        del b, held
        a = storage_pool.reusable((10, 30), like)
        assert a.data_ptr() == ptr  # let go: handed out again
    del a
    storage_pool.clear_pool()
    c = storage_pool.reusable((30, 10), like)
    ptr = c.data_ptr()
    saved = torch.ones(30, 10, requires_grad=True) * c  # c saved for backward by the multiplication
    del c
    assert storage_pool.reusable((30, 10), like).data_ptr() != ptr
    del saved
    d = storage_pool.reusable((300,), like)  # same size in bytes, another shape
    assert d.data_ptr() == ptr and d.shape == (300,) and d.dtype == torch.float32


def test_the_pool_is_bounded(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(storage_pool, "POOL_BYTES", 3 * 400)
    like = torch.zeros(1)
    live = [storage_pool.reusable((100,), like) for _ in range(5)]  # 400 bytes each: three pooled, two beyond the limit
    assert storage_pool.pool_stats()["bytes"] == 1200 and storage_pool.pool_stats()["storages"] == 3
    del live
    other = storage_pool.reusable((50,), like)  # another size: an idle storage is evicted to make room
    stats = storage_pool.pool_stats()
    assert stats["bytes"] <= 1200 and stats["storages"] == 3 and other.shape == (50,)


def test_concurrent_takers_never_share_a_storage() -> None:
    like, seen, lock = torch.zeros(1), [], threading.Lock()

    def work() -> None:
        for _ in range(200):
            a, b = storage_pool.reusable((64,), like), storage_pool.reusable((64,), like)
            with lock:
                seen.append(a.data_ptr() != b.data_ptr())
            a.fill_(1.0)
            assert bool((b != 1.0).all()) or b.data_ptr() != a.data_ptr()

    threads = [threading.Thread(target=work) for _ in range(4)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    assert len(seen) == 800 and all(seen) and storage_pool.pool_stats()["storages"] <= 16  # 4 alive per thread at most


# ------------------------------------------------------------------------------------ the LIF through the pool
@pytest.mark.parametrize("path", ["numba", "torch"])
@pytest.mark.parametrize("detach_reset,reset", [(False, "zero"), (True, "zero"), (True, "subtract")])
def test_live_outputs_survive_later_calls(monkeypatch: pytest.MonkeyPatch, detach_reset: bool, reset: str,
                                          path: str) -> None:
    """Spikes and input gradients kept from earlier forward/backward calls are never overwritten by later calls,
    while the outputs that were let go are reused (so the reuse path is exercised); the compiled kernel and the
    fused torch path."""
    if path == "numba" and backend.lif_kernels() is None:
        pytest.skip("no compiled kernel")
    monkeypatch.setenv(KERNEL_ENV, path)
    lif = MultiStepLIF(surrogate="rect", reset=reset, detach_reset=detach_reset)
    gen = torch.Generator().manual_seed(3)
    kept, copies = [], []
    for i in range(6):
        x = (torch.randn(20, 3, 40, generator=gen) * 0.6 + 0.3).requires_grad_(True)
        spikes = lif(x)
        (spikes * torch.randn(spikes.shape, generator=gen)).sum().backward()
        if i % 2 == 0:  # keep every other call's spikes and gradient (the gradient as x.grad, a storage the
            kept.append((spikes, x))  # autograd engine took over)
            copies.append((spikes.clone(), x.grad.clone()))
    for (spikes, x), (s_copy, g_copy) in zip(kept, copies):
        assert torch.equal(spikes, s_copy) and torch.equal(x.grad, g_copy)
    assert storage_pool.pool_stats()["reused"] >= 3


@needs_kernel
def test_reused_outputs_equal_fresh_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    """The values do not depend on what a reused storage held before (every element is written)."""
    gen = torch.Generator().manual_seed(4)
    x = torch.randn(33, 2, 301, generator=gen) * 0.6 + 0.3
    w = torch.randn(x.shape, generator=gen)
    lif = MultiStepLIF(surrogate="atan", reset="zero")
    out = []
    for pool_bytes in (0, storage_pool.POOL_BYTES, storage_pool.POOL_BYTES):  # fresh, pooled fresh, reused
        monkeypatch.setattr(storage_pool, "POOL_BYTES", pool_bytes)
        leaf = x.clone().requires_grad_(True)
        spikes = lif(leaf)
        (grad,) = torch.autograd.grad((spikes * w).sum(), leaf)
        out.append((spikes.clone(), grad.clone()))
        spikes.fill_(float("nan"))  # poison the storages before they go back to the pool
        grad.fill_(float("nan"))
        del spikes, grad
    assert storage_pool.pool_stats()["reused"] >= 2
    for spikes, grad in out[1:]:
        assert torch.equal(spikes, out[0][0]) and torch.equal(grad, out[0][1])


# --------------------------------------------------------------------- the models' neurons, kernel against torch
def _pair(lif: MultiStepLIF, shape: tuple[int, ...], monkeypatch: pytest.MonkeyPatch, seed: int = 0) -> None:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(shape, generator=gen) * 0.8 + 0.4
    mem0 = torch.randn(shape[1:], generator=gen) * 0.5
    w_s, w_m = torch.randn(shape, generator=gen), torch.randn(shape[1:], generator=gen)
    out = {}
    for path in ("numba", "torch"):
        monkeypatch.setenv(KERNEL_ENV, path)
        xl, ml = x.clone().requires_grad_(True), mem0.clone().requires_grad_(True)
        spikes, mem = lif(xl, ml, return_mem=True)
        grads = torch.autograd.grad((spikes * w_s).sum() + (mem * w_m).sum(), [xl, ml])
        out[path] = (spikes, mem, *grads)
    for name, a, b in zip(("spikes", "membrane", "input gradient", "membrane gradient"), out["numba"], out["torch"]):
        assert torch.equal(a, b), f"{name} differs"


SGNET = dict(beta=0.2, threshold=0.5, reset="zero", surrogate="rect", detach_reset=False)


@needs_kernel
@pytest.mark.parametrize("name,lif,shape", [
    ("sgnet", MultiStepLIF(**SGNET), (40, 2, 2496)), ("sgnet_hidden", MultiStepLIF(**SGNET), (40, 8, 128)),
    ("deeptactile", MultiStepLIF(**SGNET), (30, 2, 39, 64)),
    ("tacformer", LIFConfig().build(), (50, 2, 39, 32)),  # tau 2: input_scale 0.5, folded into the kernel
    ("x_tacformer", LIFConfig().build(), (50, 2, 39, 64)),  # the same neuron (LIFConfig) on its block widths
    ("tacformer_tau3", LIFConfig(tau=3.0, detach_reset=False).build(), (50, 2, 39, 32)),  # 1/3 rounds
    ("tacformer_subtract", MultiStepLIF(0.5, 1.0, reset="subtract", surrogate="atan", input_scale=0.37),
     (37, 3, 200))])
@pytest.mark.parametrize("threads,forward_chunk", [(1, None), (2, None), (1, 272)])
def test_models_neurons_match_the_torch_path(monkeypatch: pytest.MonkeyPatch, name: str, lif: MultiStepLIF,
                                             shape: tuple[int, ...], threads: int, forward_chunk: int | None) -> None:
    """Whole rows per step (time-major, the default), rows cut into pieces, and two threads."""
    kernels = backend.lif_kernels()
    monkeypatch.setattr(kernels, "CHUNK", 256)  # the backward's chunks (and the parallel builds at these sizes)
    if forward_chunk:
        monkeypatch.setattr(kernels, "FORWARD_CHUNK", forward_chunk)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        _pair(lif, shape, monkeypatch)
    finally:
        torch.set_num_threads(before)


@needs_kernel
def test_input_scale_runs_inside_the_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    """No separate ``x * input_scale`` pass on the compiled path: the kernel receives the unscaled input."""
    monkeypatch.setenv(KERNEL_ENV, "numba")
    seen = []
    real = compiled.compiled_forward

    def spy(kernels, x, *args, **kw):  # noqa: ANN001, ANN002, ANN003, ANN202
        seen.append((x, kw.get("input_scale")))
        return real(kernels, x, *args, **kw)

    monkeypatch.setattr(compiled, "compiled_forward", spy)
    x = torch.randn(5, 3, requires_grad=True)
    LIFConfig().build()(x)
    assert seen[0][0].data_ptr() == x.data_ptr() and seen[0][1] == 0.5


def test_forward_chunks() -> None:
    kernels = backend.lif_kernels()
    if kernels is None:
        pytest.skip("no compiled kernel")
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert compiled._forward_chunk(kernels, 32 * 2496) == 32 * 2496  # SGnet's batch: one whole row
        assert compiled._forward_chunk(kernels, 300_000) == 100_000  # three even pieces, multiples of 16
        torch.set_num_threads(2)
        assert compiled._forward_chunk(kernels, 32 * 2496) == 16 * 2496  # one piece per thread
        assert compiled._forward_chunk(kernels, 100) == 112  # one chunk: not worth a thread
    finally:
        torch.set_num_threads(before)


# -------------------------------------------------------------------------------------------- active neurons
@pytest.mark.parametrize("shape", [(7, 3, 50), (5, 2, 4, 6), (9,)])
def test_active_spikes(monkeypatch: pytest.MonkeyPatch, shape: tuple[int, ...]) -> None:
    gen = torch.Generator().manual_seed(2)
    spikes = (torch.rand(shape, generator=gen) < 0.3).float()
    spikes.view(-1, shape[-1])[0] = 0  # an empty row
    act = active_spikes(spikes)
    rows = spikes.reshape(-1, shape[-1])
    assert act.indptr.dtype == torch.int64 and act.indices.dtype == torch.int32 and act.rows == rows.shape[0]
    for r in range(rows.shape[0]):
        expect = rows[r].nonzero().flatten()
        assert act.indices[act.indptr[r]:act.indptr[r + 1]].long().tolist() == expect.tolist()
    assert torch.equal(act.to_dense(), spikes)
    other = active_spikes(1.0 - spikes)  # another call while the first result is alive: its storage is kept
    assert torch.equal(act.to_dense(), spikes) and torch.equal(other.to_dense(), 1.0 - spikes)
    monkeypatch.setattr(backend, "event_kernels", lambda: None)  # the torch fallback gives the same arrays
    other = active_spikes(spikes)
    assert torch.equal(other.indptr, act.indptr) and torch.equal(other.indices, act.indices)


def test_return_active_comes_last() -> None:
    lif = MultiStepLIF()
    x = torch.randn(6, 2, 10) + 0.4
    spikes, mem, act = lif(x, return_mem=True, return_active=True)
    assert torch.equal(act.to_dense(), spikes) and mem.shape == (2, 10)
    spikes2, act2 = lif(x, return_active=True)
    assert torch.equal(spikes2, spikes) and torch.equal(act2.indices, act.indices)
    assert isinstance(lif(x), torch.Tensor)
