"""SGnet training epoch on Ev-Objects: tactile-zoo's SGnet against the public TactileSGNet code, side by side.

``python -m benchmarks.sgnet_reference [--reference DIR] [--threads 1] [--rounds 3] [--reference-samples 32]
[--samples 576] [--quick]`` (also in ``benchmarks.run`` as ``sgnet_reference``, at the suite's ``--threads``; skipped
there, with a message saying why, when no reference folder is given).

Reference (the naive side): the authors' code, https://github.com/clear-nus/TactileSGNet (Gu et al., IROS 2020),
imported at run time from ``--reference DIR`` (default: the environment variable ``TACTILESGNET_DIR``), a folder
holding its ``tactileSGNet.py`` and ``to_graph.py``; none of its code is part of this repository. Get it with
``git clone https://github.com/clear-nus/TactileSGNet`` (or ``git archive`` of a mirror). Its network
(``TactileSGNet(num_classes=36, k=3)``, as its ``main.py`` builds it: TAGConv K=3 2 -> 64 on the taxel graph, then
Linear 2496 -> 128 -> 256 -> 36, LIF ``mem = 0.2 * mem * (1 - spike) + I``, spike where ``mem > 0.5``) takes one
sample ``(39, 2, T)``, time last, as its loader's ``np.load`` gives it, and loops over the time steps itself (a
``torch_geometric`` ``Data`` graph built and a TAGConv call per step). Its training loop as its ``main.py`` runs it:
``nn.MSELoss()`` between output rates and one-hot labels, ``torch.optim.Adam(lr=1e-3, amsgrad=True)``; here at the
recipe's batch of 8: the 8 samples go through the reference's forward one after the other, their rates are stacked
``(8, 36)``, one loss over the batch (the mean over the 8 of the script's per-sample loss) and one Adam step.

Ours (the fast side): ``create_model("sgnet", spec, compute="event")`` (opt-in: the event-driven graph convolution
and first linear layer) and the default ``compute="dense"``, each trained one epoch by the engine (``fit``) with the
registered recipe (batch 8, MSE on rates, Adam amsgrad 1e-3) on the 576 samples of Ev-Objects' released train folder.

The reference is slow (about half a second per sample on one core), so it trains on a class-balanced subset of
``--reference-samples`` samples (``engine.take``, seed 0; the first ones our side sees when it also runs a subset)
and its time is scaled to 576 samples; ours runs the whole epoch (``--samples``: a subset, scaled the same way). The
CSV says how many samples each side timed. All sides take turns in rotating order for ``--rounds`` rounds after one
untimed warm-up batch each, with subnormals flushed to zero (``flush_denormals``) on both sides alike.

Same network: before timing, a second reference network takes the weights of our dense model, and both score the
same samples (``max_rate_diff``: 0 when every output spike agrees; ``check_mean_rate``: our mean output rate on them,
above 0 when the comparison saw spikes); ``same_graph`` says whether the reference's taxel graph
(its ``TactileGraph(3)``) has exactly our default NeuTouch graph's edges. Rows: ``epoch_event`` and ``epoch_dense``
(each of ours against the reference; ``ratio`` = reference seconds per epoch / ours) and ``event_vs_dense``.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib
import io
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from torch import Tensor, nn

from .common import (
    EV_TRAIN_SAMPLES,
    PAIR_COLUMNS,
    BenchmarkSkipped,
    Context,
    Timing,
    ev_objects,
    model_recipe,
    pair_row,
    time_interleaved,
    write_csv,
)

NAME = "sgnet_reference"
TITLE = "SGnet Ev-Objects training epoch: tactile-zoo (compute event and dense) vs the public TactileSGNet code"
COLUMNS = (*PAIR_COLUMNS, "data", "variant", "batch", "fast_samples_timed", "naive_samples_timed",
           "naive_s_per_sample", "same_graph", "max_rate_diff", "check_mean_rate", "reference_sha256", "load_avg")
#: our SGnet computations timed against the reference
VARIANTS = ("event", "dense")
#: the environment variable naming the reference folder when ``--reference`` is not given
REFERENCE_ENV = "TACTILESGNET_DIR"
REFERENCE_URL = "https://github.com/clear-nus/TactileSGNet"
#: the reference's files this benchmark imports (``tactileSGNet`` imports ``to_graph`` by its top-level name)
REFERENCE_FILES = ("tactileSGNet.py", "to_graph.py")
#: the reference's graph argument: its main.py sets ``k = 3``, which (with ``useKNN=0``) builds the taxels' minimum
#: spanning tree
REFERENCE_K = 3
#: the reference's learning rate and optimiser (main.py: ``learning_rate = 1e-3``, ``Adam(..., amsgrad=True)``)
REFERENCE_LR = 1e-3


def reference_dir(arg: str | os.PathLike | None = None) -> Path | None:
    """The reference folder: ``arg``, else ``$TACTILESGNET_DIR``, else None."""
    value = arg if arg is not None else os.environ.get(REFERENCE_ENV) or None
    return Path(value).expanduser().resolve() if value is not None else None


def load_reference(folder: Path | None) -> ModuleType:
    """Import the reference's ``tactileSGNet`` module from ``folder``.

    Raises :class:`~benchmarks.common.BenchmarkSkipped` with what to do when the folder is not given or lacks the
    reference's files. The module prints its configuration when imported; that goes nowhere.
    """
    if folder is None:
        raise BenchmarkSkipped(f"no TactileSGNet reference folder: pass --reference DIR or set ${REFERENCE_ENV} to a "
                               f"checkout of {REFERENCE_URL}")
    missing = [f for f in REFERENCE_FILES if not (folder / f).is_file()]
    if missing:
        raise BenchmarkSkipped(f"{folder} lacks {', '.join(missing)}: it must be a checkout of {REFERENCE_URL}")
    sys.path.insert(0, str(folder))  # its own ``from to_graph import *`` needs the folder on the path
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return importlib.import_module("tactileSGNet")
    finally:
        sys.path.remove(str(folder))


def reference_sha256(folder: Path) -> str:
    """The first 12 hex digits of the SHA-256 of the reference files timed (a checkout exported by ``git archive``
    carries no commit id; this names the exact code)."""
    digest = hashlib.sha256()
    for name in REFERENCE_FILES:
        digest.update((folder / name).read_bytes())
    return digest.hexdigest()[:12]


def to_reference_layout(x: Tensor) -> Tensor:
    """Our samples in the layout the reference's loader gives its network: ``np.load`` of ``sample_*.npy``, taxel x
    polarity x time bin, float32.

    Shapes:
        ``x (S, T, N, C)`` -> ``(S, N, C, T)``, contiguous, so that sample ``s``'s ``split(1, dim=-1)[t].squeeze()``
        (the reference's frame ``t``) is ``x[s, t]``.
    """
    if x.dim() != 4:
        raise ValueError(f"expected samples (S, T, N, C), got shape {tuple(x.shape)}")
    return x.permute(0, 2, 3, 1).contiguous().float()


def reference_targets(y: Tensor, num_classes: int) -> Tensor:
    """The reference's training targets: one-hot rows ``zeros(B, K).scatter_(1, y, 1)``.

    Shapes:
        ``y (B,)`` -> ``(B, K)``.
    """
    return torch.zeros(y.shape[0], num_classes).scatter_(1, y.long().view(-1, 1), 1.0)


def reference_network(ref: ModuleType, num_classes: int, device: torch.device) -> nn.Module:
    """The reference's ``TactileSGNet`` as its main.py builds it (``k = 3``), on ``device``."""
    with contextlib.redirect_stdout(io.StringIO()):
        return ref.TactileSGNet(num_classes, REFERENCE_K, device=str(device)).to(device)


def copy_weights(model: nn.Module, net: nn.Module) -> None:
    """Give the reference network ``net`` the weights of our SGnet ``model`` (both: TAGConv, then three Linears)."""
    net.conv1.load_state_dict(model.gc.conv.state_dict())
    for mine, theirs in zip(model.fcs, (net.fc1, net.fc2, net.fc3)):
        theirs.load_state_dict(mine.state_dict())


def same_graph(model: nn.Module, net: nn.Module) -> bool:
    """Whether the reference's taxel graph has exactly our model's edges (as sets of directed pairs)."""
    theirs = {tuple(e) for e in net.graph.getEdge().t().tolist()}
    ours = {tuple(e) for e in model.gc.edge_index.t().tolist()}
    return theirs == ours


def reference_rates(net: nn.Module, samples: Tensor) -> Tensor:
    """Output rates of the reference network, one sample at a time (the only way it runs).

    Shapes:
        ``samples (S, N, C, T)`` (:func:`to_reference_layout`) -> ``(S, K)``.
    """
    return torch.stack([net(sample) for sample in samples])


def reference_train(net: nn.Module, opt: torch.optim.Optimizer, samples: Tensor, y: Tensor, batch: int) -> float:
    """One pass of the reference's training loop over ``samples`` in consecutive batches of ``batch``: its forward on
    each sample, its loss (``nn.MSELoss()`` against one-hot targets) on the batch's stacked rates, one Adam step per
    batch. Returns the summed loss (as the script's ``running_loss``).

    Shapes:
        ``samples (S, N, C, T)``, ``y (S,)``.
    """
    criterion = nn.MSELoss()
    total = 0.0
    net.train()
    for start in range(0, samples.shape[0], batch):
        net.zero_grad()
        opt.zero_grad()
        outputs = reference_rates(net, samples[start:start + batch])  # (B, K)
        loss = criterion(outputs.cpu(), reference_targets(y[start:start + batch].cpu(), outputs.shape[1]))
        total += loss.item()
        loss.backward()
        opt.step()
    return total


def _scaled(t: Timing, factor: float) -> Timing:
    return Timing([v * factor for v in t.times], [v * factor for v in t.cpu])


def run(ctx: Context, reference: str | os.PathLike | None = None, samples: int | None = None,
        reference_samples: int | None = None, variants: Sequence[str] = VARIANTS, check_samples: int = 4) -> Path:
    from tactile_zoo.engine import fit, take
    from tactile_zoo.engine.runtime import flush_denormals
    from tactile_zoo.registry import instantiate_model

    bad = [v for v in variants if v not in VARIANTS]
    if bad or not variants:
        raise ValueError(f"variants must be among {VARIANTS}, got {list(variants)}")
    folder = reference_dir(reference)
    ref = load_reference(folder)
    data = ev_objects(ctx)
    split, recipe, dev = data.train, model_recipe("sgnet"), ctx.device
    full, size = len(split), recipe.batch_size
    fast_n = min(full, samples or (64 if ctx.quick else full))
    naive_n = min(full, reference_samples or (size if ctx.quick else 4 * size))
    if recipe.loss != "mse_rate" or tuple(recipe.rate_targets) != (1.0, 0.0):  # the reference's loss, or say so
        raise ValueError(f"sgnet's recipe no longer trains the reference's loss: {recipe.loss} {recipe.rate_targets}")
    torch.manual_seed(0)
    models = {v: instantiate_model("sgnet", split.spec, compute=v).to(dev) for v in variants}
    first = next(iter(models.values()))
    for model in models.values():
        model.load_state_dict(first.state_dict())  # the same initial weights on every side of ours
    check = instantiate_model("sgnet", split.spec).to(dev)  # dense, the oracle of the event computation
    check.load_state_dict(first.state_dict())
    twin = reference_network(ref, split.spec.num_classes, dev)
    copy_weights(check, twin)
    graph_same = same_graph(check, twin)
    n_check = min(check_samples, full)
    with torch.no_grad(), flush_denormals():
        ours = check.eval()(split.x[:n_check].to(dev))
        theirs = reference_rates(twin.eval(), to_reference_layout(split.x[:n_check]).to(dev))
    rate_diff, mean_rate = float((ours - theirs).abs().max()), float(ours.mean())
    ctx.log(f"  same network: reference graph {'==' if graph_same else '!='} ours, max |rate difference| "
            f"{rate_diff:g} over {n_check} samples (our weights in the reference's network; mean rate {mean_rate:.3f})")
    del check, twin

    fast_split = take(split, fast_n, seed=0) if fast_n < full else split
    sub = take(split, naive_n, seed=0)
    ref_x, ref_y = to_reference_layout(sub.x).to(dev), sub.y.to(dev)
    torch.manual_seed(0)
    net = reference_network(ref, split.spec.num_classes, dev)
    opt = torch.optim.Adam(net.parameters(), lr=REFERENCE_LR, amsgrad=True)
    fns: dict[str, Any] = {v: (lambda m=m: fit(m, fast_split, recipe=recipe, device=dev, epochs=1))
                           for v, m in models.items()}
    fns["reference"] = lambda: reference_train(net, opt, ref_x, ref_y, size)
    warm = take(split, size, seed=1)
    with ctx.threads_scope(ctx.threads), flush_denormals() as flushing:
        # warm-up outside the timing: one batch through each side
        for model in models.values():
            fit(model, warm, recipe=recipe, device=dev, epochs=1)
        reference_train(net, opt, to_reference_layout(warm.x).to(dev), warm.y.to(dev), size)
        load_before = "/".join(f"{v:.2f}" for v in os.getloadavg())
        t = time_interleaved(fns, ctx.reps(3, 1), ctx, warmup=0)
        load = f"{load_before} -> " + "/".join(f"{v:.2f}" for v in os.getloadavg())
    if not flushing:
        ctx.log("  subnormals were NOT flushed (TACTILE_ZOO_KEEP_DENORMALS or a CPU without the mode)")
    naive = _scaled(t["reference"], EV_TRAIN_SAMPLES / naive_n)
    ours_t = {v: _scaled(t[v], EV_TRAIN_SAMPLES / fast_n) for v in variants}
    note = (f"seconds per epoch of {EV_TRAIN_SAMPLES} samples at batch {size}; reference extrapolated from "
            f"{naive_n} samples" + (f", ours from {fast_n}" if fast_n < EV_TRAIN_SAMPLES else
                                      ", ours measured on the whole epoch")
            + f"; subnormals flushed: {flushing}")
    naive_desc = (f"TactileSGNet public code ({REFERENCE_URL}): per-sample forward, per-step graph + TAGConv, "
                  f"MSELoss one-hot, Adam amsgrad {REFERENCE_LR:g}, one step per batch of {size}")
    common = dict(data=data.source, batch=size, fast_samples_timed=fast_n, naive_samples_timed=naive_n,
                  naive_s_per_sample=t["reference"].median / naive_n, same_graph=graph_same, max_rate_diff=rate_diff,
                  check_mean_rate=mean_rate, reference_sha256=reference_sha256(folder), load_avg=load)
    rows = [pair_row(f"epoch_{v}", f"sgnet compute={v!r}{' (default)' if v == 'dense' else ' (opt-in)'}, engine fit, "
                     f"registered recipe", naive_desc, ours_t[v], naive, **common, variant=v, note=note)
            for v in variants]
    msg = ", ".join(f"{v} {ours_t[v].median:.1f} s -> {rows[i]['ratio']:.0f}x" for i, v in enumerate(variants))
    if set(variants) == {"event", "dense"}:
        rows.append(pair_row("event_vs_dense", "sgnet compute='event' (opt-in)", "sgnet compute='dense' (default)",
                             ours_t["event"], ours_t["dense"], **{**common, "naive_samples_timed": fast_n},
                             variant="event", note="both ours, the same samples in the same rounds"))
        msg += f"; event vs dense {rows[-1]['ratio']:.2f}x"
    ctx.log(f"  epoch: reference {naive.median:.0f} s (extrapolated; {common['naive_s_per_sample']:.2f} s/sample), "
            f"{msg}; load {load}")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.sgnet_reference", description=TITLE)
    parser.add_argument("--reference", default=None, metavar="DIR",
                        help=f"checkout of {REFERENCE_URL} (default ${REFERENCE_ENV}; skipped when neither is given)")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="our computations to time (default event,dense)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--rounds", type=int, default=None, help="timed rounds (default 3)")
    parser.add_argument("--samples", type=int, default=None, help="samples our side trains on (default 576)")
    parser.add_argument("--reference-samples", type=int, default=None,
                        help="samples the reference trains on, scaled to 576 (default 32)")
    parser.add_argument("--quick", action="store_true", help="64 and 8 samples, 1 round: checks that it runs")
    parser.add_argument("--out", type=Path, default=None, help="folder of the CSV (default benchmarks/results)")
    parser.add_argument("--root", type=Path, default=None, help="data home with Ev-Objects")
    args = parser.parse_args(argv)
    from tactile_zoo.engine.runtime import flush_denormals

    ctx = Context(threads=args.threads, quick=args.quick, repeats=args.rounds, root=args.root,
                  **({"out": args.out} if args.out else {}))
    variants = tuple(v.strip() for v in args.variants.split(",") if v.strip())
    try:
        with flush_denormals() as flushing:
            ctx.flush_denormals = flushing
            torch.set_num_threads(args.threads)
            path = run(ctx, reference=args.reference, samples=args.samples, reference_samples=args.reference_samples,
                       variants=variants)
    except BenchmarkSkipped as exc:
        print(f"{NAME} skipped: {exc}", file=sys.stderr)
        return 0
    print(path.read_text())
    return 0


__all__ = ["run", "main", "NAME", "TITLE", "VARIANTS", "reference_dir", "load_reference", "to_reference_layout",
           "reference_targets", "reference_train", "copy_weights", "same_graph"]

if __name__ == "__main__":
    sys.exit(main())
