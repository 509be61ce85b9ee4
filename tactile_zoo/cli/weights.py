"""``tactile-zoo weights`` (the pretrained weights installed, or in a manifest) and ``predict`` (classes of recorded
grasps from their files)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from typing import Any

from .. import registry
from ..errors import ConfigError
from ._common import echo

__all__ = ["add_weights", "add_predict", "add_pretrained_flags", "pretrained_model", "add_raw_flag",
           "preprocessing_of_files", "preprocessing_of_checkpoint"]

logger = logging.getLogger("tactile_zoo.cli")

#: how to use weights that are not installed (your own, from `bench --save-weights` and a manifest)
USE_LOCAL = "Use your own: tactile-zoo predict MODEL --weights FILE.safetensors --manifest FILE.json FILE..."
NOTHING_INSTALLED = ("no pretrained weights installed. From a tactile-zoo checkout: pip install "
                     f"./plugins/tactile-zoo-weights. {USE_LOCAL}")


def add_weights(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("weights", help="list the pretrained weights installed (or in a manifest)",
                       description="List pretrained weights: tag, model, dataset, test accuracy, file size and where "
                                   "they come from (an installed distribution, or a manifest with --manifest).")
    p.add_argument("pattern", nargs="?", default="*", help="fnmatch pattern on the tag, e.g. 'x_tacformer.*'")
    p.add_argument("--manifest", default=None, metavar="FILE.json", help="list this manifest instead")
    p.add_argument("--json", action="store_true", help="print every entry in full as JSON")
    p.set_defaults(handler=_cmd_weights)


def _size(entry: Any) -> str:
    if entry.bytes is None:
        return "?"
    return f"{entry.bytes / 1e6:.1f} MB" if entry.bytes >= 1e6 else f"{entry.bytes / 1e3:.1f} kB"


def _source(entry: Any) -> str:
    local = entry.local_path()
    where = entry.origin or (str(local) if local else "")
    return f"{where} (download: {entry.url})" if entry.url and not (local and local.is_file()) else where


def _cmd_weights(args: argparse.Namespace) -> int:
    import fnmatch

    from ..weights import list_weights, read_manifest, tag_key, weight_sources

    if args.manifest:
        sources, entries = [], read_manifest(args.manifest)
    else:
        sources, entries = weight_sources(), list_weights()
    shown = [e for e in entries if fnmatch.fnmatchcase(tag_key(e.tag), tag_key(args.pattern))
             or fnmatch.fnmatchcase(e.tag, args.pattern)]
    failed = [s for s in sources if s.status == "failed"]
    if args.json:
        echo(json.dumps({"sources": [vars(s) for s in sources],
                         "weights": [{"qualified_tag": e.qualified_tag, "origin": e.origin, **e.to_dict()}
                                     for e in shown]}, indent=2))
        return 1 if failed and registry._strict() else 0
    for src in failed:
        print(f"tactile-zoo: warning: weights distribution {src.dist} {src.version} failed to load: {src.error}",
              file=sys.stderr)
    if not shown:
        if args.manifest:
            echo(f"{args.manifest}: no weights" + (f" match {args.pattern!r}" if args.pattern != "*" else ""))
        elif entries:
            echo(f"no installed weights match {args.pattern!r}")
        elif not registry._enabled():
            echo("weights discovery is disabled (--no-plugins or TACTILE_ZOO_NO_PLUGINS)")
        elif any(s.status == "ok" for s in sources):
            names = ", ".join(f"{s.dist} {s.version}" for s in sources if s.status == "ok")
            echo(f"no pretrained weights yet: {names} is installed, but its manifest lists none. {USE_LOCAL}")
        else:
            echo(NOTHING_INSTALLED)
        return 0
    rows = [(e.qualified_tag if not args.manifest else e.tag, e.model, e.dataset,
             "-" if e.accuracy is None else f"{e.accuracy:.4f}", _size(e), _source(e)) for e in shown]
    head = ("tag", "model", "dataset", "test acc", "size", "source")
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(5)]
    for row in [head, *rows]:
        echo("  ".join(f"{str(v):<{w}}" for v, w in zip(row[:5], widths)) + f"  {row[5]}")
    notes = [e for e in shown if e.note]
    for e in notes:
        echo(f"note ({e.tag}): {e.note}")
    return 1 if failed and registry._strict() else 0


def add_pretrained_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--pretrained", default=None, metavar="DATASET|TAG",
                   help="installed weights: the dataset they were trained on (e.g. ev_objects) or their tag "
                        "(`tactile-zoo weights` lists them)")
    p.add_argument("--weights", default=None, metavar="FILE.safetensors",
                   help="a local weights file (described by --manifest, or by FILE.json / manifest.json next to it)")
    p.add_argument("--manifest", default=None, metavar="FILE.json", help="the manifest describing --weights")


def pretrained_model(model: str, args: argparse.Namespace) -> Any:
    """Model ``model`` with the weights the flags name (``--pretrained``, or ``--weights`` with ``--manifest``)."""
    from ..weights import local_weights
    from ..weights.load import create_model

    if args.pretrained and (args.weights or args.manifest):
        raise ConfigError("give --pretrained (installed weights) or --weights/--manifest (a local file), not both")
    if args.pretrained:
        return create_model(model, pretrained=args.pretrained)
    if args.weights:
        _check_weights_file(args.weights)
    if args.weights and args.manifest:
        return create_model(model, pretrained=local_weights(args.manifest, args.weights, model=model))
    if args.weights:
        return create_model(model, pretrained=args.weights)
    if args.manifest:
        return create_model(model, pretrained=args.manifest)
    raise ConfigError("which weights? give --pretrained DATASET|TAG, or --weights FILE.safetensors (with "
                      "--manifest FILE.json)")


#: suffixes that make a --weights value a file name rather than a tag (a tag's dot separates model and recipe)
_FILE_SUFFIXES = (".safetensors", ".json", ".npy", ".npz", ".csv", ".pt", ".pth", ".ckpt", ".bin", ".onnx", ".h5",
                  ".hdf5", ".pkl", ".txt", ".zip")


def _check_weights_file(text: str) -> None:
    """``--weights`` names a ``.safetensors`` file (or, as ``--pretrained`` does, an installed tag). A value that
    looks like a path (a folder separator, a file suffix, or something that exists) but is not an existing
    ``.safetensors`` or manifest ``.json`` file is refused here, saying what the flag expects and what the path is,
    rather than being looked up as a tag."""
    import os
    from pathlib import Path

    path = Path(text).expanduser()
    suffix = path.suffix.lower()
    if not ("/" in text or os.sep in text or suffix in _FILE_SUFFIXES or path.exists()):
        return  # a tag: resolved (and refused, listing the installed ones) as --pretrained resolves it
    expects = ("--weights expects a .safetensors weights file (described by --manifest FILE.json, or by FILE.json "
               "or manifest.json next to it; installed weights go by --pretrained DATASET|TAG)")
    if suffix in (".safetensors", ".json") and path.is_file():
        return
    if path.is_dir():
        raise ConfigError(f"{expects}; {text} is a folder")
    if not path.exists():
        raise ConfigError(f"{expects}; {text} does not exist")
    raise ConfigError(f"{expects}; {text} exists but is a {suffix or 'suffix-less'} file"
                      + (" (a recording? predict and stream take recordings as FILE arguments or --file)"
                         if suffix in (".npy", ".csv") else ""))


def add_predict(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="classify recorded grasps (.csv/.npy files) with pretrained weights or a "
                                       "checkpoint",
                       description="Print the most probable classes of each recording. A file is one grasp in the "
                                   "bring-your-own recordings format: one row per time step, the taxel readings in "
                                   "row-major taxel order (all channels of a taxel together), then the global "
                                   "features, in the units the weights' dataset feeds its models. A longer recording "
                                   "is cut to the weights' number of steps; --length pad or resample accept shorter "
                                   "ones. A file that cannot be read gets one error line and the others are still "
                                   "answered; the exit status is then 1 (2 when no file could be read).")
    p.add_argument("model", metavar="MODEL|CHECKPOINT",
                   help="a model name, e.g. x_tacformer (with --pretrained or --weights), or a checkpoint saved by "
                        "`tactile-zoo train MODEL DATASET --save FILE.pt`")
    p.add_argument("files", nargs="+", metavar="FILE", help=".csv or .npy recordings")
    add_pretrained_flags(p)
    p.add_argument("--top-k", dest="top_k", type=int, default=3, metavar="K", help="classes per file (default 3)")
    p.add_argument("--length", default="crop", choices=["crop", "pad", "resample"],
                   help="a recording of another length: crop (default: cut a longer one, refuse a shorter one), pad "
                        "(zeros after a shorter one), resample (linear interpolation onto the weights' steps)")
    add_raw_flag(p, checkpoints=True)
    p.add_argument("--device", default="cpu", help="cpu (default), cuda, auto")
    p.add_argument("--json", action="store_true", help="print the predictions as JSON")
    p.set_defaults(handler=_cmd_predict)


def add_raw_flag(p: argparse.ArgumentParser, checkpoints: bool = False) -> None:
    """``--raw``; ``checkpoints``: the command also reads ``train --save`` checkpoints, which carry it too."""
    whose, where = ("of the weights (or of the checkpoint)", "in their manifest, or in the checkpoint") \
        if checkpoints else ("of the weights", "in their manifest")
    p.add_argument("--raw", action="store_true",
                   help=f"feed the file's values as they are; by default the preprocessing the dataset {whose} applies "
                        f"to a raw recording (recorded {where}: BioTac-DoS's normalisation, for instance) is applied "
                        f"first, and named in the output")


def preprocessing_of_files(model: Any, raw: bool) -> tuple[Any, str]:
    """``(the RecordingPreprocessing applied to the files or None, the line saying so)``, resolved as predict does."""
    from ..weights import entry_preprocessing

    entry = model.zoo_pretrained
    if raw:
        return None, "preprocessing: none (--raw: the values as read)"
    applied = entry_preprocessing(entry)
    if applied is None:
        return None, f"preprocessing: none ({entry.dataset} feeds recordings as they are)"
    return applied, f"preprocessing: {applied} (the weights' own, from their manifest; --raw turns it off)"


def preprocessing_of_checkpoint(config: dict[str, Any], where: str, raw: bool) -> tuple[Any, str]:
    """``(the RecordingPreprocessing applied to files or None, the line saying so)`` for a ``train --save``
    checkpoint's ``config``, as :func:`preprocessing_of_files` for weights."""
    from ..weights import checkpoint_preprocessing

    if raw:
        return None, "preprocessing: none (--raw: the values as read)"
    applied = checkpoint_preprocessing(config, where)
    if applied is None:
        return None, f"preprocessing: none ({config['dataset']} feeds recordings as they are)"
    return applied, f"preprocessing: {applied} (the checkpoint's own, as it was trained; --raw turns it off)"


