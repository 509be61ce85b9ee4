"""``tactile-zoo export``: TorchScript and ONNX files of a model's forward and streaming step, for a robot.

The weights come from installed or local pretrained weights (``--pretrained``, ``--weights``/``--manifest``, as
``predict`` and ``stream`` take them), from a checkpoint of ``tactile-zoo train --save``, or, with ``--spec-from
DATASET``, from a seeded random initialisation for that dataset's spec: the same files and names as trained
weights, for building and testing the robot side before any training (the description says ``"weights": null``).
The files and their names are described in :mod:`tactile_zoo.export`.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .. import registry
from .._signals import TERMINATED_EXIT, Terminated
from ..errors import ConfigError
from ._common import add_quiet_flag, echo, progress_on
from .weights import add_pretrained_flags, pretrained_model

__all__ = ["add_export"]

logger = logging.getLogger(__name__)

#: where the files go without --out
DEFAULT_OUT = "tactile-zoo-export"
_CHECKPOINT_SUFFIXES = (".pt", ".pth", ".ckpt")


def add_export(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write TorchScript and ONNX files of a model's forward and streaming step",
                       description="Export MODEL's full forward (x (B, T, N, C) [, g (B, T, G)] -> scores) and, for "
                                   "a streaming model, its step (x_t (B, N, C) [, g_t (B, G)], state_in_0.. -> "
                                   "scores, state_out_0..) as TorchScript (.pt) and ONNX (.onnx), with "
                                   "MODEL.export.json describing names, shapes, dtypes, the state's initial values, "
                                   "the dataset spec and the preprocessing. Every file is loaded back and checked "
                                   "against the eager model before the command succeeds. Shapes are fixed: "
                                   "--batch and --steps.")
    p.add_argument("model", metavar="MODEL|CHECKPOINT",
                   help="a model name (with --pretrained, --weights or --spec-from), or a checkpoint saved by "
                        "`tactile-zoo train MODEL DATASET --save FILE`")
    add_pretrained_flags(p)
    p.add_argument("--spec-from", dest="spec_from", default=None, metavar="DATASET",
                   help="no trained weights: a random initialisation (--seed) for DATASET's spec (a registered "
                        "dataset, e.g. sim_evtouch or ev_objects; its data is not needed)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random initialisation with --spec-from "
                                                       "(default 0)")
    p.add_argument("--format", dest="formats", default="torchscript,onnx", metavar="LIST",
                   help="comma list of torchscript, onnx (default both; onnx needs pip install "
                        "\"tactile-zoo[export]\")")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"folder of the files (default ./{DEFAULT_OUT})")
    p.add_argument("--batch", type=_positive("--batch"), default=1, metavar="B",
                   help="batch size of the exported graphs (default 1)")
    p.add_argument("--steps", type=_positive("--steps"), default=None, metavar="T",
                   help="frames of the forward's input (default: the spec's number of steps; capped, as the forward "
                        "is unrolled over every frame: docs/pretrained.md)")
    p.add_argument("--no-step", dest="step", action="store_false", help="export the forward only")
    p.add_argument("--no-check", dest="check", action="store_false",
                   help="skip loading the files back and comparing them with the eager model")
    p.add_argument("--opset", type=_positive("--opset"), default=None,
                   help="ONNX opset (default: the exporter's; 18 up to the newest your onnx knows, older ones only "
                        "where the graph converts; a file that does not carry it is refused, exit 2)")
    p.add_argument("--root", default=None, help="data home (only for a dataset whose registry entry lacks its spec)")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=[], metavar="MODULE",
                   help="import MODULE first (it registers models or datasets); repeatable")
    p.add_argument("--json", action="store_true", help="print the export's description (MODEL.export.json)")
    add_quiet_flag(p)
    p.set_defaults(handler=_cmd_export)


def _positive(flag: str) -> Callable[[str], int]:
    """An argparse type for ``flag``: a positive integer, else one line ``argument FLAG: must be ...``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1:
            # argparse turns an ArgumentTypeError into one line naming the flag
            raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
        return value

    return parse


def _formats(text: str) -> list[str]:
    from ..export import FORMATS

    names = [t.strip().lower() for t in text.split(",") if t.strip()]
    unknown = [n for n in names if n not in FORMATS]
    if unknown or not names:
        raise ConfigError(f"--format: unknown format {', '.join(map(repr, unknown)) or repr(text)}; choose from "
                          f"{', '.join(FORMATS)} (comma-separated)")
    return list(dict.fromkeys(names))


def _is_checkpoint(text: str) -> bool:
    return Path(text).suffix.lower() in _CHECKPOINT_SUFFIXES or Path(text).is_file()


def _from_checkpoint(args: argparse.Namespace) -> tuple[Any, str, Any, dict[str, Any]]:
    from ..data.spec import DatasetSpec
    from ..engine import build_from_checkpoint, load_checkpoint

    blob = load_checkpoint(args.model)
    config = blob["config"]
    if not config.get("spec"):
        raise ConfigError(f"checkpoint {args.model} does not record the spec it was trained for")
    spec = DatasetSpec.from_dict(config["spec"], where=f"checkpoint {args.model}")
    model = build_from_checkpoint(blob, spec, where=f"checkpoint {args.model}")
    info = {"weights": {"checkpoint": str(args.model), "dataset": config.get("dataset"),
                        "seed": config.get("seed"), "hparams": config.get("hparams") or {}},
            "preprocessing": _preprocessing(config.get("dataset"), config.get("dataset_kwargs") or {})}
    return model, config["model"], spec, info


