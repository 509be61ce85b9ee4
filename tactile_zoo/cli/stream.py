"""``tactile-zoo stream``: replay one recording frame by frame through a streaming model, from a checkpoint or from
pretrained weights, and from a dataset sample or your own recording file."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

from .. import registry
from ._common import add_quiet_flag, checkpoint_dataset, echo, progress_on
from .weights import (
    add_pretrained_flags,
    add_raw_flag,
    preprocessing_of_checkpoint,
    preprocessing_of_files,
    pretrained_model,
)

__all__ = ["add_stream"]


def add_stream(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("stream", help="replay one recording frame by frame through a streaming checkpoint or "
                                      "pretrained weights",
                       description="Feed a recording to a causal model's step() one frame at a time and print, after "
                                   "each frame, the top class and its probability; then, when the true class is known "
                                   "(a dataset sample), when the prediction became correct for good; and the per-step "
                                   "latency. The recording is sample INDEX of a split (--index) or your own file "
                                   "(--file: the bring-your-own format, every row streamed).")
    p.add_argument("checkpoint", metavar="CHECKPOINT|MODEL",
                   help="a checkpoint saved by `tactile-zoo train MODEL DATASET --save FILE`, or a model name with "
                        "--pretrained or --weights")
    add_pretrained_flags(p)
    p.add_argument("--dataset", default=None, help="default: the dataset it was trained on")
    p.add_argument("--index", type=int, default=None, help="sample index in the split (0-based)")
    p.add_argument("--file", default=None, metavar="FILE",
                   help="your recording (.csv/.npy: one row per time step, taxels row-major then globals) instead "
                        "of a dataset sample")
    add_raw_flag(p, checkpoints=True)
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
    add_quiet_flag(p)
    p.set_defaults(handler=_cmd_stream)


def _frame_period(dataset: str) -> float | None:
    """The frame period a dataset class declares (without loading any data), else ``None``."""
    try:
        return getattr(registry.get_dataset_entry(dataset).obj, "frame_period", None)
    except registry.UnknownNameError:
        return None


def _checkpoint_spec(args: argparse.Namespace, config: dict[str, Any]) -> Any:
    from ..data.spec import DatasetSpec
    from ..errors import ConfigError

    if not config.get("spec"):
        raise ConfigError(f"{args.checkpoint} does not record the spec it was trained for, which --file needs")
    return DatasetSpec.from_dict(config["spec"], where=f"checkpoint {args.checkpoint}")


def _top(trace: Any, k: int, names: Sequence[str]) -> tuple[str | None, float]:
    """The top class name after step ``k`` (``None``: a tie, undecided) and its probability."""
    pred = trace.predictions[k - 1]
    first = trace.tied_classes(k)[0] if pred is None else pred
    return (None if pred is None else names[pred]), float(trace.probabilities[k - 1, first])


def _shown_top(trace: Any, k: int, names: Sequence[str]) -> str:
    name, _ = _top(trace, k, names)
    return name if name is not None else f"(tie of {len(trace.tied_classes(k))})"


def _cmd_stream(args: argparse.Namespace) -> int:
    import torch

    from ..engine import build_from_checkpoint, load_checkpoint, resolve_device
    from ..engine.runtime import set_threads
    from ..engine.stream import check_streaming, replay
    from ..errors import ConfigError
    from ..weights import check_fit, read_recording

    if args.every < 1:
        raise ConfigError(f"--every must be a positive integer, got {args.every}")
    if (args.index is None) == (args.file is None):
        raise ConfigError("give --index N (a sample of the dataset) or --file FILE (your recording), one of them")
    registry.import_plugin_modules(args.plugin_modules)
    set_threads(args.threads)
    entry = blob = model = spec = None
    if args.pretrained or args.weights or args.manifest:
        name = args.checkpoint
        check_streaming(name, dict(registry.get_model_entry(name).meta))  # before any weights or data are loaded
        model = pretrained_model(name, args)
        entry = model.zoo_pretrained
        config: dict[str, Any] = {"model": entry.model, "dataset": entry.dataset, "fold": entry.fold,
                                  "dataset_kwargs": dict(entry.dataset_kwargs)}
        spec, label = entry.dataset_spec(), f"weights {entry.qualified_tag}"
    else:
        blob = load_checkpoint(args.checkpoint)
        config, label = blob["config"], args.checkpoint
        name = config["model"]
        check_streaming(name, dict(registry.get_model_entry(name).meta))  # before any data is loaded
    if args.raw and not args.file:
        raise ConfigError("--raw goes with --file (your recording): a dataset sample is already what its loader "
                          "made of the raw recording")
    applied = said = None
    if args.file:
        spec = spec if spec is not None else _checkpoint_spec(args, config)
        # pretrained weights and checkpoints both carry their dataset's preprocessing of a raw recording
        applied, said = preprocessing_of_files(model, args.raw) if entry is not None else \
            preprocessing_of_checkpoint(config, f"checkpoint {args.checkpoint}", args.raw)
        # every row: a stream has no fixed length
        recording = read_recording(args.file, spec, length=None, preprocessing=applied)
        x, g, y = recording.x, recording.g, None
        frame_period, what, source = _frame_period(config["dataset"]), args.file, {"file": args.file}
    else:
        ds, dataset, fold = checkpoint_dataset(args, config, "--dataset")
        if not 0 <= args.index < len(ds):
            raise ConfigError(f"--index {args.index} is out of range: split {args.split!r} of {dataset} (fold {fold}) "
                              f"has {len(ds)} samples (0..{len(ds) - 1})")
        if entry is not None:
            check_fit(entry, ds.spec)
        spec, sample = ds.spec, ds[args.index]
        x, g, y = sample.x, sample.g, int(sample.y)
        frame_period = getattr(ds, "frame_period", None)
        what = f"sample {args.index} of {dataset} [{args.split}, fold {fold}]"
        source = {"dataset": dataset, "split": args.split, "fold": fold, "index": args.index}
    if model is None:
        model = build_from_checkpoint(blob, spec, where=f"checkpoint {args.checkpoint}")
    device = resolve_device(args.device)
    model = model.to(device)
    check_streaming(name, model=model)
    trace = replay(model, x, g, y, frame_period=frame_period, device=device, progress=progress_on(args))
    names, T = spec.class_names, trace.num_steps
    shown = [k for k in range(1, T + 1) if k % args.every == 0 or k == T]
    preds = trace.predictions
    settled, latency = trace.settled, trace.latency_ms()
    known = trace.target is not None

    def when(k: int) -> str:
        seconds = trace.time_of(k)
        return f"{100 * k / T:.1f} % of T" if seconds is None else f"{seconds:.3f} s"

    if args.json:
        steps = [{"step": k, "time_s": trace.time_of(k), "fraction": k / T, "top_class": _top(trace, k, names)[0],
                  "probability": _top(trace, k, names)[1],
                  "tied_classes": [names[c] for c in trace.tied_classes(k)] if preds[k - 1] is None else None,
                  "correct": preds[k - 1] == trace.target if known else None} for k in shown]
        echo(json.dumps({"checkpoint": None if blob is None else args.checkpoint, "model": name,
                         "weights": None if entry is None else entry.qualified_tag, **source,
                         "preprocessing": None if applied is None else applied.name,
                         "num_steps": T, "frame_period_s": trace.frame_period, "loss": trace.loss,
                         "true_class": names[trace.target] if known else None, "steps": steps,
                         "final_scores": trace.scores[-1].tolist(), "settled_step": settled,
                         "settled_time_s": None if settled is None else trace.time_of(settled),
                         "latency_ms": latency, "threads": torch.get_num_threads(), "device": str(device)},
                        indent=2))
        return 0
    width = max(len("top class"), *(len(n) for n in names), *(len(_shown_top(trace, k, names)) for k in shown))
    echo(f"{name} ({label}) on {what}: {T} steps"
         + ("" if trace.frame_period is None else f" of {1000 * trace.frame_period:g} ms"))
    if said is not None:
        echo(said)
    echo(f"{'step':>5}  {'time':>12}  {'top class':<{width}}  {'p':>5}" + ("  correct" if known else ""))
    for k in shown:
        pred = preds[k - 1]
        verdict = "undecided" if pred is None else "yes" if pred == trace.target else "no"
        echo(f"{k:>5}  {when(k):>12}  {_shown_top(trace, k, names):<{width}}  {_top(trace, k, names)[1]:.3f}"
             + (f"  {verdict}" if known else ""))
    name, p = _top(trace, T, names)
    final = (f"undecided: a tie of {len(trace.tied_classes(T))} classes at p {p:.3f} each" if name is None
             else f"{name} (p {p:.3f})")
    if known:
        echo(f"true class: {names[trace.target]}; final prediction: {final}")
        if settled is None:
            why = "undecided (a tie)" if preds[-1] is None else "wrong"
            echo(f"correct and stayed correct: never (the last prediction is {why})")
        else:
            echo(f"correct and stayed correct: from step {settled} of {T} ({when(settled)})")
    else:
        echo(f"final prediction: {final}; the true class of a file is unknown")
    if any(pred is None for pred in preds):
        echo(f"undecided steps: {sum(pred is None for pred in preds)} of {T} (several classes shared the top score; "
             f"a tie names no class and is never counted correct)")
    echo(f"per-step latency: median {latency['median']:.3f} ms, mean {latency['mean']:.3f} ms, max "
         f"{latency['max']:.3f} ms (batch 1, {torch.get_num_threads()} thread(s), {device})")
    return 0