#: suffixes that make predict's MODEL argument a checkpoint file
_CHECKPOINT_SUFFIXES = (".pt", ".pth", ".ckpt")


def _predict_model(args: argparse.Namespace) -> tuple[Any, dict[str, Any], tuple[Any, str]]:
    """``(model, what the output says of it, (preprocessing, its line))`` for pretrained weights or a checkpoint."""
    from pathlib import Path

    if not (args.pretrained or args.weights or args.manifest) and Path(args.model).suffix in _CHECKPOINT_SUFFIXES:
        from ..data.spec import DatasetSpec
        from ..engine import build_from_checkpoint, load_checkpoint

        blob = load_checkpoint(args.model)
        config, where = blob["config"], f"checkpoint {args.model}"
        if not config.get("spec"):
            raise ConfigError(f"{where} does not record the spec it was trained for, which predict needs")
        model = build_from_checkpoint(blob, DatasetSpec.from_dict(config["spec"], where=where), where=where)
        about = {"model": config["model"], "weights": None, "checkpoint": args.model, "dataset": config.get("dataset"),
                 "test_accuracy": (config.get("metrics") or {}).get("accuracy"), "note": None,
                 "label": f"checkpoint {args.model}", "classes": config["spec"]["class_names"],
                 "steps": config["spec"]["num_steps"]}
        return model, about, preprocessing_of_checkpoint(config, where, args.raw)
    model = pretrained_model(args.model, args)
    entry = model.zoo_pretrained
    about = {"model": entry.model, "weights": entry.qualified_tag, "checkpoint": None, "dataset": entry.dataset,
             "test_accuracy": entry.accuracy, "note": entry.note or None, "label": f"weights {entry.qualified_tag}",
             "classes": entry.spec["class_names"], "steps": entry.spec["num_steps"]}
    return model, about, preprocessing_of_files(model, args.raw)


