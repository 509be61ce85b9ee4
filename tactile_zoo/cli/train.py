"""``tactile-zoo train`` (one cell, the harness's) and ``evaluate`` (a saved checkpoint on a split)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from .. import registry
from ..errors import ConfigError
from ._common import (
    add_quiet_flag,
    add_recipe_flags,
    add_tracker_flags,
    checkpoint_dataset,
    echo,
    fold_arg,
    progress_on,
)

__all__ = ["add_train", "add_evaluate"]


def add_train(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train one model on one dataset (one cell) and optionally save it")
    p.add_argument("model")
    p.add_argument("dataset")
    p.add_argument("--seed", default="0", help="seed (default 0)")
    p.add_argument("--fold", default="0", help="fold of a k-fold protocol (default 0)")
    p.add_argument("--save", default=None, metavar="MODEL.pt",
                   help="write a checkpoint (weights, resolved config and the data's preprocessing) to a new file, or "
                        "over a checkpoint it wrote before; any other file, a link or a device is refused before "
                        "training")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--threads", default="1", help="torch threads (default 1, as bench runs each cell, so the numbers "
                                                  "match the leaderboard's)")
    add_recipe_flags(p)
    add_tracker_flags(p, "the current folder")
    p.set_defaults(handler=_cmd_train)


def _single_config(args: argparse.Namespace) -> Any:
    from ..bench.config import merge_config

    flags = {"models": [args.model], "datasets": [args.dataset], "root": args.root, "download": args.download,
             "epochs": args.epochs, "refit": args.refit, "quick": args.quick, "device": args.device,
             "plugin_modules": args.plugin_modules, "recipe_name": args.recipe_name}
    return merge_config(None, flags, args.sets, args.hparams, args.dataset_args, args.model_revisions)


def _cmd_train(args: argparse.Namespace) -> int:
    from ..bench.config import parse_threads, plan_cells
    from ..bench.grid import resolve_datasets, resolve_models
    from ..bench.parsing import parse_seeds
    from ..bench.trackers import check_tracker
    from ..engine import save_checkpoint
    from ..engine.build import load_splits
    from ..engine.cell import train_cell
    from ..engine.checkpoint import check_checkpoint_path
    from ..engine.config import check_model_builds
    from ..engine.malloc import tune_malloc
    from ..engine.runtime import set_threads, versions
    from ..errors import ConfigError

    if args.save is not None:  # the ownership rule (tactile_zoo._owned), checked before any work
        check_checkpoint_path(args.save, "--save")
    config = _single_config(args)
    tracker = check_tracker(args.tracker)  # a missing extra fails now, not after the training
    registry.import_plugin_modules(config.plugin_modules)
    set_threads(parse_threads(args.threads))
    tune_malloc()  # more large freed blocks come back already faulted in (tactile_zoo.engine.malloc)
    try:
        seeds = parse_seeds(args.seed)
    except ConfigError as exc:  # name the flag this command has (--seed), not bench's --seeds
        raise ConfigError(str(exc).replace("--seeds", "--seed", 1)) from None
    if len(seeds) != 1:
        raise ConfigError(f"--seed takes one seed, got {args.seed!r}")
    seed, fold = seeds[0], fold_arg(args.fold)
    model = resolve_models([args.model])[0]
    dataset = resolve_datasets([args.dataset])[0]
    # the harness's own cell configuration, through its one function: same resolution, same numbers
    plan = plan_cells(config, [model], [dataset])
    cell = plan.configs[model, dataset]
    # the model built once on the dataset's spec (its train split is loaded, and cached, for the cell anyway): a bad
    # --hparam value is one line and exit 2, as in bench, not a traceback from the constructor
    spec = load_splits(dataset, config.root, fold, config.download, cell.dataset_kwargs, ("train",))["train"].spec
    check_model_builds(cell, spec, plan.given[model])
    outcome = train_cell(cell, fold=fold, seed=seed, root=config.root, download=config.download,
                         device=config.device, progress=progress_on(args))
    result, prefix = outcome.fit, outcome.prefix or {"fractions": [], "accuracy": []}
    metrics = {k: v for k, v in result.metrics.items() if k != "confusion"}
    summary = {"model": model, "dataset": dataset, "fold": fold, "seed": seed, "test": metrics,
               "best_epoch": result.best_epoch, "epochs_run": result.epochs_run,
               "train_seconds": round(result.train_seconds, 2), "params": result.params, "device": result.device,
               "accuracy_at": dict(zip((f"{f:g}" for f in prefix["fractions"]), prefix["accuracy"]))}
    if cell.subset:
        summary["subset"] = dict(cell.subset)
    ties = _test_ties(outcome)
    if ties:
        summary["test_ties"] = ties
    if args.save is not None:
        from ..weights.manifest import preprocessing_of

        spec = outcome.spec.to_dict()
        blob = {**cell.to_dict(), "fold": fold, "seed": seed, "quick": bool(config.quick), "spec": spec,
                "metrics": metrics, "best_epoch": result.best_epoch, "versions": versions(),
                "preprocessing": preprocessing_of(model, dataset, spec, cell.hparams, cell.dataset_kwargs)}
        summary["saved"] = str(save_checkpoint(args.save, result.model, blob, flag="--save"))
    if tracker is not None:
        _track(tracker, args.tracker_dir or ".", cell, outcome, summary)
    if args.json:
        echo(json.dumps(summary, indent=2))
    else:
        echo(f"{model} on {dataset} (fold {fold}, seed {seed}): test accuracy {metrics['accuracy']:.4f}, "
             f"balanced {metrics['balanced_accuracy']:.4f}, macro-F1 {metrics['macro_f1']:.4f}; best epoch "
             f"{result.best_epoch} of {result.epochs_run}; {result.train_seconds:.1f}s on {result.device}")
        if cell.subset:
            echo(f"note: {'a --quick' if config.quick else 'a subset'} run: test figures on {metrics['n']} test "
                 f"samples (at most {cell.subset.get('test', 'all')} per split, class-balanced), after training on at "
                 f"most {cell.subset.get('train', 'all')}; not comparable with the leaderboard's")
        if ties:
            echo(f"note: {ties} of {metrics['n']} test samples are ties (several classes share the top score: the "
                 f"model named no class); the test figures count each as argmax's pick, the lowest tied class, as "
                 f"every published cell does; accuracy_at counts them undecided")
        if args.save is not None:
            echo(f"saved {summary['saved']}")
    return 0


def _test_ties(outcome: Any) -> int:
    """How many test samples have a tied top class probability (:func:`tactile_zoo.engine.metrics.tied_top`)."""
    import torch

    from ..engine.metrics import tied_top

    probabilities = outcome.tests["test"].probabilities if "test" in outcome.tests else []
    return int(tied_top(torch.tensor(probabilities)).sum()) if len(probabilities) else 0


def _track(tracker: str, folder: str, cell: Any, outcome: Any, summary: dict[str, Any]) -> None:
    """Log the trained cell as bench would log its record (the tracker module's keys: config and hash, curves,
    final metrics, the record as cell.json)."""
    from ..bench.grid import cell_id
    from ..bench.trackers import log_record
    from ..bench.worker import _ok_record
    from ..engine.config import config_hash

    digest = config_hash(cell)
    record = {"cell_id": cell_id(summary["model"], summary["dataset"], summary["fold"], summary["seed"], digest),
              "model": summary["model"], "dataset": summary["dataset"], "fold": summary["fold"],
              "seed": summary["seed"], "config_hash": digest, "config": cell.to_dict(), **_ok_record(outcome)}
    if log_record(tracker, record, folder):
        where = Path(folder) / ("mlruns" if tracker == "mlflow" else f"tensorboard/{record['cell_id']}")
        summary["tracker"] = {"name": tracker, "cell_id": record["cell_id"], "path": str(where)}


#: checkpoint suffixes read as the source's released Keras models (D-CNN) instead of a `train --save` checkpoint
KERAS_SUFFIXES = (".h5", ".hdf5")


def add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="evaluate a checkpoint saved by `tactile-zoo train --save`, or a released "
                                        "Keras D-CNN (.h5)",
                       description="Evaluate a checkpoint on a split. A CHECKPOINT ending in .h5 or .hdf5 is one of "
                                   "the Keras 2.2.4 D-CNN models released with Augment8000 "
                                   "(VGG16_scaling_time_warp{1..10}.h5), built as model dcnn for DATASET (required "
                                   "then): tactile-zoo evaluate MODEL.h5 augment8000 --split all --dataset-arg "
                                   "stats=source --root DIR.")
    p.add_argument("checkpoint", help="a .pt file from `train --save`, or a released Keras D-CNN .h5/.hdf5 file")
    p.add_argument("dataset", nargs="?", default=None,
                   help="default: the dataset it was trained on (required for a Keras file)")
    p.add_argument("--split", default="test",
                   help="split to evaluate (default test), or all (every sample the dataset loaded). Augment8000's "
                        "120 real-life samples: `test` of every fold when the training file is present too, else "
                        "`all` (with the real-life file alone, `test` is one fold of them); the released models need "
                        "--dataset-arg stats=source (the published normalisation constants) when the training file "
                        "is present")
    p.add_argument("--fold", default=None, help="fold (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--root", default=None, help="data home")
    p.add_argument("--dataset-arg", dest="dataset_args", action="append", default=[], metavar="KEY=VALUE",
                   help="dataset keyword argument (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--device", default=None, help="auto, cpu, cuda")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=[], metavar="MODULE")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    add_quiet_flag(p)
    p.set_defaults(handler=_cmd_evaluate)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from ..engine import build_from_checkpoint, evaluate, load_checkpoint

    registry.import_plugin_modules(args.plugin_modules)
    # "all" is the dataset's split=None: every sample (the only way to the 120 real-life Augment8000 samples at once
    # when the training file is absent)
    chosen = argparse.Namespace(**{**vars(args), "split": None}) if args.split == "all" else args
    if Path(args.checkpoint).suffix.lower() in KERAS_SUFFIXES:
        if not Path(args.checkpoint).is_file():
            raise ConfigError(f"checkpoint {args.checkpoint} does not exist")
        config: dict[str, Any] = {"model": "dcnn"}  # names no dataset: DATASET is required
        ds, dataset, fold = checkpoint_dataset(chosen, config, "DATASET")
        # through the registry: the command line never imports a model module
        model = registry.get_model_entry("dcnn").obj.from_keras(args.checkpoint, ds.spec)
    else:
        blob = load_checkpoint(args.checkpoint)
        config = blob["config"]
        ds, dataset, fold = checkpoint_dataset(chosen, config, "DATASET")
        model = build_from_checkpoint(blob, ds.spec, where=f"checkpoint {args.checkpoint}")
    result = evaluate(model, ds, device=args.device or "auto", progress=progress_on(args))
    metrics = {k: v for k, v in result.metrics.items() if k != "confusion"}
    if args.json:
        echo(json.dumps({"checkpoint": args.checkpoint, "model": config["model"], "dataset": dataset,
                           "split": args.split, "fold": fold, **metrics, "confusion": result.metrics["confusion"]},
                          indent=2))
    else:
        echo(f"{config['model']} ({args.checkpoint}) on {dataset} [{args.split}, fold {fold}, {metrics['n']} "
             f"samples]: accuracy {metrics['accuracy']:.4f}, balanced {metrics['balanced_accuracy']:.4f}, "
             f"macro-F1 {metrics['macro_f1']:.4f}")
    return 0
