"""Event-driven TAGConv: the graph convolution of every frame as one event product over the input events.

``TAGConv`` (Du et al., 2017; PyG's layer, as :class:`~tactile_zoo.nn.graph.FrameGraphConv` applies it) on a frame
``x (N, F_in)`` with hop matrices ``A^k`` and weights ``W_k (F_out, F_in)``::

    out[i, g] = b[g] + sum_{k=0..K} sum_j sum_f A^k[i, j] W_k[g, f] x[j, f]

is linear in the flat frame ``x (N * F_in)``: ``out = x @ E + b`` with the effective matrix
``E[(j, f), (i, g)] = sum_k A^k[i, j] W_k[g, f]`` of shape ``(N * F_in, N * F_out)``. Event-camera inputs are binary
and sparse (Ev-Objects: 12.8 % of the 78 entries of a frame), so the product runs as
:func:`~tactile_zoo.nn.event_linear.event_linear` over the frame's events: each output row is the sum of the rows of
``E`` its events select, and ``E``'s gradient sums the output gradients of the frames where each input was active.
``E`` is rebuilt from the weights at every call (``H * N^2 * F_in * F_out`` multiply-adds, about 0.8 M for SGnet),
and autograd carries its gradient back to the weights and the bias.

The same function as the dense backend, rounded differently (relative differences around 1e-6 in float32;
tests/nn/test_event_graph_conv.py). Off CPU and under a tracer it is the dense backend itself
(``FrameGraphConv``), the oracle.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .backend import GraphBackend
from .event_linear import event_linear, uses_events
from .graph import FrameGraphConv

__all__ = ["event_graph_conv", "effective_matrix"]


def effective_matrix(conv: FrameGraphConv, dtype: torch.dtype) -> Tensor:
    """``E (F_out * N, F_in * N)`` laid out as a linear layer's weight: ``E^T[(i, g), (j, f)] = sum_k A^k[i, j]
    W_k[g, f]`` for the dense-backend TAGConv or GCNConv ``conv`` (differentiable in the weights)."""
    prop = conv.propagator.to(dtype)  # (H, N, N)
    hops, n = prop.shape[0], conv.num_nodes
    weight = torch.stack(conv.hop_weights(), dim=0)  # (H, F_out, F_in)
    if weight.shape[0] != hops:  # GCNConv: one weight, applied after its single hop
        weight = weight.expand(hops, -1, -1)
    return torch.einsum("kij,kgf->igjf", prop, weight).reshape(n * conv.out_channels, n * conv.in_channels)


def event_graph_conv(conv: FrameGraphConv, x: Tensor) -> Tensor:
    """``conv(x)`` computed over the nonzero entries of ``x`` (see the module docstring).

    Args:
        conv: a :class:`~tactile_zoo.nn.graph.FrameGraphConv` with the ``"dense"`` backend (its hop matrices).
        x: node features, mostly zero (binary events).

    Shapes:
        ``x (*, N, F_in)`` -> ``(*, N, F_out)``.
    """
    if conv.backend is not GraphBackend.DENSE or x.dim() < 2 or x.shape[-2:] != (conv.num_nodes, conv.in_channels) \
            or not uses_events(x, conv.hop_weights()[0]):
        return conv(x)  # the dense path: also where it raises on a wrong shape
    lead, n = x.shape[:-2], conv.num_nodes
    matrix = effective_matrix(conv, x.dtype)  # (N * F_out, N * F_in)
    bias = None if conv.conv.bias is None else conv.conv.bias.repeat(n)  # (N * F_out,), node-major like E's rows
    out = event_linear(x.reshape(-1, n * conv.in_channels), matrix, bias)
    return out.view(*lead, n, conv.out_channels)
