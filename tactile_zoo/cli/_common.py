"""What several commands share: printing, the recipe flags, fold and checkpoint arguments."""

from __future__ import annotations

import argparse
from typing import Any

from .. import registry, settings
from ..errors import ConfigError

__all__ = ["echo", "add_quiet_flag", "progress_on", "add_recipe_flags", "add_tracker_flags",
           "fold_arg", "checkpoint_dataset"]


def echo(*args: Any) -> None:
    """Print to stdout and flush (a long command's lines must show up while it runs, also through a pipe)."""
    print(*args, flush=True)


def add_quiet_flag(p: argparse.ArgumentParser) -> None:
    """``-q``: no progress (a command that can run for more than a few seconds shows its progress otherwise)."""
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress (a bar on a terminal, log lines on stderr otherwise)")


def progress_on(args: argparse.Namespace) -> bool:
    """Whether the command shows progress: not under the command's ``-q``, nor under ``tactile-zoo -q COMMAND``
    (see :mod:`tactile_zoo.engine.progress` for what is shown where)."""
    return not (getattr(args, "quiet", False) or getattr(args, "log_quiet", False))


def add_recipe_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--recipe", dest="recipe_name", default=None, metavar="NAME",
                   help="start every model from its named recipe NAME (e.g. source; default: each model's default; "
                        "`tactile-zoo info MODEL` lists them); --set overrides keys on top")
    p.add_argument("--epochs", default=None, help="replace every model's max_epochs")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="[MODEL:]KEY=VALUE",
                   help="override a training-recipe key (lr, batch_size, patience, schedule, ...) for every model or "
                        "for MODEL only; repeatable")
    p.add_argument("--hparam", dest="hparams", action="append", default=[], metavar="[MODEL:]KEY=VALUE",
                   help="a model constructor keyword (for every model or MODEL only); repeatable")
    p.add_argument("--dataset-arg", dest="dataset_args", action="append", default=[], metavar="[DATASET:]KEY=VALUE",
                   help="a dataset keyword argument (e.g. seed=1, augment_factor=2); repeatable")
    p.add_argument("--model-revision", dest="model_revisions", action="append", default=[], metavar="[MODEL=]N",
                   help="build every model, or MODEL only, at its revision N (default: its registered default; "
                        "`tactile-zoo info MODEL` lists them); part of the cell hash; repeatable")
    p.add_argument("--device", default=None, help="auto (CUDA when available, the default), cpu, cuda, cuda:N")
    p.add_argument("--root", default=None, help="data home (default $TACTILE_ZOO_DATA, else ~/.cache/tactile_zoo/data)")
    p.add_argument("--download", action="store_true", default=None, help="download datasets that can be")
    p.add_argument("--refit", action="store_true", default=None,
                   help="after selecting the epoch on val, retrain on train+val for that many epochs")
    p.add_argument("--quick", action="store_true", default=None,
                   help="smoke run: 2 epochs, at most 64 train / 32 val / 64 test samples per split")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=None, metavar="MODULE",
                   help="import MODULE first (it registers models or datasets); repeatable")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress (bars on a terminal, log lines on stderr otherwise) and no per-cell lines")


def add_tracker_flags(p: argparse.ArgumentParser, where: str) -> None:
    p.add_argument("--tracker", choices=["tensorboard", "mlflow"], default=None,
                   help="also log each cell (config and hash, per-epoch curves, final metrics, the cell JSON) to "
                        "TensorBoard event files or an MLflow file store; optional extras: pip install "
                        "\"tactile-zoo[tensorboard]\" or \"tactile-zoo[mlflow]\"")
    p.add_argument("--tracker-dir", default=None, metavar="DIR",
                   help=f"where the tracker writes DIR/tensorboard/<cell id>/ or DIR/mlruns (default {where})")


def fold_arg(value: Any) -> int:
    try:
        fold = int(value)
    except (TypeError, ValueError):
        fold = -1
    if fold < 0:
        raise ConfigError(f"--fold must be a non-negative integer, got {value!r}")
    return fold


def checkpoint_dataset(args: argparse.Namespace, config: dict[str, Any], flag: str) -> tuple[Any, str, int]:
    """The split a checkpoint is evaluated or replayed on: the checkpoint's own dataset (with its fold and keyword
    arguments, hence the preprocessing it was trained with) unless ``args.dataset`` names another; ``--dataset-arg``
    overrides single keywords on top, ``--fold`` the fold."""
    from ..bench.config import parse_assignment

    dataset = args.dataset or config.get("dataset")
    if not dataset:
        raise ConfigError(f"{args.checkpoint} does not name its dataset; give {flag}")
    same = registry.normalize_name(dataset) == registry.normalize_name(str(config.get("dataset")))
    # the checkpoint's own keywords stay under --dataset-arg: dropping them would load the data with another
    # preprocessing (BioTac-DoS's default normalisation instead of the trained one) without a word
    kwargs = dict(config.get("dataset_kwargs") or {}) if same else {}
    for text in args.dataset_args:
        _, key, value = parse_assignment("--dataset-arg", text)
        kwargs[key] = value
    settings.check_keywords(kwargs, "--dataset-arg", "")  # the schema's keyword names, finite values
    fold = fold_arg(args.fold) if args.fold is not None else (int(config.get("fold", 0)) if same else 0)
    return registry.load_dataset(dataset, root=args.root, split=args.split, fold=fold, **kwargs), dataset, fold
