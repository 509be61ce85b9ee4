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
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..errors import ConfigError
from .lif import LIFConfig

__all__ = ["SpikingSelfAttention"]

MSAState = tuple[Tensor | None, Tensor | None]  # (Q/K/V-chain membrane, output-chain membrane)


class SpikingSelfAttention(nn.Module):
    """MSA-SNN (eqs. 7-9): multi-head self-attention over the ``L`` tokens of every frame, with spiking Q/K/V and
    output chains.

    Args:
        dim: token width ``D`` (input and output).
        num_heads: attention heads; ``D`` must be divisible by it.
        lif: the LIF neurons' configuration (:class:`LIFConfig`).
        attn_dropout: dropout on the attention weights while training.

    Shapes:
        input ``x``: ``(T, *, L, D)`` (time first, any batch dims, tokens, features).
        output: ``(T, *, L, D)``; the attention matrix of each frame is ``(heads, L, L)``.
    """

    def __init__(self, dim: int, num_heads: int = 4, lif: LIFConfig | None = None, attn_dropout: float = 0.0) -> None:
        super().__init__()
        if dim < 1 or num_heads < 1 or dim % num_heads:
            raise ConfigError(f"SpikingSelfAttention: dim={dim} must be a positive multiple of num_heads={num_heads}")
        lif = lif or LIFConfig()
        self.dim, self.num_heads, self.attn_dropout = dim, num_heads, attn_dropout
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

    def _qkv(self, x: Tensor, mem: Tensor | None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Eq. 7 for all frames at once: Q, K, V as ``(T * prod(*), heads, L, d_k)`` and the LIF membrane."""
        *_, n_tok, d = x.shape
        h, dh = self.num_heads, d // self.num_heads
        a = self.qkv_in(x).unflatten(-1, (3, d))  # (T, *, L, 3, D)
        a = torch.addcmul(self.qkv_in_norm_b, F.layer_norm(a, (d,)), self.qkv_in_norm_w)  # per-branch affine
        s, mem = self.qkv_lif(a, mem, return_mem=True)  # spikes (T, *, L, 3, D)
        s = s.reshape(-1, 3, d).transpose(0, 1)  # (3, M, D) with M = T * prod(*) * L
        qkv = torch.baddbmm(self.qkv_out_b, s, self.qkv_out_w.transpose(1, 2))  # (3, M, D)
        qkv = torch.addcmul(self.qkv_out_norm_b, F.layer_norm(qkv, (d,)), self.qkv_out_norm_w)
        q, k, v = (z.view(-1, n_tok, h, dh).transpose(1, 2) for z in qkv.unbind(0))  # (T * prod(*), H, L, dh)
        return q, k, v, mem

    def run(self, x: Tensor, state: MSAState | None = None) -> tuple[Tensor, MSAState]:
        """The block over ``x`` starting from LIF membranes ``state`` (``None``: at rest); returns the output and
        the membranes after the last frame, so feeding a sequence in pieces equals feeding it whole."""
        mem_qkv, mem_out = state if state is not None else (None, None)
        q, k, v, mem_qkv = self._qkv(x, mem_qkv)
        drop = self.attn_dropout if self.training else 0.0
        o = F.scaled_dot_product_attention(q, k, v, dropout_p=drop)  # (T * prod(*), H, L, dh), eq. 8
        o = o.transpose(1, 2).reshape(x.shape)  # heads concatenated: (T, *, L, D)
        s_out, mem_out = self.out_lif(o, mem_out, return_mem=True)  # (T, *, L, D)
        return self.proj_norm(self.proj(s_out)), (mem_qkv, mem_out)  # eq. 9

    def attention_weights(self, x: Tensor) -> Tensor:
        """The softmax attention of every frame, ``(T, *, heads, L, L)`` (for inspection and tests)."""
        q, k, _, _ = self._qkv(x, None)
        w = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(q.shape[-1]), dim=-1)  # (T * prod(*), H, L, L)
        return w.reshape(*x.shape[:-2], self.num_heads, x.shape[-2], x.shape[-2])
