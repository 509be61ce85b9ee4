"""Frame bins for models that read a coarser clock than the sensor's, and streaming that stays exact with them.

:func:`bin_frames` turns ``(B, T, ...)`` into ``(B, ceil(T / k), ...)`` bins; :class:`BinnedStreamer` gives a model
whose per-bin computation is causal a ``forward`` over bins and a frame-by-frame ``step`` that equals ``forward`` on
every prefix, an open last bin included. Tacformer, X-Tacformer, ConvLSTM and CNN-LSTM build on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn.classifier import ClassifierMixin
from ._inputs import check_inputs

__all__ = ["bin_frames", "bins_for", "BinnedStreamer", "StreamState"]


def bin_frames(x: Tensor, bin_size: int, reduce: str = "sum") -> Tensor:
    """``(B, T, ...) -> (B, ceil(T / bin_size), ...)``: frames summed (or averaged) over consecutive bins.

    A last, partial bin holds the frames there are: a sum over fewer frames, or their mean. That is what makes a
    prefix of any length a valid input, and what streaming reproduces frame by frame.
    """
    if bin_size == 1:
        return x
    b, t = x.shape[:2]
    nb = -(-t // bin_size)
    pad = nb * bin_size - t
    if pad:
        x = torch.cat([x, x.new_zeros(b, pad, *x.shape[2:])], dim=1)
    out = x.reshape(b, nb, bin_size, *x.shape[2:]).sum(2)  # (B, T', ...)
    if reduce == "mean":
        counts = torch.full((nb,), float(bin_size), dtype=x.dtype, device=x.device)
        counts[-1] = bin_size - pad
        out = out / counts.view(1, nb, *([1] * (x.dim() - 2)))
    return out


def bins_for(name: str, num_steps: int, max_frames: int | None) -> int:
    """The bin size that brings ``num_steps`` frames down to at most ``max_frames`` bins (1 when ``None``); ``name``
    is the model named in the error for a bad ``max_frames``."""
    if max_frames is None:
        return 1
    if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
        raise ConfigError(f"{name}: max_frames must be a positive integer or None, got {max_frames!r}")
    return max(1, -(-num_steps // max_frames))


@dataclass
class StreamState:
    """Streaming state: the model's state after the last complete bin, and the frames of the bin being filled."""

    core: Any
    pending_x: Tensor  # (B, N, C) sum of the frames of the open bin
    pending_g: Tensor  # (B, G) sum of their globals
    pending: int  # frames in the open bin


class BinnedStreamer(ClassifierMixin, nn.Module):
    """Streaming for a model whose per-bin computation is causal: ``_advance(xb (T', B, N, C), gb (T', B, G),
    core_state) -> (scores, core_state)`` must fold bins into a state and score everything folded so far. A model
    defines it, or (the built-ins) ``_features`` with the same arguments, returning the classifier's input
    ``(B, F)`` instead of the scores, and ``forward_head``: then ``forward_features`` comes with it.

    :meth:`forward` folds all bins from rest. :meth:`step` feeds one frame: it re-scores the open (partial) bin from
    the state after the last complete bin, and commits the new state only when the bin is full, so the scores at
    every frame equal ``forward`` on that prefix (whose last bin is partial in the same way).
    """

    name: str
    spec: DatasetSpec
    bin_size: int

    def _features(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        raise NotImplementedError

    def _advance(self, xb: Tensor, gb: Tensor | None, core: Any) -> tuple[Tensor, Any]:
        features, core = self._features(xb, gb, core)
        return self.forward_head(features), core

    def _bins(self, x: Tensor, g: Tensor | None) -> tuple[Tensor, Tensor | None]:
        g = check_inputs(self.name, self.spec, x, g)
        xb = bin_frames(x, self.bin_size, "sum").transpose(0, 1)  # (T', B, N, C), time-major
        gb = None if g is None else bin_frames(g, self.bin_size, "mean").transpose(0, 1)  # (T', B, G)
        return xb, gb

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self._advance(*self._bins(x, g), None)[0]

    def forward_features(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """What the classifier reads after all frames, ``(B, F)``."""
        return self._features(*self._bins(x, g), None)[0]

    def init_state(self, batch_size: int) -> StreamState:
        p = next(self.parameters())
        return StreamState(None, p.new_zeros(batch_size, self.spec.num_nodes, self.spec.num_channels),
                           p.new_zeros(batch_size, self.spec.num_globals), 0)

    def step(self, x_t: Tensor, g_t: Tensor | None, state: StreamState) -> tuple[Tensor, StreamState]:
        g_t = check_inputs(self.name, self.spec, x_t, g_t, per_step=True)
        px = state.pending_x + x_t
        pg = state.pending_g if g_t is None else state.pending_g + g_t
        n = state.pending + 1
        scores, core = self._advance(px[None], None if g_t is None else (pg / n)[None], state.core)
        if n == self.bin_size:  # the bin is complete: commit it and open the next
            return scores, StreamState(core, torch.zeros_like(px), torch.zeros_like(pg), 0)
        return scores, StreamState(state.core, px, pg, n)
