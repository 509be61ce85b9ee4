"""Spiking multi-head self-attention (MSA-SNN) of X-Tacformer, paper eqs. 7-9.

Paper: "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition". The spatial branch attends, within
each frame, over the taxel tokens of that frame; a LIF neuron between every pair of linear maps makes the block
spiking, while Q, K and V themselves are real valued (they leave a LayerNorm), so the attention product is an ordinary
scaled dot product:

    Q, K, V = LN(Linear(LIF(LN(Linear(X)))))          (eq. 7; one such chain per Q, K and V, own weights each)
    MSA'    = softmax(Q K^T / sqrt(d_k)) V            (eq. 8; per head, d_k = dim / heads)
    MSA     = LN(Linear(LIF(MSA')))                    (eq. 9; heads concatenated first)

Reading of eq. 7 (our decision): it names one expression for three outputs; we give each of Q, K and V its own
weights and LayerNorm affine parameters (as Spikformer does for its Q, K, V chains) rather than one shared chain
that would make Q = K = V. The three chains still run as one op each: the first Linear is one ``dim -> 3 dim``
matmul, the three LayerNorms and the LIF run on the stacked ``(..., 3, dim)`` tensor, and the second Linear is one
batched matmul over the three branches.

The LIF neurons are the paper's (eqs. 2-4 via :meth:`MultiStepLIF.from_tau`) and run over time, so the input carries
a leading time axis; attention is within a frame, never across frames, which keeps the block causal in time (the LIF
membranes are the only state carried between frames; see :meth:`SpikingSelfAttention.run`).

Eq. 8 has two implementations (``attention=``): ``"fused"`` is ``F.scaled_dot_product_attention``, on CPU a
flash-attention kernel built for long sequences, which tiles the scores and recomputes them in the backward;
``"explicit"`` (:func:`explicit_attention`) forms the whole ``(L, L)`` score matrix with batched matmuls and keeps
the softmax probabilities for the backward. For Tacformer's 39 taxel tokens (4 heads of 16) the explicit one is
faster on CPU: forward + backward of the attention 1.26x, a whole Tacformer training step about 1.05x (one thread,
docs/performance.md). The two agree to float rounding, not bit for bit, so each is a model revision of its own:
Tacformer's and X-Tacformer's revision 2 compute ``"fused"``, revision 3 (their default) ``"explicit"``
(docs/revisions.md). The class's own default stays ``"fused"``.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from ..errors import ConfigError
from . import backend as switch
from .backend import Attention
from .lif import LIFConfig

__all__ = ["SpikingSelfAttention", "explicit_attention", "ATTENTION_KINDS"]

MSAState = tuple[Tensor | None, Tensor | None]  # (Q/K/V-chain membrane, output-chain membrane)
#: the implementations of eq. 8 (see the module docstring): ``"fused"`` (``F.scaled_dot_product_attention``, the
#: default) and ``"explicit"`` (:func:`explicit_attention`); :class:`~tactile_zoo.nn.backend.Attention`
ATTENTION_KINDS = tuple(choice.value for choice in Attention)


class _ExplicitAttention(torch.autograd.Function):
    """``dropout(softmax(scale Q K^T)) V`` on Q, K and V packed in one head-major tensor, as one autograd node.

    The forward keeps the probabilities ``P`` (and the dropout mask), so the backward is four batched matmuls and the
    softmax gradient, nothing recomputed; it writes dQ, dK and dV straight into one packed gradient, so no stack
    copies them together afterwards. The scale rides on the matmuls' ``alpha`` (``baddbmm`` at ``beta = 0``)
    instead of a pass of its own over the scores.
    """

    @staticmethod
    def forward(ctx: Any, qkv: Tensor, scale: float, mask: Tensor | None) -> Tensor:  # (3, B, L, d), (B, L, L)
        q, k, v = qkv.unbind(0)
        zero = qkv.new_zeros(())  # baddbmm's ``input``, ignored at beta = 0
        p = torch.softmax(torch.baddbmm(zero, q, k.transpose(1, 2), beta=0.0, alpha=scale), dim=-1)  # (B, L, L)
        ctx.save_for_backward(qkv, p, mask)
        ctx.scale = scale
        return torch.bmm(p if mask is None else p * mask, v)  # (B, L, d)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad_o: Tensor) -> tuple[Tensor, None, None]:
        qkv, p, mask = ctx.saved_tensors
        q, k, v = qkv.unbind(0)
        grad_o = grad_o.contiguous()
        grad = torch.empty_like(qkv)  # (3, B, L, d): dQ, dK, dV written in place by the matmuls' ``out``
        zero = qkv.new_zeros(())
        torch.bmm((p if mask is None else p * mask).transpose(1, 2), grad_o, out=grad[2])  # dV = P'^T dO
        grad_p = torch.bmm(grad_o, v.transpose(1, 2))  # dP' = dO V^T
        if mask is not None:
            grad_p.mul_(mask)  # P' = P * mask
        # dS = P * (dP - rowsum(dP * P)): softmax's own backward kernel (what autograd runs for torch.softmax), one pass
        grad_s = torch._softmax_backward_data(grad_p, p, -1, p.dtype)
        torch.baddbmm(zero, grad_s, k, beta=0.0, alpha=ctx.scale, out=grad[0])  # dQ = scale dS K
        torch.baddbmm(zero, grad_s.transpose(1, 2), q, beta=0.0, alpha=ctx.scale, out=grad[1])  # dK = scale dS^T Q
        return grad, None, None


def _traced(qkv: Tensor) -> bool:
    """Whether a tracer records this call (TorchScript's trace, the ONNX exporter, ``torch.compile``, a fake or
    functional tensor): it cannot record a Python autograd Function."""
    return (torch.jit.is_tracing() or torch.onnx.is_in_onnx_export() or torch.compiler.is_compiling()
            or type(qkv) is not Tensor)


def _packed_attention(qkv: Tensor, dropout_p: float) -> Tensor:
    """Eq. 8 on packed, contiguous ``qkv (3, B, L, d)`` -> ``(B, L, d)``; dropout (training only: the caller passes
    0 otherwise) draws its mask as ``F.dropout`` does, ``bernoulli(1 - p) / (1 - p)`` on the probabilities.

    Under a tracer the same forward ops run as ordinary differentiable ops (the same numbers; an exported file holds
    them), since a tracer cannot record the autograd Function."""
    _, b, n, d = qkv.shape
    mask = None
    if dropout_p > 0.0:
        mask = qkv.new_empty(b, n, n).bernoulli_(1.0 - dropout_p).div_(1.0 - dropout_p)
    if _traced(qkv):
        q, k, v = qkv.unbind(0)
        p = torch.softmax(torch.baddbmm(qkv.new_zeros(()), q, k.transpose(1, 2), beta=0.0, alpha=1.0 / math.sqrt(d)),
                          dim=-1)
        return torch.bmm(p if mask is None else p * mask, v)
    return _ExplicitAttention.apply(qkv, 1.0 / math.sqrt(d), mask)


def explicit_attention(q: Tensor, k: Tensor, v: Tensor, dropout_p: float = 0.0) -> Tensor:
    """Self-attention ``softmax(Q K^T / sqrt(d_k)) V`` with the whole score matrix in memory: what
    ``F.scaled_dot_product_attention(q, k, v, dropout_p=dropout_p)`` computes (no mask, not causal), up to float
    rounding, and faster than it on CPU for short sequences (tens of tokens; see the module docstring).

    Args:
        q, k, v: queries, keys and values, one shape; any layout (copied into one packed tensor).
        dropout_p: dropout on the attention probabilities (kept ones scaled by ``1 / (1 - p)``, as SDPA does); pass
            0 outside training.

    Shapes:
        ``q, k, v (*, L, d_k)`` -> ``(*, L, d_k)``.
    """
    if not q.shape == k.shape == v.shape:
        raise ConfigError(f"explicit_attention: q, k and v must have one shape (self-attention), got {tuple(q.shape)}, "
                         f"{tuple(k.shape)} and {tuple(v.shape)}")
    qkv = torch.stack([z.reshape(-1, *z.shape[-2:]) for z in (q, k, v)])  # (3, B, L, d)
    return _packed_attention(qkv, dropout_p).view(q.shape)


class SpikingSelfAttention(nn.Module):
    """MSA-SNN (eqs. 7-9): multi-head self-attention over the ``L`` tokens of every frame, with spiking Q/K/V and
    output chains.

    Args:
        dim: token width ``D`` (input and output).
        num_heads: attention heads; ``D`` must be divisible by it.
        lif: the LIF neurons' configuration (:class:`LIFConfig`).
        attn_dropout: dropout on the attention weights while training.
        attention: eq. 8's implementation, one of :data:`ATTENTION_KINDS`: ``"fused"``
            (``F.scaled_dot_product_attention``) or ``"explicit"`` (:func:`explicit_attention`, faster on CPU for
            tens of tokens); the same up to float rounding.

    Shapes:
        input ``x``: ``(T, *, L, D)`` (time first, any batch dims, tokens, features).
        output: ``(T, *, L, D)``; the attention matrix of each frame is ``(heads, L, L)``.
    """

    def __init__(self, dim: int, num_heads: int = 4, lif: LIFConfig | None = None, attn_dropout: float = 0.0,
                 attention: str = "fused") -> None:
        super().__init__()
        if dim < 1 or num_heads < 1 or dim % num_heads:
            raise ConfigError(f"SpikingSelfAttention: dim={dim} must be a positive multiple of num_heads={num_heads}")
        attention = switch.resolve(Attention, attention, "attention", "SpikingSelfAttention")
        lif = lif or LIFConfig()
        self.dim, self.num_heads, self.attn_dropout, self.attention = dim, num_heads, attn_dropout, attention
        # eq. 7, stage 1 for Q, K and V at once: Linear (dim -> 3 dim), a LayerNorm per branch, LIF
        self.qkv_in = nn.Linear(dim, 3 * dim)
        self.qkv_in_norm_w = nn.Parameter(torch.ones(3, dim))
        self.qkv_in_norm_b = nn.Parameter(torch.zeros(3, dim))
        self.qkv_lif = lif.build()
        # eq. 7, stage 2: one (dim -> dim) Linear per branch as one batched matmul, then a LayerNorm per branch
        self.qkv_out_w = nn.Parameter(torch.empty(3, dim, dim))
        self.qkv_out_b = nn.Parameter(torch.zeros(3, 1, dim))
        self.qkv_out_norm_w = nn.Parameter(torch.ones(3, 1, dim))
        self.qkv_out_norm_b = nn.Parameter(torch.zeros(3, 1, dim))
        # eq. 9: LIF -> Linear -> LayerNorm
        self.out_lif = lif.build()
        self.proj = nn.Linear(dim, dim)
        self.proj_norm = nn.LayerNorm(dim)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        bound = 1.0 / math.sqrt(self.dim)  # nn.Linear's default init, per branch
        nn.init.uniform_(self.qkv_out_w, -bound, bound)
        nn.init.uniform_(self.qkv_out_b, -bound, bound)

    def forward(self, x: Tensor) -> Tensor:
        return self.run(x)[0]

    def _packed_qkv(self, x: Tensor, mem: Tensor | None) -> tuple[Tensor, Tensor]:
        """Eq. 7 for all frames at once: Q, K, V packed as ``(3, M, D)`` (``M = T * prod(*) * L`` tokens) and the
        LIF membrane."""
        d = x.shape[-1]
        a = self.qkv_in(x).unflatten(-1, (3, d))  # (T, *, L, 3, D)
        a = torch.addcmul(self.qkv_in_norm_b, F.layer_norm(a, (d,)), self.qkv_in_norm_w)  # per-branch affine
        s, mem = self.qkv_lif(a, mem, return_mem=True)  # spikes (T, *, L, 3, D)
        s = s.reshape(-1, 3, d).transpose(0, 1)  # (3, M, D)
        qkv = torch.baddbmm(self.qkv_out_b, s, self.qkv_out_w.transpose(1, 2))  # (3, M, D)
        return torch.addcmul(self.qkv_out_norm_b, F.layer_norm(qkv, (d,)), self.qkv_out_norm_w), mem

    def _qkv(self, x: Tensor, mem: Tensor | None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Eq. 7 for all frames at once: Q, K, V as ``(T * prod(*), heads, L, d_k)`` and the LIF membrane."""
        *_, n_tok, d = x.shape
        qkv, mem = self._packed_qkv(x, mem)
        h, dh = self.num_heads, d // self.num_heads
        q, k, v = (z.view(-1, n_tok, h, dh).transpose(1, 2) for z in qkv.unbind(0))  # (T * prod(*), H, L, dh)
        return q, k, v, mem

    def run(self, x: Tensor, state: MSAState | None = None) -> tuple[Tensor, MSAState]:
        """The block over ``x`` starting from LIF membranes ``state`` (``None``: at rest); returns the output and
        the membranes after the last frame, so feeding a sequence in pieces equals feeding it whole."""
        mem_qkv, mem_out = state if state is not None else (None, None)
        drop = self.attn_dropout if self.training else 0.0
        h, dh = self.num_heads, self.dim // self.num_heads
        if self.attention is Attention.EXPLICIT:
            qkv, mem_qkv = self._packed_qkv(x, mem_qkv)
            # one copy to head-major (3, T * prod(*) * H, L, dh); the kernel's packed gradient comes back through
            # it as one copy too (separate Q, K, V would each be copied, and stacked again in the backward)
            qkv = qkv.view(3, -1, x.shape[-2], h, dh).transpose(2, 3).reshape(3, -1, x.shape[-2], dh)
            o = _packed_attention(qkv, drop).view(-1, h, x.shape[-2], dh)  # (T * prod(*), H, L, dh), eq. 8
        else:
            q, k, v, mem_qkv = self._qkv(x, mem_qkv)
            o = F.scaled_dot_product_attention(q, k, v, dropout_p=drop)  # (T * prod(*), H, L, dh), eq. 8
        o = o.transpose(1, 2).reshape(x.shape)  # heads concatenated: (T, *, L, D)
        s_out, mem_out = self.out_lif(o, mem_out, return_mem=True)  # (T, *, L, D)
        return self.proj_norm(self.proj(s_out)), (mem_qkv, mem_out)  # eq. 9

    def attention_weights(self, x: Tensor) -> Tensor:
        """The softmax attention of every frame, ``(T, *, heads, L, L)`` (for inspection and tests)."""
        q, k, _, _ = self._qkv(x, None)
        w = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(q.shape[-1]), dim=-1)  # (T * prod(*), H, L, L)
        return w.reshape(*x.shape[:-2], self.num_heads, x.shape[-2], x.shape[-2])
