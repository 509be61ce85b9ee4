"""Graph convolution over every frame of a sequence at once, on one static sensor graph.

A tactile sequence ``x [B, T, N, F]`` is ``B * T`` graph signals on the same taxel graph. PyG's ``TAGConv``
(Du et al., "Topology Adaptive Graph Convolutional Networks", 2017) and ``GCNConv`` (Kipf & Welling, ICLR 2017)
accept node features with leading batch dimensions and a single ``edge_index`` (they aggregate along
``node_dim=-2``), so one call covers all frames: no per-step ``Data``/``Batch`` objects. With ``A`` the normalised
adjacency PyG builds (``gcn_norm``; ``TAGConv`` without self-loops, ``GCNConv`` with them by default)::

    TAGConv:  X' = sum_{k=0..K} A^k X W_k + b
    GCNConv:  X' = A X W + b

The ``"dense"`` backend (default) precomputes ``A^k`` as dense ``N x N`` matrices from PyG's own ``gcn_norm`` output
and applies them as matrix products: with few features per node as one product of the flat frames ``(M, N*F)`` with
a cached Kronecker matrix ``A^k (x) I_F``, otherwise in a nodes-first layout. It holds the very same PyG module and
reads its weights, so parameters and ``state_dict`` are interchangeable with ``backend="pyg"``, and it equals PyG's
output and gradients to float rounding (tests/nn/test_graph.py). Hops are applied before the weights when
``F_in <= F_out`` (cheaper; PyG's ``TAGConv`` always does so) and after them otherwise (PyG's ``GCNConv`` order).
Measured (1 thread, forward + backward, TAGConv K=3, 2 -> 64 channels, a loaded machine): the dense backend is about
5x faster than one batched PyG call at N = 39 (8000 frames), still 3x at N = 312, and about 100x faster than one PyG
call per frame.

The weights' gradient sums over all ``M * N`` rows (78000 at SGnet's Ev-Objects batch of 8). Autograd's ``linear``
backward asks BLAS for it as ``grad.t() @ input`` with the transposed gradient as a strided view, a call MKL serves
about 8x slower than the same product with that operand contiguous (measured, 1 thread, 78000 x 64 by 78000 x 8:
63 ms vs 7.5 ms). From :data:`TALL_ROWS` rows on, the dense backend copies the operand first
(:class:`_TallLinear`; 2-2.6x faster with the copy, which PyTorch runs on one thread): MKL then computes the same
sums in the same order, so the gradient is bit-identical to autograd's (checked on SGnet and Tacformer at their
recipes' shapes in float32 and float64 at 1 and 2 threads, and in tests/nn/test_graph.py). Not for a weight with a
single row or column: MKL treats that product as a matrix-vector one, whose summation order does depend on the
layout. ``weight_grad="fast"`` (opt-in) never copies and computes ``(input.t() @ grad).t()``: the same sums in
another order (relative differences around 1e-6), 4x faster than with the copy at SGnet's shapes.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..errors import ConfigError
from . import backend as switch
from .backend import GraphBackend, WeightGrad

__all__ = ["FrameGraphConv", "dense_propagator"]

_KINDS = ("tag", "gcn")


def dense_propagator(conv: nn.Module, edge_index: Tensor, num_nodes: int, edge_weight: Tensor | None = None
                     ) -> Tensor:
    """The hop matrices ``[H, N, N]`` a PyG ``TAGConv`` (``H = K + 1``: ``A^0 .. A^K``) or ``GCNConv`` (``H = 1``)
    applies, built in float64 from PyG's ``gcn_norm`` with the module's own settings.

    Row ``i`` of ``A`` gathers node ``i``'s incoming messages: ``A[i, j]`` sums the weights of edges ``j -> i``
    (for ``flow="source_to_target"``; transposed for ``"target_to_source"``).
    """
    from torch_geometric.nn import GCNConv, TAGConv
    from torch_geometric.nn.conv.gcn_conv import gcn_norm

    if getattr(conv, "aggr", "add") != "add":
        raise ConfigError(f"the dense graph backend needs aggr='add', the layer has aggr={conv.aggr!r}; "
                          f"use backend='pyg'")
    weight = None if edge_weight is None else edge_weight.to(torch.float64)
    if isinstance(conv, TAGConv):
        hops, self_loops, improved = conv.K + 1, False, False
    elif isinstance(conv, GCNConv):
        hops, self_loops, improved = 1, conv.add_self_loops, conv.improved
    else:
        raise ConfigError(f"dense_propagator supports TAGConv and GCNConv, got {type(conv).__name__}")
    if conv.normalize:
        edge_index, weight = gcn_norm(edge_index, weight, num_nodes, improved, self_loops, conv.flow, torch.float64)
    elif weight is None:
        weight = torch.ones(edge_index.shape[1], dtype=torch.float64)
    dst, src = (edge_index[1], edge_index[0]) if conv.flow == "source_to_target" else (edge_index[0], edge_index[1])
    adj = torch.zeros(num_nodes, num_nodes, dtype=torch.float64)
    adj.index_put_((dst, src), weight, accumulate=True)
    if hops == 1 and isinstance(conv, GCNConv):
        return adj.unsqueeze(0)
    powers = [torch.eye(num_nodes, dtype=torch.float64)]
    for _ in range(hops - 1):
        powers.append(adj @ powers[-1])
    return torch.stack(powers)


class FrameGraphConv(nn.Module):
    """``TAGConv`` or ``GCNConv`` applied to every frame of a batch of sequences in one call.

    Args:
        in_channels: input features per node ``F_in``.
        out_channels: output features per node ``F_out``.
        edge_index: the static graph, ``LongTensor [2, E]`` (e.g. ``spec.sensor.edge_index()``).
        num_nodes: ``N``.
        kind: ``"tag"`` (``TAGConv``, ``K`` hops) or ``"gcn"`` (``GCNConv``; ``K`` unused).
        K: hops of ``TAGConv``.
        bias: learn an additive bias.
        backend: ``"dense"`` (precomputed hop matrices, default) or ``"pyg"`` (one PyG call on ``[M, N, F]``).
        edge_weight: optional edge weights ``[E]``.
        weight_grad: ``"autograd"`` (default: the weight gradient bit-identical to autograd's ``linear`` backward) or
            ``"fast"`` (the same sums in another order, faster on CPU; dense backend only; see the module docstring).
        **pyg_kwargs: passed to the PyG layer (e.g. ``normalize``, ``improved``, ``add_self_loops``).

    Shapes:
        - input: ``(*, N, F_in)`` with any leading dimensions (e.g. ``B, T``).
        - output: ``(*, N, F_out)``.
    """

    def __init__(self, in_channels: int, out_channels: int, edge_index: Tensor, num_nodes: int, kind: str = "tag",
                 K: int = 3, bias: bool = True, backend: str = "dense", edge_weight: Tensor | None = None,
                 weight_grad: str = "autograd", **pyg_kwargs: Any) -> None:
        super().__init__()
        from torch_geometric.nn import GCNConv, TAGConv

        if kind not in _KINDS:
            raise ConfigError(f"FrameGraphConv kind must be one of {_KINDS}, got {kind!r}")
        backend = switch.resolve(GraphBackend, backend, "backend", "FrameGraphConv")
        for name, value in (("in_channels", in_channels), ("out_channels", out_channels), ("num_nodes", num_nodes)):
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"FrameGraphConv {name} must be a positive int, got {value!r}")
        if kind == "tag" and (not isinstance(K, int) or K < 0):
            raise ConfigError(f"FrameGraphConv K must be a non-negative int, got {K!r}")
        edge_index = torch.as_tensor(edge_index)
        if edge_index.dim() != 2 or edge_index.shape[0] != 2 or edge_index.is_floating_point():
            raise ConfigError(f"edge_index must be an integer tensor [2, E], got {edge_index.dtype} "
                              f"{tuple(edge_index.shape)}")
        if edge_index.numel() and (edge_index.min() < 0 or edge_index.max() >= num_nodes):
            raise ConfigError(f"edge_index refers to nodes outside 0..{num_nodes - 1}")
        if edge_weight is not None and tuple(edge_weight.shape) != (edge_index.shape[1],):
            raise ConfigError(f"edge_weight must have shape [{edge_index.shape[1]}], got {tuple(edge_weight.shape)}")
        self.in_channels, self.out_channels, self.num_nodes = in_channels, out_channels, num_nodes
        weight_grad = switch.resolve(WeightGrad, weight_grad, "weight_grad", "FrameGraphConv")
        if weight_grad is not WeightGrad.AUTOGRAD and backend is not GraphBackend.DENSE:
            raise ConfigError(f"FrameGraphConv: weight_grad={weight_grad.value!r} needs the dense backend, got "
                              f"backend={backend.value!r}")
        self.kind, self.backend, self.weight_grad = kind, backend, weight_grad
        try:
            if kind == "tag":
                self.conv = TAGConv(in_channels, out_channels, K=K, bias=bias, **pyg_kwargs)
            else:
                self.conv = GCNConv(in_channels, out_channels, bias=bias, **pyg_kwargs)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"bad PyG arguments {pyg_kwargs} for FrameGraphConv(kind={kind!r}): {exc}") from None
        edge_index = edge_index.long()
        # graph buffers follow .to(device) but stay out of the state_dict, which matches a bare PyG module's
        self.register_buffer("edge_index", edge_index, persistent=False)
        self.register_buffer("edge_weight", None if edge_weight is None else edge_weight.float(), persistent=False)
        dense = backend is GraphBackend.DENSE
        propagator = dense_propagator(self.conv, edge_index, num_nodes, edge_weight) if dense else None
        # kept in float64 (cast per call, it is tiny) so a float64 module matches PyG to float64 rounding
        self.register_buffer("propagator", propagator, persistent=False)

    def extra_repr(self) -> str:
        return f"kind={self.kind}, num_nodes={self.num_nodes}, backend={self.backend}"

    def hop_weights(self) -> list[Tensor]:
        """The PyG module's weight matrices ``[F_out, F_in]``, one per hop."""
        lins = self.conv.lins if self.kind == "tag" else [self.conv.lin]
        return [lin.weight for lin in lins]

    def forward(self, x: Tensor) -> Tensor:
        if x.dim() < 2 or x.shape[-2] != self.num_nodes or x.shape[-1] != self.in_channels:
            raise ConfigError(f"FrameGraphConv expects (..., {self.num_nodes}, {self.in_channels}) node features, "
                              f"got {tuple(x.shape)}")
        lead = x.shape[:-2]
        frames = x.reshape(-1, self.num_nodes, self.in_channels)  # (M, N, F_in), M = prod(lead)
        if self.backend is GraphBackend.PYG:
            out = self.conv(frames, self.edge_index, self.edge_weight)
        else:
            out = self._dense(frames)
        return out.reshape(*lead, self.num_nodes, self.out_channels)

    def _dense(self, x: Tensor) -> Tensor:
        prop = self.propagator  # (H, N, N) hop matrices A^k, float64: cast only where used (_kron caches its cast)
        hops, n, m = prop.shape[0], self.num_nodes, x.shape[0]
        f_in, f_out = self.in_channels, self.out_channels
        weights = self.hop_weights()
        if f_in <= f_out:
            # hops first, on the narrow input: Z[m, i, k, f] = sum_j A^k[i, j] x[m, j, f]
            z = _hop(x, prop, self._kron(f_in, x.dtype, adjoint=False))  # (M, N, H, F_in)
            weight = torch.cat(weights, dim=1)  # (F_out, H * F_in)
            return _tall_linear(z.reshape(m, n, hops * f_in), weight, self.conv.bias, self.weight_grad)  # (M, N, F_out)
        # weights first, on the narrow output: out[m, i, f] = sum_{k, j} A^k[i, j] (x W_k^T)[m, j, f]
        y = _tall_linear(x, torch.cat(weights, dim=0), None, self.weight_grad).view(m, n, hops, f_out)
        out = _hop_sum(y, prop, self._kron(f_out, x.dtype, adjoint=True))  # (M, N, F_out)
        return out if self.conv.bias is None else out + self.conv.bias

    def _kron(self, f: int, dtype: torch.dtype, adjoint: bool) -> Tensor | None:
        """The Kronecker propagation matrix for ``f`` features (None above :data:`KRON_LIMIT`), cached: it depends
        on the fixed graph only, and rebuilding it costs more than a streaming step's whole convolution."""
        hops, n = self.propagator.shape[0], self.num_nodes
        if (n * f) * (n * hops * f) > KRON_LIMIT:
            return None
        # Keyed on the buffer object itself (held by the entry, so its identity cannot be reused), not on its
        # data_ptr(): torch.export traces with storage-less fake stand-ins for the buffers, whose data_ptr() raises.
        # A new buffer (.to(), .float()) is a new object and misses, as a moved one did with data_ptr().
        key = (f, adjoint, dtype, self.propagator.device, KRON_LIMIT)
        cache = self.__dict__.setdefault("_kron_cache", {})
        hit = cache.get(key)
        if hit is not None and hit[0] is self.propagator:
            return hit[1]
        prop = self.propagator.to(dtype)
        eye = torch.eye(f, dtype=prop.dtype, device=prop.device)
        if adjoint:  # rows (j, k, f), cols (i, g): kron[(j, k, f), (i, g)] = A^k[i, j] [f == g]
            kron = torch.einsum("kij,fg->jkfig", prop, eye).reshape(n * hops * f, n * f)
        else:  # rows (j, f), cols (i, k, g): kron[(j, f), (i, k, g)] = A^k[i, j] [f == g]
            kron = torch.einsum("kij,fg->jfikg", prop, eye).reshape(n * f, n * hops * f)
        kron = kron.contiguous()
        if not torch.compiler.is_compiling():  # a traced (fake) matrix must not outlive the trace in the cache
            cache.clear()  # one graph, one dtype in use at a time: keep the cache from growing
            cache[key] = (self.propagator, kron)
        return kron


#: Rows (``M * N``) from which the weight gradient's product runs on a contiguous copy of the output gradient: below,
#: MKL's strided call is as fast as the copy alone (measured, 1 thread: the copy pays from about 50000 rows on).
TALL_ROWS = 1 << 16


class _TallLinear(torch.autograd.Function):
    """``F.linear`` for inputs with many rows, whose weight gradient avoids MKL's slow path (see the module
    docstring). The forward call and the input and bias gradients are autograd's own; so is the weight gradient's
    value with ``weight_grad="autograd"``, bit for bit."""

    @staticmethod
    def forward(ctx: Any, x: Tensor, weight: Tensor, bias: Tensor | None, weight_grad: str) -> Tensor:
        ctx.save_for_backward(x, weight)
        ctx.has_bias, ctx.weight_grad = bias is not None, weight_grad
        return F.linear(x, weight, bias)

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, ...]:
        x, weight = ctx.saved_tensors  # plain differentiable ops below: double backward works as through F.linear
        g = grad.reshape(-1, grad.shape[-1])  # (R, F_out): the rows of all leading dimensions, as linear folds them
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:  # linear's own product: grad @ weight
            grad_x = torch.mm(g, weight).view(x.shape)
        if ctx.needs_input_grad[1]:
            rows = x.reshape(-1, x.shape[-1])  # (R, F_in)
            if ctx.weight_grad == WeightGrad.FAST:  # (x^T g)^T: BLAS's quick path as is, another summation order
                grad_w = torch.mm(rows.t(), g).t()
            else:  # autograd's grad^T x, with grad^T copied: the same MKL sums, without its slow strided path
                grad_w = torch.mm(g.t().contiguous(), rows)
        if ctx.has_bias and ctx.needs_input_grad[2]:
            grad_b = g.sum(0)
        return grad_x, grad_w, grad_b, None


