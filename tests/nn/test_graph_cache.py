"""FrameGraphConv's cached Kronecker propagation matrix: reused while the graph buffer is the same, rebuilt when it
is replaced, and never in the way of ``torch.export`` (whose fake tensors have no ``data_ptr()``)."""

from __future__ import annotations

import copy

import pytest
import torch

from tactile_zoo.data.sensors import NEUTOUCH
from tactile_zoo.nn.graph import FrameGraphConv

#: (F_in, F_out): hops before the weights (F_in <= F_out) and after them (the adjoint matrix)
WIDTHS = [(2, 8), (8, 2)]


def _conv(f_in: int, f_out: int) -> FrameGraphConv:
    torch.manual_seed(0)
    return FrameGraphConv(f_in, f_out, NEUTOUCH.edge_index(), NEUTOUCH.num_nodes, kind="tag", K=3).eval()


def _x(f_in: int) -> torch.Tensor:
    return torch.randn(2, 5, NEUTOUCH.num_nodes, f_in, generator=torch.Generator().manual_seed(1))


def _entries(conv: FrameGraphConv) -> list[tuple[torch.Tensor, torch.Tensor]]:
    return list(conv.__dict__.get("_kron_cache", {}).values())


@pytest.mark.parametrize(("f_in", "f_out"), WIDTHS)
def test_torch_export_traces_the_layer_and_computes_the_same(f_in: int, f_out: int) -> None:
    conv, x = _conv(f_in, f_out), _x(f_in)
    with torch.no_grad():
        want = conv(x)
        program = torch.export.export(conv, (x,))  # raised "Cannot access data pointer" with a data_ptr() key
        got = program.module()(x)
        assert torch.equal(conv(x), want)  # eager after the export: the cache still serves real tensors
    assert torch.allclose(got, want, rtol=0, atol=1e-6)
    assert all(type(t) is torch.Tensor for entry in _entries(conv) for t in entry)  # nothing fake stayed behind


@pytest.mark.parametrize(("f_in", "f_out"), WIDTHS)
def test_the_matrix_is_built_once_per_buffer(f_in: int, f_out: int) -> None:
    conv, x = _conv(f_in, f_out), _x(f_in)
    with torch.no_grad():
        first = conv(x)
        (entry,) = _entries(conv)
        assert entry[0] is conv.propagator  # the entry holds the buffer it was built from
        assert torch.equal(conv(x), first)
        assert _entries(conv)[0][1] is entry[1]  # the second call reused the matrix
        assert torch.equal(first, _conv(f_in, f_out)(x))  # and a fresh layer computes the very same numbers


def test_a_replaced_buffer_gets_a_new_matrix() -> None:
    conv, x = _conv(2, 8), _x(2)
    with torch.no_grad():
        conv(x)
        (old,) = _entries(conv)
        # a new buffer object with other values (what .to() or a new graph do): the old matrix must not serve it
        conv.propagator = conv.propagator * 0.5
        halved = conv(x)
        (new,) = _entries(conv)
        assert new[0] is conv.propagator and new[1] is not old[1]
        assert not torch.equal(new[1], old[1])
        double = copy.deepcopy(conv).double()  # .double() converts the float64 buffer in place: same values
        assert torch.allclose(double(x.double()).float(), halved, atol=1e-6)


def test_a_deep_copy_uses_its_own_buffer() -> None:
    conv, x = _conv(2, 8), _x(2)
    with torch.no_grad():
        want = conv(x)
        twin = copy.deepcopy(conv)
        assert _entries(twin)[0][0] is twin.propagator  # the copied entry follows the copied buffer
        assert torch.equal(twin(x), want)
