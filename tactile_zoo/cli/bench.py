"""``tactile-zoo bench`` and ``report``: the harness's grid of cells into a resumable leaderboard."""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ._common import add_recipe_flags, add_tracker_flags, echo

__all__ = ["add_bench", "add_report", "add_rebuild_weights"]

logger = logging.getLogger(__name__)


def add_bench(sub: argparse._SubParsersAction) -> None:
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
    p.add_argument("--retries", default=None, metavar="N",
                   help="dask: reschedule a cell whose worker died up to N times (the scheduler's allowed-failures; "
                        "default: its own setting, Dask's default 3); the record's `attempts` says how many ran")
    p.add_argument("--dashboard", default=None, metavar="ADDRESS",
                   help="dask without --scheduler: serve the local cluster's dashboard there, e.g. :8787 (default off)")
    p.add_argument("--threads", default=None, help="torch threads per cell, under every executor (default 1, so "
                                                   "local and distributed runs give identical numbers; run cells "
                                                   "side by side with --executor process --workers N)")
    p.add_argument("--evaluation", choices=["validation", "reference", "tuning", "final"], default=None,
                   help="default: the one the recipe declares (`full`: final), else validation. validation: the "
                        "epoch is selected on the validation split and the test split is read once. final: train "
                        "on train+val for the recipe's fixed epochs, nothing selected, the test split read once. "
                        "reference: the sources' protocol: train on train+val for the recipe's fixed "
                        "epochs, test after every epoch, keep the final epoch's accuracy (honest) and the best "
                        "epoch's (chosen on test: optimistic, labelled so). tuning: as validation, but the test "
                        "split is never read (loading it raises); the cells record the validation score, for "
                        "choosing recipes")
    p.add_argument("--save-weights", action="store_true", default=None,
                   help="write the trained weights of every cell this run computes to OUT/weights/<cell id>."
                        "safetensors (its sha256 in the cell record); finished cells are not recomputed for it")
    p.add_argument("--config", default=None, metavar="FILE.yaml", help="settings file (flags given here win)")
    _add_skip_invalid(p)
    p.add_argument("--dry-run", action="store_true", help="print the grid of cells and exit")
    p.add_argument("--no-plots", action="store_true", help="write the tables and report.md without the PNG plots "
                                                           "(`tactile-zoo report DIR` draws them later)")
    add_recipe_flags(p)
    add_tracker_flags(p, "the run folder, --out")
    p.set_defaults(handler=_cmd_bench)


def _add_skip_invalid(p: argparse.ArgumentParser) -> None:
    p.add_argument("--skip-invalid", action="store_true",
                   help="a damaged cell file (unreadable, truncated, failing the cell schema) is named as a warning "
                        "instead of making the command fail; report leaves it out of the tables, bench recomputes "
                        "the grid's own (moving the damaged file to cells/damaged/ first)")


def _bench_config(args: argparse.Namespace) -> Any:
    from ..bench.config import load_yaml_config, merge_config

    flags = {key: getattr(args, key) for key in (
        "models", "datasets", "root", "download", "seeds", "folds", "epochs", "refit", "quick", "device", "out",
        "force", "executor", "workers", "scheduler", "threads", "plugin_modules", "prefixes", "recipe_name",
        "evaluation", "retries", "dashboard", "save_weights", "tracker", "tracker_dir")}
    return merge_config(load_yaml_config(args.config) if args.config else None, flags, args.sets, args.hparams,
                        args.dataset_args, args.model_revisions)


def _cmd_bench(args: argparse.Namespace) -> int:
    from ..bench import run_bench

    outcome = run_bench(_bench_config(args), dry_run=args.dry_run, quiet=args.quiet,
                        plots=not args.no_plots, skip_invalid=args.skip_invalid)
    return outcome.exit_code


