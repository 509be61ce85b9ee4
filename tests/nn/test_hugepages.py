"""tactile_zoo.nn.hugepages: large CPU outputs advised to use huge pages; the advice never changes a value."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo.nn.lif_compiled as compiled
import tactile_zoo.nn.lif_fused as fused
from tactile_zoo.nn import hugepages, memory, storage_pool
from tactile_zoo.nn.lif import MultiStepLIF


class _Recorder:
    def __init__(self) -> None:
        self.calls: list[tuple[int, int, int]] = []

    def __call__(self, addr: int, length: int, advice: int) -> int:
        self.calls.append((addr, length, advice))
        return 0


@pytest.fixture
def recorder(monkeypatch: pytest.MonkeyPatch) -> _Recorder:
    rec = _Recorder()
    monkeypatch.setattr(hugepages, "_madvise", lambda: rec)
    return rec


def test_large_tensors_get_their_inner_huge_pages_advised(recorder: _Recorder) -> None:
    like = torch.zeros(1, dtype=torch.float64)
    out = hugepages.empty((5, 1 << 20), like)  # 40 MiB
    assert out.shape == (5, 1 << 20) and out.dtype == torch.float64 and out.is_contiguous()
    ((addr, length, advice),) = recorder.calls
    huge = 2 << 20
    assert advice == 14 and addr % huge == 0 and length % huge == 0 and length > 0
    assert out.data_ptr() <= addr and addr + length <= out.data_ptr() + out.numel() * out.element_size()
    assert addr - out.data_ptr() < huge  # every whole huge page inside the tensor, none outside
    assert out.data_ptr() + out.numel() * out.element_size() - (addr + length) < huge


def test_small_tensors_are_left_alone(recorder: _Recorder) -> None:
    out = hugepages.empty((3, 4), torch.zeros(1))
    assert out.shape == (3, 4) and not recorder.calls


def test_opt_out_and_the_real_call(monkeypatch: pytest.MonkeyPatch) -> None:
    hugepages._madvise.cache_clear()
    monkeypatch.setenv("TACTILE_ZOO_NO_HUGEPAGES", "1")
    try:
        assert hugepages._madvise() is None
    finally:
        hugepages._madvise.cache_clear()
    monkeypatch.delenv("TACTILE_ZOO_NO_HUGEPAGES")
    out = hugepages.empty((hugepages.MIN_BYTES // 4 + 12345,), torch.zeros(1))  # the real advice where the OS takes it
    out.copy_(torch.arange(out.numel(), dtype=torch.float32))
    assert out[-1].item() == out.numel() - 1


def test_lif_outputs_do_not_depend_on_huge_pages(recorder: _Recorder, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fused LIF's spikes and gradients are the same numbers whether its outputs are advised or not."""
    gen = torch.Generator().manual_seed(5)
    x = torch.randn(16, 4, 16384, generator=gen) * 0.6 + 0.3  # 4 MiB: holds at least one whole huge page
    w = torch.randn(x.shape, generator=gen)
    results, advised = [], []
    for min_bytes in (hugepages.MIN_BYTES, 0):  # 0: both outputs go through the advice (recorded, not applied)
        monkeypatch.setattr(hugepages, "MIN_BYTES", min_bytes)
        recorder.calls.clear()
        leaf = x.clone().requires_grad_(True)
        spikes = MultiStepLIF(surrogate="atan", detach_reset=True)(leaf)
        (grad,) = torch.autograd.grad((spikes * w).sum(), leaf)
        results.append((spikes, grad))
        advised.append(len(recorder.calls))
    assert advised[0] == 0 and advised[1] >= 1  # the spikes (and the gradient, where aligned) were advised
    # both paths allocate through it
    assert fused.hugepages is hugepages and compiled.hugepages is hugepages
    assert fused.storage_pool is storage_pool and compiled.storage_pool is storage_pool
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])


def test_the_released_path_still_imports() -> None:
    """``tactile_zoo.nn.memory`` (documented in 0.2.0) is a deprecated alias of :mod:`tactile_zoo.nn.hugepages`: the
    same objects, each read warning with the new home."""
    with pytest.warns(DeprecationWarning, match="tactile_zoo.nn.hugepages.empty"):
        assert memory.empty is hugepages.empty
    with pytest.warns(DeprecationWarning, match="MIN_BYTES"):
        assert memory.MIN_BYTES == hugepages.MIN_BYTES
    with pytest.raises(AttributeError):
        memory.reusable  # noqa: B018 - moved to storage_pool, never documented here