def _cmd_predict(args: argparse.Namespace) -> int:
    """Answer every file that can be read, as the files are read (in bounded batches, so any number of files fits in
    memory); each one that cannot gets one error line (naming it and what is wrong). Exit 0 when all were answered,
    1 when some were, 2 when none was."""
    from ..weights import Refused, iter_predict

    if args.top_k < 1:
        raise ConfigError(f"--top-k must be a positive integer, got {args.top_k}")
    model, about, (applied, preprocessing) = _predict_model(args)
    answers = iter_predict(model, args.files, top_k=args.top_k, length=args.length, device=args.device,
                           on_error="report", raw=args.raw)
    results: list[dict[str, Any]] = []  # --json: the small per-file summaries only, never the inputs
    refused: list[Any] = []
    answered = 0
    width = max(len("class"), *(len(name) for name in about["classes"]))
    for r in answers:
        if isinstance(r, Refused):
            logger.error("%s", r.reason)
            refused.append(r)
            continue
        answered += 1
        if args.json:
            results.append({k: v for k, v in r.to_dict().items() if k != "probabilities"})
            continue
        if answered == 1:  # the header with the first answer: nothing on stdout when no file could be read
            accuracy = "" if about["test_accuracy"] is None else f", test accuracy {about['test_accuracy']:.4f}"
            echo(f"{about['model']} with {about['label']} (trained on {about['dataset']}{accuracy})")
            if about["note"]:
                echo(f"note: {about['note']}")
            echo(preprocessing)
        fitted = "" if r.length == "as recorded" else f", {r.length} to {about['steps']}"
        echo(f"{r.source} ({r.steps_read} steps{fitted})")
        for rank, (name, prob) in enumerate(r.top_k, start=1):
            echo(f"  {rank:>2}  {name:<{width}}  {prob:.3f}")
    code = 2 if not answered else 1 if refused else 0
    if args.json and answered:
        echo(json.dumps({**{k: about[k] for k in ("model", "weights", "dataset", "test_accuracy", "note")},
                         **({"checkpoint": about["checkpoint"]} if about["checkpoint"] else {}),
                         "preprocessing": None if applied is None else applied.name, "predictions": results,
                         "refused": [bad.to_dict() for bad in refused]}, indent=2))
    elif refused and answered:
        echo(f"{len(refused)} of {answered + len(refused)} file(s) not answered: "
             f"{', '.join(bad.source for bad in refused)} (why: the error lines on stderr)")
    return code
