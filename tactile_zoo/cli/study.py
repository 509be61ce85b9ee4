"""``tactile-zoo study check|freeze|run|audit|report|compare FILE``: a pre-registered study (:mod:`tactile_zoo.study`);
``compare``: one whose grids train your models only, set against a published set (:mod:`tactile_zoo.study.compare`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..errors import ConfigError
from ._common import echo, progress_on

__all__ = ["add_study"]

ACTIONS = ("check", "freeze", "run", "audit", "report", "compare")


def add_study(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="check, run, audit or report a pre-registered study file",
                       description="check: validate the file, print its grids' cells and estimate the CPU-hours. "
                                   "run: freeze the file (its hash and a copy into the results folder), then run "
                                   "every grid with the bench (resumable). freeze: only the freeze that run starts "
                                   "with, for a plan committed before its first cell. audit: check the cells "
                                   "against the study's rules (exit 1 naming each broken one). report: markdown and "
                                   "CSV of the results, the declared reads (recorded once) and the rules' outcomes. "
                                   "compare: a study whose grids train only your models and whose `against` "
                                   "names a published set of the zoo's cells: refuse what cannot be compared "
                                   "(another split, dataset revision, protocol or seed set), run the grids, "
                                   "then report yours beside the published cells (means, paired differences, "
                                   "early classification, tuning); no baseline is retrained.")
    p.add_argument("action", choices=ACTIONS, help="what to do with the study")
    p.add_argument("file", help="the study file (YAML)")
    p.add_argument("--history", action="append", default=None, metavar="DIR",
                   help="check: folders of earlier bench results to estimate the cost from, searched recursively "
                        "(repeatable; default: ./benchmarks/results when it exists; the study's own folder always)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report: where to write report.md, summary.csv and reads.csv (default RESULTS/study); compare: "
                        "report.md, means.csv, paired.csv and curves.csv (default RESULTS/compare)")
    p.add_argument("-q", "--quiet", action="store_true", help="run, compare: no progress")
    p.add_argument("--grid", action="append", default=None, metavar="NAME",
                   help="run: only this grid (repeatable; default every grid, in the file's order)")
    p.set_defaults(handler=_cmd_study)


def _cmd_study(args: argparse.Namespace) -> int:
    from ..study import audit, run_study, write_report
    from ..study.checks import describe, plans
    from ..study.compare import load_comparison
    from ..study.compare_report import run_comparison
    from ..study.freeze import freeze as freeze_study
    from ..study.freeze import freeze_status
    from ..study.plan import check_lines

    if args.grid is not None and args.action != "run":
        raise ConfigError(f"--grid: only `study run` takes it, not `study {args.action}`")
    if args.action == "compare":
        for path in run_comparison(args.file, out=args.out, quiet=not progress_on(args)).values():
            echo(f"wrote {path}")
        return 0
    study, _ = load_comparison(args.file)  # a comparison study's `against` is read by compare alone
    if args.action == "check":
        history = [Path(h) for h in args.history] if args.history is not None else \
            [p for p in (Path(os.getcwd()) / "benchmarks" / "results",) if p.is_dir()]
        for line in [*describe(study), *freeze_status(study), *check_lines(study, plans(study), history)]:
            echo(line)
        return 0
    if args.action == "freeze":
        state = freeze_study(study)
        echo(f"study {study.name} frozen {state['time']} (sha256 {state['sha256'][:12]}) in "
             f"{study.results / 'study'}")
        return 0
    if args.action == "run":
        return run_study(study, quiet=not progress_on(args), grids=args.grid).exit_code
    if args.action == "audit":
        result = audit(study)
        for line in result.lines:
            echo(line)
        for line in result.failures:
            echo(f"FAIL: {line}")
        echo(f"audit of study {study.name}: " + (f"{len(result.failures)} rule(s) broken" if result.failures
                                                 else "every rule held"))
        return 1 if result.failures else 0
    for path in write_report(study, args.out).values():
        echo(f"wrote {path}")
    return 0
