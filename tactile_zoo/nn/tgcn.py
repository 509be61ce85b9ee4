"""T-GCN cell of X-Tacformer (paper eqs. 10-13) and attention over frames: the temporal graph attention branch.

Paper: "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition"; the cell follows T-GCN (Zhao et al.,
IEEE T-ITS 2020): a graph convolution of each frame feeds a GRU whose state lives on the taxels.

    u_t = sigmoid(W_u [GC(A, X_t), h_{t-1}] + b_u)                    (eq. 10, update gate)
    r_t = sigmoid(W_r [GC(A, X_t), h_{t-1}] + b_r)                    (eq. 11, reset gate)
    c_t = tanh(W_c [GC(A, X_t), r_t * h_{t-1}] + b_c)                 (eq. 12, candidate)
    h_t = u_t * h_{t-1} + (1 - u_t) * c_t                             (eq. 13)

``W [a, b]`` splits into ``W^x a + W^h b``: the graph convolution and the input halves of all three gates do not depend
on ``h``, so they run once over all ``T * B`` frames (one graph-conv call, one matmul); only the hidden halves
(``H -> 2H`` for u and r, ``H -> H`` for c) loop over time. One GC is shared by the three gates, as eqs. 10-12 write.

Attention over frames (our reading of the paper's temporal attention): each frame's hidden state is pooled over the
taxels to ``f_t``, scored by a small additive (Bahdanau-style) network ``e_t = w^T tanh(W f_t + b)``, and the branch
output is ``sum_t softmax_t(e)_t f_t``. The weights sum to one over the frames seen so far; softmax over a growing
prefix can be updated online (running maximum, denominator and weighted sum), so the branch is causal and streams in
constant memory (:meth:`TemporalGraphAttention.run`).

``temporal_backend="tgt"`` swaps the cell for ``torch_geometric_temporal``'s ``TGCN2``: one ``GCNConv`` (with
self-loops) per gate, each gate's Linear over the concatenation ``[GC_g(A, X_t), h]``, the GCs re-run every step. With
the three GCs given the same weights it computes eqs. 10-13 (tests/nn/test_tgcn.py checks this against
:class:`TGCNCell`); trained, its gates learn separate GCs, so it is an alternative, not the paper's cell.

The optional package is installed with ``pip install --no-deps torch-geometric-temporal==0.56.2`` (``make install``
does it): its release requires torch-sparse, a source-only package that does not build against current torch, and
its package ``__init__`` imports every model, one of which (``nn/recurrent/evolvegcno.py``) imports torch-sparse.
:func:`load_tgcn2` therefore loads the one file that defines ``TGCN2`` (``nn/recurrent/temporalgcn.py``, which
imports only torch and torch_geometric) from the installed distribution, without running the package ``__init__``.
The package is loaded, not copied: nothing of it is vendored here.
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
import sys
from pathlib import Path

import torch
from torch import Tensor, nn

from ..errors import ConfigError
from . import backend as switch
from .backend import TemporalBackend
from .graph import FrameGraphConv

__all__ = ["TGCNCell", "TGCN2Cell", "TemporalAttention", "TemporalGraphAttention", "load_tgcn2", "TGT_INSTALL"]

#: The release of torch-geometric-temporal the ``tgt`` backend is tested with, and how to install it.
TGT_VERSION = "0.56.2"
TGT_INSTALL = f"pip install --no-deps torch-geometric-temporal=={TGT_VERSION}"
_TGT_PACKAGE = "torch_geometric_temporal"  # import name of the distribution torch-geometric-temporal
_TGT_MODULE = ("nn", "recurrent", "temporalgcn.py")  # the file that defines TGCN2, inside the package
_TGT_LOADED_AS = "tactile_zoo.nn._tgt_temporalgcn"  # private module name: the real package stays un-imported

# (taxel states h (B, N, H), running max of the scores (B,), softmax denominator (B,), weighted feature sum (B, F))
BranchState = tuple[Tensor, Tensor, Tensor, Tensor]


class TGCNCell(nn.Module):
    """The T-GCN recurrence, eqs. 10-13, over a whole sequence of graph frames.

    Args:
        in_channels: features per taxel ``C``.
        hidden_channels: GRU state per taxel ``H``.
        edge_index: the taxel graph ``[2, E]``.
        num_nodes: taxels ``N``.
        gc_channels: output width of ``GC(A, X_t)`` (default ``H``).
        graph_backend: ``"dense"`` or ``"pyg"`` (see :class:`FrameGraphConv`).

    Shapes:
        input ``x``: ``(T, B, N, C)``; ``h``: ``(B, N, H)`` or ``None`` (zeros).
        output: ``(T, B, N, H)`` hidden states of every frame, and the last one ``(B, N, H)``.
    """

    def __init__(self, in_channels: int, hidden_channels: int, edge_index: Tensor, num_nodes: int,
                 gc_channels: int | None = None, graph_backend: str = "dense") -> None:
        super().__init__()
        hid = hidden_channels
        gc_channels = gc_channels or hid
        self.hidden_channels = hid
        self.gc = FrameGraphConv(in_channels, gc_channels, edge_index, num_nodes, kind="gcn", backend=graph_backend)
        self.lin_x = nn.Linear(gc_channels, 3 * hid)  # [W_u^x; W_r^x; W_c^x] and [b_u; b_r; b_c]
        self.lin_h_ur = nn.Linear(hid, 2 * hid, bias=False)  # [W_u^h; W_r^h]
        self.lin_h_c = nn.Linear(hid, hid, bias=False)  # W_c^h

    def forward(self, x: Tensor, h: Tensor | None = None) -> tuple[Tensor, Tensor]:
        t, b, n, _ = x.shape
        hid = self.hidden_channels
        gx = self.lin_x(self.gc(x))  # (T, B, N, 3H): every frame's GC and input-side gate terms in one call
        if h is None:
            h = x.new_zeros(b, n, hid)
        hs = []
        for gx_t in gx.unbind(0):  # (B, N, 3H); unbind keeps the backward to one gradient buffer
            ur = torch.sigmoid(gx_t[..., :2 * hid] + self.lin_h_ur(h))  # eqs. 10-11, (B, N, 2H)
            u, r = ur.chunk(2, dim=-1)
            c = torch.tanh(gx_t[..., 2 * hid:] + self.lin_h_c(r * h))  # eq. 12
            h = c + u * (h - c)  # eq. 13: u h + (1 - u) c
            hs.append(h)
        return torch.stack(hs), h  # (T, B, N, H), (B, N, H)


@functools.cache
def load_tgcn2() -> type[nn.Module]:
    """``torch_geometric_temporal``'s ``TGCN2`` class, loaded from the installed distribution's
    ``nn/recurrent/temporalgcn.py`` alone.

    ``import torch_geometric_temporal`` would run the package ``__init__``, which imports every model, and
    ``nn/recurrent/evolvegcno.py`` among them imports torch-sparse (absent: it does not build here). So the package is
    only located (``find_spec`` of a top-level name does not execute it) and that one file is executed as a private
    module; it imports only torch and torch_geometric. If the real module was already imported (an environment with
    torch-sparse), that one is used. Raises :class:`ConfigError` naming the install command when the package is
    missing or its layout differs.
    """
    module = sys.modules.get(f"{_TGT_PACKAGE}.nn.recurrent.temporalgcn") or sys.modules.get(_TGT_LOADED_AS)
    if module is None:
        spec = importlib.util.find_spec(_TGT_PACKAGE)
        if spec is None or not spec.submodule_search_locations:
            raise ConfigError(f"temporal_backend='tgt' needs torch-geometric-temporal, which is not installed: "
                              f"run `{TGT_INSTALL}` (--no-deps: its release requires torch-sparse, which does not "
                              f"build against current torch; the TGCN2 cell needs only torch and torch-geometric), "
                              f"or use temporal_backend='native'")
        path = Path(next(iter(spec.submodule_search_locations)), *_TGT_MODULE)
        if not path.is_file():
            raise ConfigError(f"torch-geometric-temporal {_tgt_version()} has no {'/'.join(_TGT_MODULE)} (at {path}); "
                              f"temporal_backend='tgt' is tested with `{TGT_INSTALL}`")
        file_spec = importlib.util.spec_from_file_location(_TGT_LOADED_AS, path)
        module = importlib.util.module_from_spec(file_spec)
        sys.modules[_TGT_LOADED_AS] = module  # so its classes resolve by name (copy, pickle) in this process
        try:
            file_spec.loader.exec_module(module)
        except Exception as exc:
            del sys.modules[_TGT_LOADED_AS]
            raise ConfigError(f"loading TGCN2 from {path} (torch-geometric-temporal {_tgt_version()}) failed: "
                              f"{type(exc).__name__}: {exc}; temporal_backend='tgt' is tested with "
                              f"`{TGT_INSTALL}`") from exc
    cls = getattr(module, "TGCN2", None)
    if not (isinstance(cls, type) and issubclass(cls, nn.Module)):
        raise ConfigError(f"{module.__file__} defines no TGCN2 module (torch-geometric-temporal {_tgt_version()}); "
                          f"temporal_backend='tgt' is tested with `{TGT_INSTALL}`")
    return cls


def _tgt_version() -> str:
    try:
        return importlib.metadata.version("torch-geometric-temporal")
    except importlib.metadata.PackageNotFoundError:
        return "(version unknown)"


class TGCN2Cell(nn.Module):
    """``torch_geometric_temporal``'s ``TGCN2`` stepped over frames, with :class:`TGCNCell`'s interface.

    Not eqs. 10-13 as trained: TGCN2 runs one ``GCNConv`` (with self-loops) per gate on every step (it equals them
    when the three GCs share weights). ``gc_channels`` and ``graph_backend`` are accepted for the interface and unused.
    Raises :class:`ConfigError` when torch-geometric-temporal is not installed (see :func:`load_tgcn2`).
    """

    def __init__(self, in_channels: int, hidden_channels: int, edge_index: Tensor, num_nodes: int,
                 gc_channels: int | None = None, graph_backend: str = "dense") -> None:
        super().__init__()
        tgcn2 = load_tgcn2()
        self.hidden_channels = hidden_channels
        self.cell = tgcn2(in_channels, hidden_channels, batch_size=1)  # batch_size is unused by TGCN2
        self.register_buffer("edge_index", torch.as_tensor(edge_index).long().clone(), persistent=False)

    def forward(self, x: Tensor, h: Tensor | None = None) -> tuple[Tensor, Tensor]:
        _, b, n, _ = x.shape
        if h is None:  # TGCN2's own zero state is float32 whatever the input's dtype
            h = x.new_zeros(b, n, self.hidden_channels)
        hs = []
        for x_t in x.unbind(0):  # (B, N, C)
            h = self.cell(x_t, self.edge_index, None, h)
            hs.append(h)
        return torch.stack(hs), h


class TemporalAttention(nn.Module):
    """Additive attention over frames: ``e_t = w^T tanh(W f_t + b)``, ``alpha = softmax_t(e)``,
    output ``sum_t alpha_t f_t``.

    Args:
        features: width ``F`` of a frame feature.
        attn_dim: width of the scoring network's hidden layer.

    Shapes:
        input ``f``: ``(T, B, F)``; output: ``(B, F)`` and the weights ``alpha`` ``(T, B)`` (sum to one over T).

    The scoring network's last layer has no bias: softmax over frames ignores a constant added to every score.
    """

    def __init__(self, features: int, attn_dim: int = 32) -> None:
        super().__init__()
        self.score = nn.Sequential(nn.Linear(features, attn_dim), nn.Tanh(), nn.Linear(attn_dim, 1, bias=False))

    def forward(self, f: Tensor) -> tuple[Tensor, Tensor]:
        alpha = torch.softmax(self.score(f).squeeze(-1), dim=0)  # (T, B)
        return torch.einsum("tb,tbf->bf", alpha, f), alpha

    def update(self, f: Tensor, state: tuple[Tensor, Tensor, Tensor] | None
               ) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor]]:
        """Online softmax: fold frames ``f (T, B, F)`` into ``state = (max e, sum exp(e - max), sum exp(e - max) f)``
        and return the output over every frame seen so far (equal to :meth:`forward` on the whole prefix)."""
        e = self.score(f).squeeze(-1)  # (T, B)
        m_new = e.max(dim=0).values  # (B,)
        if state is not None:
            m_old, den, num = state
            m_new = torch.maximum(m_old, m_new)
            keep = torch.exp(m_old - m_new)  # (B,)
            den, num = den * keep, num * keep[:, None]
        else:
            den, num = e.new_zeros(e.shape[1]), f.new_zeros(f.shape[1:])
        w = torch.exp(e - m_new)  # (T, B)
        den = den + w.sum(0)
        num = num + torch.einsum("tb,tbf->bf", w, f)
        return num / den[:, None], (m_new, den, num)


class TemporalGraphAttention(nn.Module):
    """The temporal branch: T-GCN over the frames, hidden states pooled per frame, attention over frames.

    Args:
        in_channels, hidden_channels, edge_index, num_nodes: as :class:`TGCNCell`.
        pool: frame feature from the taxel states: ``"mean"`` over taxels (``F = H``) or ``"flatten"``
            (``F = N * H``, keeps which taxel is which).
        attn_dim: hidden width of the frame-scoring network.
        temporal_backend: ``"native"`` (eqs. 10-13) or ``"tgt"`` (torch_geometric_temporal's TGCN2).
        graph_backend: passed to the graph convolution.

    Shapes:
        input ``x``: ``(T, B, N, C)``; output ``(B, F)``.
    """

    def __init__(self, in_channels: int, hidden_channels: int, edge_index: Tensor, num_nodes: int,
                 pool: str = "mean", attn_dim: int = 32, temporal_backend: str = "native",
                 graph_backend: str = "dense") -> None:
        super().__init__()
        temporal = switch.resolve(TemporalBackend, temporal_backend, "temporal_backend", "TemporalGraphAttention")
        cell = TGCN2Cell if temporal is TemporalBackend.TGT else TGCNCell
        if pool not in ("mean", "flatten"):
            raise ConfigError(f"pool must be 'mean' or 'flatten', got {pool!r}")
        self.pool = pool
        self.cell = cell(in_channels, hidden_channels, edge_index, num_nodes, graph_backend=graph_backend)
        self.out_features = hidden_channels * (num_nodes if pool == "flatten" else 1)
        self.attention = TemporalAttention(self.out_features, attn_dim)

    def frame_features(self, hs: Tensor) -> Tensor:
        """``(T, B, N, H)`` taxel states -> ``(T, B, F)`` frame features."""
        return hs.mean(dim=2) if self.pool == "mean" else hs.flatten(2)

    def forward(self, x: Tensor) -> Tensor:
        hs, _ = self.cell(x)  # (T, B, N, H)
        return self.attention(self.frame_features(hs))[0]  # (B, F)

    def run(self, x: Tensor, state: BranchState | None = None) -> tuple[Tensor, BranchState]:
        """Continue from ``state`` over the frames ``x (T, B, N, C)``; returns the output over every frame seen so
        far and the new state (constant size in T)."""
        h, att = (None, None) if state is None else (state[0], state[1:])
        hs, h = self.cell(x, h)
        out, att = self.attention.update(self.frame_features(hs), att)
        return out, (h, *att)

