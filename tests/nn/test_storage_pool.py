"""The storage pool's :func:`reusable_like`: ``empty_like``'s layout on a pooled storage, handed out again only once
nothing refers to it."""

from __future__ import annotations

import torch

from tactile_zoo.nn.storage_pool import clear_pool, reusable_like


def test_reusable_like_keeps_empty_likes_strides() -> None:
    """ConvLSTM's products write its gates in the input convolution's layout; a different layout is a different BLAS
    kernel and changes the last bits, so the pooled buffer must have exactly ``empty_like``'s strides."""
    channels_last = torch.randn(5, 3000, 64).transpose(1, 2)
    for x in (channels_last, torch.randn(5, 64, 3000), torch.randn(1, 64, 1), channels_last[:, :, :7]):
        want = torch.empty_like(x).stride()
        got = reusable_like(x)
        assert got.shape == x.shape and got.stride() == want
        # a layout recorded on the meta device, the memory on the CPU (ConvLSTM's compiled backward does this)
        moved = reusable_like(torch.empty_like(x, device="meta"), x)
        assert moved.device.type == "cpu" and moved.shape == x.shape and moved.stride() == want


def test_reusable_like_hands_a_storage_out_again_only_once_it_is_free() -> None:
    clear_pool()
    x = torch.randn(4, 3000, 64).transpose(1, 2)  # 3 MB: above the pool's smallest size
    first = reusable_like(x)
    ptr = first.untyped_storage().data_ptr()
    view = first[0]
    del first
    held = reusable_like(x)  # a view of ``first`` is alive: a different storage
    assert held.untyped_storage().data_ptr() != ptr
    del view  # the last reference to the first storage: it is free now, and the only free one
    again = reusable_like(x)
    assert again.untyped_storage().data_ptr() == ptr and again.stride() == x.stride()
