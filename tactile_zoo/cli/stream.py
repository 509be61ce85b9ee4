"""``tactile-zoo stream``: replay one recorded sample frame by frame through a streaming checkpoint."""

from __future__ import annotations

import argparse
import json

from .. import registry
from ._common import checkpoint_dataset, echo

__all__ = ["add_stream"]


def add_stream(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("stream", help="replay one recorded sample frame by frame through a streaming checkpoint",
                       description="Feed sample INDEX of a split to a causal model's step() one frame at a time and "
                                   "print, after each frame, the top class and its probability; then when the "
                                   "prediction became correct for good, and the per-step latency.")
    p.add_argument("checkpoint", help="a checkpoint saved by `tactile-zoo train MODEL DATASET --save FILE`")
    p.add_argument("--dataset", default=None, help="default: the dataset it was trained on")
    p.add_argument("--index", type=int, required=True, help="sample index in the split (0-based)")
    p.add_argument("--split", default="test", help="split to take the sample from (default test)")
    p.add_argument("--fold", default=None, help="fold (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--every", type=int, default=1, metavar="K", help="print every K-th step (and the last)")
    p.add_argument("--root", default=None, help="data home")
    p.add_argument("--dataset-arg", dest="dataset_args", action="append", default=[], metavar="KEY=VALUE",
                   help="dataset keyword argument (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--device", default="cpu", help="cpu (default), cuda, auto")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=[], metavar="MODULE")
    p.add_argument("--json", action="store_true", help="print the trace as JSON")
    p.set_defaults(handler=_cmd_stream)


def _cmd_stream(args: argparse.Namespace) -> int:
    import torch

    from ..engine import build_from_checkpoint, load_checkpoint, resolve_device
    from ..engine.runtime import set_threads
    from ..engine.stream import check_streaming, replay
    from ..errors import ConfigError

    if args.every < 1:
        raise ConfigError(f"--every must be a positive integer, got {args.every}")
    registry.import_plugin_modules(args.plugin_modules)
    set_threads(args.threads)
    blob = load_checkpoint(args.checkpoint)
    config = blob["config"]
    name = config["model"]
    meta = dict(registry.get_model_entry(name).meta)
    check_streaming(name, meta)  # before any data is loaded
    ds, dataset, fold = checkpoint_dataset(args, config, "--dataset")
    if not 0 <= args.index < len(ds):
        raise ConfigError(f"--index {args.index} is out of range: split {args.split!r} of {dataset} (fold {fold}) has "
                          f"{len(ds)} samples (0..{len(ds) - 1})")
    device = resolve_device(args.device)
    model = build_from_checkpoint(blob, ds.spec, where=f"checkpoint {args.checkpoint}").to(device)
    check_streaming(name, model=model)
    sample = ds[args.index]
    trace = replay(model, sample.x, sample.g, int(sample.y), frame_period=getattr(ds, "frame_period", None),
                   device=device)
    names, T = ds.spec.class_names, trace.num_steps
    shown = [k for k in range(1, T + 1) if k % args.every == 0 or k == T]
    probs, preds = trace.probabilities, trace.predictions
    settled, latency = trace.settled, trace.latency_ms()

    def when(k: int) -> str:
        seconds = trace.time_of(k)
        return f"{100 * k / T:.1f} % of T" if seconds is None else f"{seconds:.3f} s"

    if args.json:
        steps = [{"step": k, "time_s": trace.time_of(k), "fraction": k / T, "top_class": names[preds[k - 1]],
                  "probability": float(probs[k - 1, preds[k - 1]]), "correct": preds[k - 1] == trace.target}
                 for k in shown]
        echo(json.dumps({"checkpoint": args.checkpoint, "model": name, "dataset": dataset, "split": args.split,
                           "fold": fold, "index": args.index, "num_steps": T, "frame_period_s": trace.frame_period,
                           "loss": trace.loss, "true_class": names[trace.target], "steps": steps,
                           "final_scores": trace.scores[-1].tolist(), "settled_step": settled,
                           "settled_time_s": None if settled is None else trace.time_of(settled),
                           "latency_ms": latency, "threads": torch.get_num_threads(), "device": str(device)},
                          indent=2))
        return 0
    width = max(len("top class"), *(len(n) for n in names))
    echo(f"{name} ({args.checkpoint}) on sample {args.index} of {dataset} [{args.split}, fold {fold}]: {T} steps"
         + ("" if trace.frame_period is None else f" of {1000 * trace.frame_period:g} ms"))
    echo(f"{'step':>5}  {'time':>12}  {'top class':<{width}}  {'p':>5}  correct")
    for k in shown:
        pred = preds[k - 1]
        echo(f"{k:>5}  {when(k):>12}  {names[pred]:<{width}}  {float(probs[k - 1, pred]):.3f}  "
             f"{'yes' if pred == trace.target else 'no'}")
    final = preds[-1]
    echo(f"true class: {names[trace.target]}; final prediction: {names[final]} (p {float(probs[-1, final]):.3f})")
    if settled is None:
        echo("correct and stayed correct: never (the last prediction is wrong)")
    else:
        echo(f"correct and stayed correct: from step {settled} of {T} ({when(settled)})")
    echo(f"per-step latency: median {latency['median']:.3f} ms, mean {latency['mean']:.3f} ms, max "
         f"{latency['max']:.3f} ms (batch 1, {torch.get_num_threads()} thread(s), {device})")
    return 0