def _preprocessing(dataset: str | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    return {"dataset": dataset, "dataset_kwargs": dict(kwargs),
            "note": "x and g are the values this dataset's loader feeds the models, with these options (the "
                    "bring-your-own recordings format); the frame bins some models use are inside the exported "
                    "graphs"}


def _cmd_export(args: argparse.Namespace) -> int:
    from ..engine import seed_everything
    from ..export import check_opset, check_steps, export_model, onnx_available, spec_for_dataset
    from ..export.folder import ExportFolder

    check_steps(args.steps, "--steps")  # the cap; the memory the example input needs: export_model, with the spec
    ExportFolder(args.out).check_owner()  # someone else's folder is refused before any weights are loaded
    formats = _formats(args.formats)
    if "onnx" in formats and onnx_available():  # before any weights are loaded
        check_opset(args.opset, "--opset")
    registry.import_plugin_modules(args.plugin_modules)
    trained = bool(args.pretrained or args.weights or args.manifest)
    if _is_checkpoint(args.model):
        if trained or args.spec_from:
            raise ConfigError(f"{args.model} is a checkpoint, which holds its own weights and spec: drop "
                              f"--pretrained/--weights/--manifest/--spec-from")
        model, name, spec, info = _from_checkpoint(args)
        label = f"checkpoint {args.model}"
    elif args.spec_from:
        if trained:
            raise ConfigError("--spec-from (random weights) and --pretrained/--weights/--manifest (trained weights) "
                              "exclude each other: give one")
        name = registry.get_model_entry(args.model).qualified_name  # an unknown model fails here, before any work
        spec = spec_for_dataset(args.spec_from, root=args.root)
        seed_everything(args.seed)
        model = registry.instantiate_model(name, spec)
        info = {"weights": None, "initialisation": {"random": True, "seed": args.seed},
                "preprocessing": _preprocessing(spec.name, {})}
        label = f"random initialisation (seed {args.seed}) for the spec of {spec.name}"
    else:
        if not trained:
            raise ConfigError("which weights? give --pretrained DATASET|TAG, --weights FILE.safetensors (with "
                              "--manifest FILE.json), a checkpoint file, or --spec-from DATASET for randomly "
                              "initialised weights")
        registry.get_model_entry(args.model)
        model = pretrained_model(args.model, args)
        entry = model.zoo_pretrained
        name, spec = entry.model, entry.dataset_spec()
        info = {"weights": {"tag": entry.qualified_tag, "sha256": entry.sha256, "dataset": entry.dataset,
                            "recipe": entry.recipe, "test_accuracy": entry.accuracy, "licence": entry.licence,
                            "dataset_licence": entry.dataset_licence, "note": entry.note or None},
                "preprocessing": _preprocessing(entry.dataset, dict(entry.dataset_kwargs))}
        label = f"weights {entry.qualified_tag}"
    name = name.rpartition(":")[2]
    try:
        result = export_model(model, args.out, name=name, spec=spec, formats=formats, batch=args.batch,
                              steps=args.steps, step=args.step, check=args.check, seed=args.seed, opset=args.opset,
                              info=info, progress=progress_on(args))
    except Terminated as exc:  # SIGTERM: export_model removed its staging folder, as after Ctrl-C
        logger.error("%s; the export stopped and left %s as it was", exc, args.out)
        return TERMINATED_EXIT
    desc = result.manifest
    if args.json:
        echo(json.dumps(desc, indent=2))
        return 0
    echo(f"exported {name} ({label}) to {Path(args.out)}:")
    for graph in ("forward", "step"):
        part = desc.get(graph)
        if not part:
            continue
        ins = ", ".join(f"{i['name']} {tuple(i['shape'])}" for i in part["inputs"] if not
                        i["name"].startswith("state_in_"))
        states = f" + {len(part['state'])} state tensors" if part.get("state") else ""
        echo(f"  {graph}: {ins}{states} -> scores {tuple(part['outputs'][0]['shape'])}{states}")
        for fmt, file in part["files"].items():
            verdict = desc["checks"].get(f"{fmt}.{graph}")
            if verdict is None:
                checked = "not checked"
            elif verdict.get("ok") is None:
                checked = f"not checked: {verdict['skipped']}"
            else:
                runtime = "onnxruntime" if fmt == "onnx" else "torch.jit"
                checked = f"checked, {runtime} vs eager: max |diff| {verdict['scores_max_abs_diff']:.2g}"
            echo(f"    {file:<28} {checked}")
    if desc.get("step_note"):
        echo(f"  note: {desc['step_note']}")
    echo(f"  {result.manifest_path.name}: names, shapes, dtypes, initial state values, spec, preprocessing, checks")
    return 0