def _tall_linear(x: Tensor, weight: Tensor, bias: Tensor | None, weight_grad: str = WeightGrad.AUTOGRAD) -> Tensor:
    """``F.linear(x, weight, bias)`` for ``x (..., F_in)``; backward as :class:`_TallLinear` where that helps.

    Plain ``F.linear`` (autograd's backward) without gradients, off CPU (the layout of the weight gradient's product
    only matters to CPU BLAS), and with ``weight_grad="autograd"`` below :data:`TALL_ROWS` rows or for a weight with
    a single row or column (see the module docstring)."""
    if x.device.type != "cpu" or not torch.is_grad_enabled() or not (weight.requires_grad or x.requires_grad or (
            bias is not None and bias.requires_grad)):
        return F.linear(x, weight, bias)
    if weight_grad == WeightGrad.AUTOGRAD and (x.numel() < TALL_ROWS * x.shape[-1] or min(weight.shape) < 2):
        return F.linear(x, weight, bias)
    return _TallLinear.apply(x, weight, bias, weight_grad)


#: Largest Kronecker propagation matrix (entries) used; above it the hop runs as one product in a transposed layout.
KRON_LIMIT = 1 << 20


def _hop(x: Tensor, prop: Tensor, kron: Tensor | None) -> Tensor:
    """``Z[m, i, k, f] = sum_j prop[k, i, j] x[m, j, f]`` for ``x (M, N, F)``, ``prop (H, N, N)``; returns
    ``(M, N, H, F)``.

    With few features it is one matrix product on the flat frames, ``x (M, N*F) @ kron (N*F, N*H*F)``: no copies and
    no tiny batched products (the Kronecker factor wastes a factor F of multiplications, cheap while F is small).
    Otherwise (``kron`` None) the nodes move to the front, ``(N, M*F)``, for one product with the stacked hops.
    """
    m, n, f = x.shape
    hops = prop.shape[0]
    if kron is not None:
        return (x.reshape(m, n * f) @ kron).view(m, n, hops, f)
    prop = prop.to(x.dtype)
    xt = x.transpose(0, 1).reshape(n, m * f)  # (N, M * F)
    z = (prop.reshape(hops * n, n) @ xt).view(hops, n, m, f)  # (H, N, M, F)
    return z.permute(2, 1, 0, 3)  # (M, N, H, F), a view; the caller's reshape copies


def _hop_sum(y: Tensor, prop: Tensor, kron: Tensor | None) -> Tensor:
    """``out[m, i, f] = sum_{k, j} prop[k, i, j] y[m, j, k, f]`` for ``y (M, N, H, F)``; returns ``(M, N, F)``."""
    m, n, hops, f = y.shape
    if kron is not None:
        return (y.reshape(m, n * hops * f) @ kron).view(m, n, f)
    prop = prop.to(y.dtype)
    yt = y.permute(1, 2, 0, 3).reshape(n * hops, m * f)  # (N * H, M * F), rows (j, k)
    cat = prop.permute(1, 2, 0).reshape(n, n * hops)  # (N, N * H): cat[i, (j, k)] = A^k[i, j]
    return (cat @ yt).view(n, m, f).transpose(0, 1)  # (M, N, F)