def add_report(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="rebuild leaderboard.csv, summary.csv, report.md and plots from cell files")
    p.add_argument("dir", help="a bench output folder")
    p.add_argument("--no-plots", action="store_true", help="tables and report.md only")
    p.add_argument("--all-cells", action="store_true",
                   help="every cell file in the folder, not only the grid of the last bench command (for a table "
                        "built by several commands into one folder)")
    p.add_argument("--running", action="store_true",
                   help="only list the cells running now (from DIR/progress/, written after every epoch, checked "
                        "against the processes that write them; a cell whose process has ended is listed as "
                        "stopped) and exit; `watch tactile-zoo report DIR --running` follows a run from a second "
                        "terminal")
    _add_skip_invalid(p)
    p.set_defaults(handler=_cmd_report)


def _cmd_report(args: argparse.Namespace) -> int:
    from ..bench import write_outputs
    from ..bench.progress import describe_running

    running = describe_running(args.dir)
    if args.running:
        for line in running:
            echo(line)
        if not any(line.startswith("running ") for line in running):
            echo(f"no cell is running in {args.dir}")
        return 0
    written = write_outputs(args.dir, plots=not args.no_plots, all_cells=args.all_cells,
                            skip_invalid=args.skip_invalid,
                            on_invalid=lambda item: logger.warning("damaged cell file %s; left out (--skip-invalid)",
                                                                   item))
    for path in written.values():
        echo(f"wrote {path}")
    for line in running:
        echo(line)
    return 0


def add_rebuild_weights(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rebuild-weights", help="remake a bench folder's saved weights from its cell records, without "
                                               "reading a test split",
                       description="Weights are not committed; their cell records are. Train each selected cell that "
                                   "saved weights again from its record (its revision, seed and thread count; the "
                                   "test split is neither loaded nor evaluated) and keep the file only when its "
                                   "sha256 is the recorded one. Files already there with that sha256 are kept. "
                                   "Reproduces on the CPU type that ran the cells; exit 1 when a file differs.")
    p.add_argument("dir", help="a bench output folder whose cells were run with --save-weights")
    p.add_argument("--cell", action="append", default=[], metavar="ID",
                   help="only cells whose id matches (shell wildcards, e.g. 'dcnn__ev_objects__f0__s[5-9]__*'; "
                        "repeatable; default every cell that saved weights)")
    p.add_argument("--root", default=None, help="data home (default $TACTILE_ZOO_DATA, else ~/.cache/tactile_zoo/data)")
    p.add_argument("--workers", type=int, default=1, help="cells trained side by side, one process each (default 1)")
    p.add_argument("--plugin-module", dest="plugin_modules", action="append", default=[], metavar="MODULE",
                   help="import these modules in each worker (models registered outside entry points)")
    p.add_argument("--dry-run", action="store_true", help="list the selected cells and exit")
    p.set_defaults(handler=_cmd_rebuild_weights)


def _cmd_rebuild_weights(args: argparse.Namespace) -> int:
    from ..bench.rebuild import rebuild_weights, weight_cells
    from ..engine.runtime import cpu_isa, cpu_model
    from ..study.audit import cpu_type

    records = weight_cells(args.dir, args.cell)
    here = f"{cpu_model()} ({cpu_isa().get('capability', '?')})"
    for record in records:
        if cpu_type(record) != here:
            logger.warning("%s ran on %s, this machine is %s: its weights will probably not reproduce",
                           record["cell_id"], cpu_type(record), here)
    if args.dry_run:
        for record in records:
            echo(f"{record['cell_id']}: {record['weights']['file']} ({record.get('seconds', 0):.0f} s when it ran)")
        return 0
    outcomes = rebuild_weights(args.dir, args.cell, root=args.root, workers=args.workers,
                               plugin_modules=args.plugin_modules, on_result=lambda o: echo(o.line()))
    differ = [o for o in outcomes if o.status == "differs"]
    echo(f"{len(outcomes)} cell(s): {sum(o.status == 'present' for o in outcomes)} already there, "
         f"{sum(o.status == 'rebuilt' for o in outcomes)} rebuilt, {len(differ)} differ")
    return 1 if differ else 0
