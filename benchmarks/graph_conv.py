"""Graph convolution over frames, forward + backward: ``FrameGraphConv`` on all frames at once vs PyG per frame.

``TAGConv`` K=3 from 2 to 64 channels (SGnet's first layer) on the NeuTouch graph (39 taxels, the MST SGnet uses),
input ``(B, T, N, C)`` = (32, 250, 39, 2) Ev-Objects-like 0/1 events, a fixed random upstream gradient, backward to
the weights. Fast paths: ``FrameGraphConv`` with the ``dense`` backend (precomputed ``A^k``, matrix products) and
the ``pyg`` backend (one PyG call on ``(B * T, N, C)``). Naive counterparts, all with the very same PyG module:

- ``per_frame``: one ``TAGConv`` call per frame, ``B * T`` calls on ``(N, C)`` (the batch-1 reference's pattern);
- ``per_step``: one call per time step on a ``torch_geometric.data.Batch`` of the ``B`` frames built at that step
  (how a PyG loop over time usually batches).

``max_abs_diff`` compares each fast output with the per-frame output.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor

from .common import PAIR_COLUMNS, Context, pair_row, time_interleaved, write_csv

NAME = "graph_conv"
TITLE = "Graph conv over frames (TAGConv K=3), forward+backward: batched vs one PyG call per frame"
COLUMNS = (*PAIR_COLUMNS, "params", "max_abs_diff", "target")


def per_frame(conv: torch.nn.Module, x: Tensor, edge_index: Tensor) -> Tensor:
    """One PyG call per frame: ``x (B, T, N, C)`` -> ``(B, T, N, F)``."""
    rows = []
    for xb in x.unbind(0):  # (T, N, C)
        rows.append(torch.stack([conv(frame, edge_index) for frame in xb.unbind(0)]))  # (T, N, F)
    return torch.stack(rows)


def per_step(conv: torch.nn.Module, x: Tensor, edge_index: Tensor) -> Tensor:
    """One PyG call per time step on a ``Batch`` of the step's ``B`` frames: ``(B, T, N, C)`` -> ``(B, T, N, F)``."""
    from torch_geometric.data import Batch, Data

    batch, _, nodes, _ = x.shape
    steps = []
    for frames in x.unbind(1):  # (B, N, C), one time step
        graph = Batch.from_data_list([Data(x=f, edge_index=edge_index) for f in frames.unbind(0)])
        steps.append(conv(graph.x, graph.edge_index).view(batch, nodes, -1))  # (B, N, F)
    return torch.stack(steps, dim=1)


def _fwd_bwd(module: torch.nn.Module, forward: Callable[[Tensor], Tensor], x: Tensor, grad_out: Tensor
             ) -> Callable[[], Tensor]:
    def run() -> Tensor:
        module.zero_grad(set_to_none=True)
        out = forward(x)
        out.backward(grad_out)
        return out.detach()

    return run


def run(ctx: Context, batch: int = 32, steps: int = 250, in_channels: int = 2, out_channels: int = 64, hops: int = 3
        ) -> Path:
    from tactile_zoo.data.sensors import NEUTOUCH
    from tactile_zoo.nn.graph import FrameGraphConv

    dev = ctx.device
    nodes, edge_index = NEUTOUCH.num_nodes, NEUTOUCH.edge_index().to(dev)
    gen = torch.Generator().manual_seed(0)
    x = (torch.rand(batch, steps, nodes, in_channels, generator=gen) < 0.128).float().to(dev)  # (B, T, N, C)
    grad_out = torch.randn(batch, steps, nodes, out_channels, generator=gen).to(dev)
    torch.manual_seed(0)
    dense = FrameGraphConv(in_channels, out_channels, edge_index, nodes, kind="tag", K=hops, backend="dense").to(dev)
    pyg = FrameGraphConv(in_channels, out_channels, edge_index, nodes, kind="tag", K=hops, backend="pyg").to(dev)
    pyg.load_state_dict(dense.state_dict())
    conv = dense.conv  # the naive loops call the very same PyG TAGConv
    fns = {
        "dense": _fwd_bwd(dense, dense, x, grad_out),
        "pyg": _fwd_bwd(pyg, pyg, x, grad_out),
        "per_frame": _fwd_bwd(dense, lambda v: per_frame(conv, v, edge_index), x, grad_out),
        "per_step": _fwd_bwd(dense, lambda v: per_step(conv, v, edge_index), x, grad_out),
    }
    outs = {name: fn() for name, fn in fns.items()}  # also the warm-up
    t = time_interleaved(fns, ctx.reps(5, 2), ctx, warmup=0)
    params = f"B={batch} T={steps} N={nodes} C={in_channels}->{out_channels} K={hops}"
    names = {"dense": "FrameGraphConv(backend='dense'), one call", "pyg": "FrameGraphConv(backend='pyg'), one call",
             "per_frame": "TAGConv per frame (B*T calls)", "per_step": "TAGConv per time step on a Batch (T calls)"}
    rows = []
    for naive in ("per_frame", "per_step"):
        for fast in ("dense", "pyg"):
            diff = float((outs[fast] - outs[naive]).abs().max())
            rows.append(pair_row(f"{fast}_vs_{naive}", names[fast], names[naive], t[fast], t[naive], params=params,
                                 max_abs_diff=diff, target=">= 20x faster than per_frame, same outputs"
                                 if naive == "per_frame" else ""))
            ctx.log(f"  {fast} {t[fast].median * 1e3:.1f} ms vs {naive} {t[naive].median * 1e3:.0f} ms -> "
                    f"{rows[-1]['ratio']:.1f}x (max diff {diff:.2g})")
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE", "per_frame", "per_step"]
