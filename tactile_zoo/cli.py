"""The ``tactile-zoo`` command line.

``main(argv=None) -> int`` so tests call it in-process. Every subcommand is one ``_cmd_*`` function plus one
``_add_*`` function that declares its arguments; errors tactile-zoo raises on purpose print one line and exit 2
(``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from . import registry
from .errors import TactileZooError

__all__ = ["main", "entry", "build_parser"]

Handler = Callable[[argparse.Namespace], int]


def _print(*args: Any) -> None:
    print(*args, flush=True)


# ----------------------------------------------------------------------------------------------- list / info / plugins
def _add_list(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered models, datasets or sensors")
    p.add_argument("what", choices=["models", "datasets", "sensors"])
    p.add_argument("pattern", nargs="?", default="*", help="fnmatch pattern, e.g. '*tacformer'")
    p.add_argument("--tags", default=None, help="comma-separated tags every listed model must have")
    p.set_defaults(handler=_cmd_list)


def _cmd_list(args: argparse.Namespace) -> int:
    tags = [t for t in (args.tags or "").split(",") if t]
    lister = {"models": registry.list_models, "datasets": registry.list_datasets}.get(args.what)
    if not (lister(args.pattern, tags=tags) if lister else registry.list_sensors(args.pattern)):
        print(f"tactile-zoo: no {args.what} match {args.pattern!r}" + (f" with tags {tags}" if tags else ""),
              file=sys.stderr)
        return 0
    if args.what == "models":
        for name in registry.list_models(args.pattern, tags=tags):
            meta = registry.get_model_entry(name).meta
            _print(f"{name:<24} {', '.join(meta.get('tags', ())):<36} {meta.get('paper', '')}")
    elif args.what == "datasets":
        for name in registry.list_datasets(args.pattern, tags=tags):
            meta = registry.get_dataset_entry(name).meta
            _print(f"{name:<24} {meta.get('sensor', ''):<14} {meta.get('num_classes', ''):>4} classes  "
                   f"{meta.get('description', '')}")
    else:
        for name in registry.list_sensors(args.pattern):
            sensor = registry.get_sensor(name)
            _print(f"{name:<16} {sensor.num_nodes:>4} taxels  grid {sensor.grid_shape[0]}x{sensor.grid_shape[1]}  "
                   f"{sensor.description}")
    return 0


def _add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="metadata of a model, dataset or sensor (a model's parameter count too)")
    p.add_argument("name")
    p.add_argument("--root", default=None, help="data home (for a dataset's spec)")
    p.add_argument("--dataset", default=None, help="dataset whose spec a model is built for (default: first "
                                                   "simulated one)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_cmd_info)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict) or hasattr(value, "items"):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_jsonable(v) for v in value]
    return value if isinstance(value, str | int | float | bool | type(None)) else str(value)


def _model_info(name: str, args: argparse.Namespace) -> dict[str, Any]:
    entry = registry.get_model_entry(name)
    info: dict[str, Any] = {"kind": "model", "name": entry.qualified_name, **_jsonable(dict(entry.meta))}
    ds_name = args.dataset or next(iter(registry.list_datasets("sim_*")), None)
    if ds_name is not None:
        ds = registry.load_dataset(ds_name, root=args.root, split="train")
        model = registry.create_model(name, ds.spec)
        info["built_for"] = ds.spec.name
        info["parameters"] = sum(p.numel() for p in model.parameters())
    return info


def _dataset_info(name: str, args: argparse.Namespace) -> dict[str, Any]:
    entry = registry.get_dataset_entry(name)
    info: dict[str, Any] = {"kind": "dataset", "name": entry.qualified_name, **_jsonable(dict(entry.meta))}
    ds = registry.load_dataset(name, root=args.root, split=None)
    info["spec"] = ds.spec.to_dict()
    info["num_folds"] = ds.num_folds
    info["samples"] = len(ds)
    counts: dict[str, int] = {}
    for split in ("train", "val", "test", *getattr(ds, "extra_splits", ())):
        counts[split] = len(registry.load_dataset(name, root=args.root, split=split))
    info["split_sizes_fold0"] = counts
    return info


def _unknown_name_message(name: str) -> str:
    """Close matches among every model, dataset and sensor name (a typo of a sensor must suggest the sensor)."""
    import difflib

    known = {"models": registry.list_models(), "datasets": registry.list_datasets(),
             "sensors": registry.list_sensors()}
    by_key = {registry.normalize_name(n): n for names in known.values() for n in names}
    close = [by_key[k] for k in difflib.get_close_matches(registry.normalize_name(name), list(by_key), n=3,
                                                          cutoff=0.6)]
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    listing = "; ".join(f"{kind}: {', '.join(names) or '(none)'}" for kind, names in known.items())
    return f"unknown name {name!r}: not a model, dataset or sensor.{hint} Known {listing}"


def _cmd_info(args: argparse.Namespace) -> int:
    kinds = []
    for kind, lookup in (("model", registry.get_model_entry), ("dataset", registry.get_dataset_entry),
                         ("sensor", registry.get_sensor)):
        try:
            lookup(args.name)
            kinds.append(kind)
        except registry.UnknownNameError:
            pass
    if not kinds:
        raise registry.UnknownNameError(_unknown_name_message(args.name))
    if kinds[0] == "model":
        info = _model_info(args.name, args)
    elif kinds[0] == "dataset":
        info = _dataset_info(args.name, args)
    else:
        sensor = registry.get_sensor(args.name)
        info = {"kind": "sensor", "name": sensor.name, "taxels": sensor.num_nodes, "grid_shape": sensor.grid_shape,
                "default_graph": sensor.default_graph, "edges": int(sensor.edge_index().shape[1]) // 2,
                "channels": sensor.channels, "description": sensor.description}
    if args.json:
        _print(json.dumps(_jsonable(info), indent=2))
    else:
        width = max(len(k) for k in info)
        for key, value in info.items():
            _print(f"{key:<{width}}  {json.dumps(_jsonable(value)) if not isinstance(value, str) else value}")
    return 0


def _add_plugins(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="discovered plugin distributions and their status")
    p.set_defaults(handler=_cmd_plugins)


def _cmd_plugins(args: argparse.Namespace) -> int:
    found = registry.plugins()
    if not found:
        _print("no tactile-zoo plugins installed" + (" (discovery disabled)" if not registry._enabled() else ""))
        return 0
    for info in found:
        line = f"{info.dist} {info.version:<8} {info.group:<22} {info.name} = {info.value}  [{info.status}]"
        _print(line + (f"  {info.error}" if info.error else ""))
    return 1 if any(i.status == "failed" for i in found) and registry._strict() else 0


# ----------------------------------------------------------------------------------------------- download
def _add_download(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("download", help="fetch and verify a dataset's raw files, or say exactly where to place them")
    p.add_argument("name")
    p.add_argument("--root", default=None, help="data home (default $TACTILE_ZOO_DATA, else ~/.cache/tactile_zoo/data)")
    p.add_argument("--extract", action="store_true", help="also unpack the verified archive next to it (members "
                                                          "with absolute paths, '..' or links are refused)")
    p.set_defaults(handler=_cmd_download)


def _cmd_download(args: argparse.Namespace) -> int:
    entry = registry.get_dataset_entry(args.name)
    obj = entry.obj
    if getattr(obj, "simulated", False):
        _print(f"{entry.qualified_name}: simulated, nothing to download")
        return 0
    check = getattr(obj, "availability", None)
    present, where = check(args.root) if callable(check) else (False, "")
    downloadable = bool(getattr(obj, "downloadable", False))
    if not present and not downloadable:
        _print(f"{entry.qualified_name} cannot be downloaded automatically. {where or entry.meta.get('obtain', '')}")
        return 1
    # loading downloads when needed, verifies the checksum, and builds the processed cache in one go
    ds = registry.load_dataset(args.name, root=args.root, split=None, download=downloadable)
    state = "present" if present else "downloaded and verified"
    _print(f"{entry.qualified_name}: {state} ({check(args.root)[1] if callable(check) else 'loaded'}); "
           f"{len(ds)} samples, spec {json.dumps(ds.spec.to_dict())}")
    if args.extract:
        extract = getattr(obj, "extract", None)
        if not callable(extract):
            _print(f"{entry.qualified_name}: nothing to extract (its raw files are not an archive)")
        else:
            _print(f"{entry.qualified_name}: extracted to {extract(args.root)}")
    return 0


# ----------------------------------------------------------------------------------------------- bench / train / ...
def _add_recipe_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--epochs", default=None, help="replace every model's max_epochs")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="[MODEL:]KEY=VALUE",
                   help="override a training-recipe key (lr, batch_size, patience, schedule, ...) for every model or "
                        "for MODEL only; repeatable")
    p.add_argument("--hparam", dest="hparams", action="append", default=[], metavar="[MODEL:]KEY=VALUE",
                   help="a model constructor keyword (for every model or MODEL only); repeatable")
    p.add_argument("--dataset-arg", dest="dataset_args", action="append", default=[], metavar="[DATASET:]KEY=VALUE",
                   help="a dataset keyword argument (e.g. seed=1, augment_factor=2); repeatable")
    p.add_argument("--device", default=None, help="auto (CUDA when available, the default), cpu, cuda, cuda:N")
    p.add_argument("--root", default=None, help="data home (default $TACTILE_ZOO_DATA, else ~/.cache/tactile_zoo/data)")
    p.add_argument("--download", action="store_true", default=None, help="download datasets that can be")
    p.add_argument("--refit", action="store_true", default=None,
                   help="after selecting the epoch on val, retrain on train+val for that many epochs")
    p.add_argument("--quick", action="store_true", default=None,
                   help="smoke run: 2 epochs, at most 64 train / 32 val / 64 test samples per split")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=None, metavar="MODULE",
                   help="import MODULE first (it registers models or datasets); repeatable")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars or per-cell lines")


def _add_bench(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="train and evaluate models x datasets into a resumable leaderboard",
                       description="Cross models with datasets (cells = model x dataset x fold x seed), train each "
                                   "cell with its model's recipe, and write leaderboard.csv, summary.csv, report.md "
                                   "and plots. Rerunning the same command resumes.")
    p.add_argument("--models", action="append", default=None, metavar="all|NAMES|PATTERNS",
                   help="'all' (default), names, comma lists, wildcards such as '*tacformer'")
    p.add_argument("--datasets", action="append", default=None, metavar="all|NAMES|PATTERNS",
                   help="'all' (default): every registered dataset whose data is here (simulated ones always)")
    p.add_argument("--seeds", default=None, help="comma list or range of seeds, e.g. 0,1,2 or 0-4 (default 0)")
    p.add_argument("--folds", default=None, help="run only the first K folds of each dataset (default: every fold)")
    p.add_argument("--prefixes", default=None, help="early-classification prefix fractions (default "
                                                    "0.1,0.25,0.5,0.75,1.0)")
    p.add_argument("--out", default=None, help="output folder (default ./tactile-zoo-results/<name of the grid>)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--resume", dest="force", action="store_false", default=None,
                      help="reuse finished cells in --out (the default)")
    mode.add_argument("--force", dest="force", action="store_true", default=None, help="recompute every cell")
    p.add_argument("--executor", choices=["local", "process", "dask"], default=None,
                   help="local (default), process (local worker processes), dask (a Dask cluster)")
    p.add_argument("--workers", default=None, help="worker processes (process executor; dask without --scheduler)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler, e.g. tcp://HOST:8786")
    p.add_argument("--threads", default=None, help="torch threads per cell, under every executor (default 1, so "
                                                   "local and distributed runs give identical numbers; run cells "
                                                   "side by side with --executor process --workers N)")
    p.add_argument("--config", default=None, metavar="FILE.yaml", help="settings file (flags given here win)")
    p.add_argument("--dry-run", action="store_true", help="print the grid of cells and exit")
    p.add_argument("--no-plots", action="store_true", help="write the tables and report.md without the PNG plots "
                                                           "(`tactile-zoo report DIR` draws them later)")
    _add_recipe_flags(p)
    p.set_defaults(handler=_cmd_bench)


def _bench_config(args: argparse.Namespace) -> Any:
    from .bench.config import load_yaml_config, merge_config

    flags = {key: getattr(args, key) for key in (
        "models", "datasets", "root", "download", "seeds", "folds", "epochs", "refit", "quick", "device", "out",
        "force", "executor", "workers", "scheduler", "threads", "plugin_modules", "prefixes")}
    return merge_config(load_yaml_config(args.config) if args.config else None, flags, args.sets, args.hparams,
                        args.dataset_args)


def _cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run_bench

    outcome = run_bench(_bench_config(args), dry_run=args.dry_run, quiet=args.quiet, plots=not args.no_plots)
    return outcome.exit_code


def _add_train(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train one model on one dataset (one cell) and optionally save it")
    p.add_argument("model")
    p.add_argument("dataset")
    p.add_argument("--seed", default="0", help="seed (default 0)")
    p.add_argument("--fold", default="0", help="fold of a k-fold protocol (default 0)")
    p.add_argument("--save", default=None, metavar="MODEL.pt", help="write a checkpoint (weights + resolved config)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--threads", default="1", help="torch threads (default 1, as bench runs each cell, so the numbers "
                                                  "match the leaderboard's)")
    _add_recipe_flags(p)
    p.set_defaults(handler=_cmd_train)


def _single_config(args: argparse.Namespace) -> Any:
    from .bench.config import merge_config

    flags = {"models": [args.model], "datasets": [args.dataset], "root": args.root, "download": args.download,
             "epochs": args.epochs, "refit": args.refit, "quick": args.quick, "device": args.device,
             "plugin_modules": args.plugin_modules}
    return merge_config(None, flags, args.sets, args.hparams, args.dataset_args)


def _fold_arg(value: Any) -> int:
    from .errors import ConfigError

    try:
        fold = int(value)
    except (TypeError, ValueError):
        fold = -1
    if fold < 0:
        raise ConfigError(f"--fold must be a non-negative integer, got {value!r}")
    return fold


def _cmd_train(args: argparse.Namespace) -> int:
    from .bench.cell import import_plugin_modules
    from .bench.config import parse_seeds
    from .bench.grid import resolve_datasets, resolve_models
    from .engine import fit, prefix_evaluation, resolve_recipe, save_checkpoint, take
    from .engine.runtime import versions
    from .errors import ConfigError

    config = _single_config(args)
    import_plugin_modules(config.plugin_modules)
    from .bench.config import BenchConfig
    from .engine.runtime import set_threads

    set_threads(BenchConfig(threads=args.threads).threads)
    try:
        seeds = parse_seeds(args.seed)
    except ConfigError as exc:  # name the flag this command has (--seed), not bench's --seeds
        raise ConfigError(str(exc).replace("--seeds", "--seed", 1)) from None
    if len(seeds) != 1:
        raise ConfigError(f"--seed takes one seed, got {args.seed!r}")
    fold = _fold_arg(args.fold)
    model = resolve_models([args.model])[0]
    dataset = resolve_datasets([args.dataset])[0]
    entry = registry.get_model_entry(model)
    recipe_over, hparams = config.overrides_for(model, (entry.name,))
    recipe = resolve_recipe(entry.meta.get("recipe"), recipe_over, config.effective_epochs(),
                            where=f"recipe of model {model!r}")
    kwargs = config.kwargs_for(dataset)
    splits = {s: registry.load_dataset(dataset, root=config.root, split=s, fold=fold, download=config.download,
                                       **kwargs) for s in ("train", "val", "test")}
    subset = config.subset or {}
    train, val, test = (take(splits[s], subset.get(s)) for s in ("train", "val", "test"))
    result = fit(model, train, recipe=recipe, seed=seeds[0], val_dataset=val, test_dataset=test, hparams=hparams,
                 device=config.device, refit=config.refit, progress=not args.quiet)
    prefix = prefix_evaluation(result.model, test, config.prefixes, causal=bool(entry.meta.get("causal", False)),
                               loss=recipe.loss)
    metrics = {k: v for k, v in result.metrics.items() if k != "confusion"}
    summary = {"model": model, "dataset": dataset, "fold": fold, "seed": seeds[0], "test": metrics,
               "best_epoch": result.best_epoch, "epochs_run": result.epochs_run,
               "train_seconds": round(result.train_seconds, 2), "params": result.params, "device": result.device,
               "accuracy_at": dict(zip((f"{f:g}" for f in prefix["fractions"]), prefix["accuracy"]))}
    if args.save:
        config_blob = {"model": model, "hparams": hparams, "dataset": dataset, "dataset_kwargs": kwargs, "fold": fold,
                       "seed": seeds[0], "recipe": recipe.to_dict(), "refit": bool(config.refit),
                       "quick": bool(config.quick), "spec": train.spec.to_dict(), "metrics": metrics,
                       "best_epoch": result.best_epoch, "versions": versions()}
        summary["saved"] = str(save_checkpoint(args.save, result.model, config_blob))
    if args.json:
        _print(json.dumps(summary, indent=2))
    else:
        _print(f"{model} on {dataset} (fold {fold}, seed {seeds[0]}): test accuracy {metrics['accuracy']:.4f}, "
               f"balanced {metrics['balanced_accuracy']:.4f}, macro-F1 {metrics['macro_f1']:.4f}; best epoch "
               f"{result.best_epoch} of {result.epochs_run}; {result.train_seconds:.1f}s on {result.device}")
        if args.save:
            _print(f"saved {summary['saved']}")
    return 0


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="evaluate a checkpoint saved by `tactile-zoo train --save`")
    p.add_argument("checkpoint")
    p.add_argument("dataset", nargs="?", default=None, help="default: the dataset it was trained on")
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument("--fold", default=None, help="fold (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--root", default=None, help="data home")
    p.add_argument("--dataset-arg", dest="dataset_args", action="append", default=[], metavar="KEY=VALUE",
                   help="dataset keyword argument (default: the checkpoint's when the dataset is the same)")
    p.add_argument("--device", default=None, help="auto, cpu, cuda")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=[], metavar="MODULE")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(handler=_cmd_evaluate)


def _checkpoint_dataset(args: argparse.Namespace, config: dict[str, Any], flag: str) -> tuple[Any, str, int]:
    """The split a checkpoint is evaluated or replayed on: the checkpoint's own dataset (with its fold and keyword
    arguments) unless ``args.dataset`` names another; ``--dataset-arg`` and ``--fold`` override."""
    from .bench.config import parse_assignment
    from .errors import ConfigError

    dataset = args.dataset or config.get("dataset")
    if not dataset:
        raise ConfigError(f"{args.checkpoint} does not name its dataset; give {flag}")
    same = registry.normalize_name(dataset) == registry.normalize_name(str(config.get("dataset")))
    kwargs = dict(config.get("dataset_kwargs") or {}) if same and not args.dataset_args else {}
    for text in args.dataset_args:
        _, key, value = parse_assignment("--dataset-arg", text)
        kwargs[key] = value
    fold = _fold_arg(args.fold) if args.fold is not None else (int(config.get("fold", 0)) if same else 0)
    return registry.load_dataset(dataset, root=args.root, split=args.split, fold=fold, **kwargs), dataset, fold


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .bench.cell import import_plugin_modules
    from .engine import build_from_checkpoint, evaluate, load_checkpoint

    import_plugin_modules(args.plugin_modules)
    blob = load_checkpoint(args.checkpoint)
    config = blob["config"]
    ds, dataset, fold = _checkpoint_dataset(args, config, "DATASET")
    model = build_from_checkpoint(blob, ds.spec, where=f"checkpoint {args.checkpoint}")
    result = evaluate(model, ds, device=args.device or "auto")
    metrics = {k: v for k, v in result.metrics.items() if k != "confusion"}
    if args.json:
        _print(json.dumps({"checkpoint": args.checkpoint, "model": config["model"], "dataset": dataset,
                           "split": args.split, "fold": fold, **metrics, "confusion": result.metrics["confusion"]},
                          indent=2))
    else:
        _print(f"{config['model']} ({args.checkpoint}) on {dataset} [{args.split}, fold {fold}, {metrics['n']} "
               f"samples]: accuracy {metrics['accuracy']:.4f}, balanced {metrics['balanced_accuracy']:.4f}, "
               f"macro-F1 {metrics['macro_f1']:.4f}")
    return 0


def _add_report(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="rebuild leaderboard.csv, summary.csv, report.md and plots from cell files")
    p.add_argument("dir", help="a bench output folder")
    p.add_argument("--no-plots", action="store_true", help="tables and report.md only")
    p.add_argument("--all-cells", action="store_true",
                   help="every cell file in the folder, not only the grid of the last bench command (for a table "
                        "built by several commands into one folder)")
    p.set_defaults(handler=_cmd_report)


def _cmd_report(args: argparse.Namespace) -> int:
    from .bench import write_outputs

    written = write_outputs(args.dir, plots=not args.no_plots, all_cells=args.all_cells)
    for path in written.values():
        _print(f"wrote {path}")
    return 0


# ----------------------------------------------------------------------------------------------- stream
def _add_stream(sub: argparse._SubParsersAction) -> None:
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

    from .bench.cell import import_plugin_modules
    from .engine import build_from_checkpoint, load_checkpoint, resolve_device
    from .engine.runtime import set_threads
    from .engine.stream import check_streaming, replay
    from .errors import ConfigError

    if args.every < 1:
        raise ConfigError(f"--every must be a positive integer, got {args.every}")
    import_plugin_modules(args.plugin_modules)
    set_threads(args.threads)
    blob = load_checkpoint(args.checkpoint)
    config = blob["config"]
    name = config["model"]
    meta = dict(registry.get_model_entry(name).meta)
    check_streaming(name, meta)  # before any data is loaded
    ds, dataset, fold = _checkpoint_dataset(args, config, "--dataset")
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
        _print(json.dumps({"checkpoint": args.checkpoint, "model": name, "dataset": dataset, "split": args.split,
                           "fold": fold, "index": args.index, "num_steps": T, "frame_period_s": trace.frame_period,
                           "loss": trace.loss, "true_class": names[trace.target], "steps": steps,
                           "final_scores": trace.scores[-1].tolist(), "settled_step": settled,
                           "settled_time_s": None if settled is None else trace.time_of(settled),
                           "latency_ms": latency, "threads": torch.get_num_threads(), "device": str(device)},
                          indent=2))
        return 0
    width = max(len("top class"), *(len(n) for n in names))
    _print(f"{name} ({args.checkpoint}) on sample {args.index} of {dataset} [{args.split}, fold {fold}]: {T} steps"
           + ("" if trace.frame_period is None else f" of {1000 * trace.frame_period:g} ms"))
    _print(f"{'step':>5}  {'time':>12}  {'top class':<{width}}  {'p':>5}  correct")
    for k in shown:
        pred = preds[k - 1]
        _print(f"{k:>5}  {when(k):>12}  {names[pred]:<{width}}  {float(probs[k - 1, pred]):.3f}  "
               f"{'yes' if pred == trace.target else 'no'}")
    final = preds[-1]
    _print(f"true class: {names[trace.target]}; final prediction: {names[final]} (p {float(probs[-1, final]):.3f})")
    if settled is None:
        _print("correct and stayed correct: never (the last prediction is wrong)")
    else:
        _print(f"correct and stayed correct: from step {settled} of {T} ({when(settled)})")
    _print(f"per-step latency: median {latency['median']:.3f} ms, mean {latency['mean']:.3f} ms, max "
           f"{latency['max']:.3f} ms (batch 1, {torch.get_num_threads()} thread(s), {device})")
    return 0


# ----------------------------------------------------------------------------------------------- parser and main
#: Every subcommand's argument declaration, in help order. Later subcommands append themselves here.
SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [_add_list, _add_info, _add_plugins]
SUBCOMMANDS.append(_add_download)
SUBCOMMANDS += [_add_bench, _add_train, _add_evaluate, _add_report]
SUBCOMMANDS.append(_add_stream)


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(prog="tactile-zoo", description="Tactile recognition model zoo and benchmark.")
    parser.add_argument("--version", action="version", version=f"tactile-zoo {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("--strict-plugins", action="store_true", help="a plugin that fails to load is an error")
    parser.add_argument("--no-plugins", action="store_true", help="do not discover entry-point plugins")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    print(f"tactile-zoo: warning: {message}", file=sys.stderr)


class _ArgumentError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        raise _ArgumentError(message)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 some work failed, 2 bad input or error)."""
    parser = build_parser()
    parser.__class__ = _Parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action.choices.values():
                choice.__class__ = _Parser
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except _ArgumentError as exc:
        print(f"tactile-zoo: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help and --version: main() returns its code instead of exiting the caller
        return exc.code if isinstance(exc.code, int) else 0
    registry.set_plugin_policy(strict=True if args.strict_plugins else None,
                               enabled=False if args.no_plugins else None)
    from .engine.runtime import flush_denormals

    try:
        # before torch starts its thread pool, so that every thread it starts inherits flush-to-zero
        with warnings.catch_warnings(), flush_denormals():
            warnings.simplefilter("always", registry.PluginWarning)
            warnings.showwarning = _show_warning
            return int(args.handler(args) or 0)
    except TactileZooError as exc:
        if args.debug:
            raise
        print(f"tactile-zoo: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tactile-zoo: interrupted", file=sys.stderr)
        return 130
    finally:
        registry.set_plugin_policy()


def entry() -> None:  # console script
    sys.exit(main())


if __name__ == "__main__":  # python -m tactile_zoo.cli
    entry()
