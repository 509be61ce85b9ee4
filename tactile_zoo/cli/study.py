"""``tactile-zoo study check|run|audit|report FILE``: a pre-registered study (:mod:`tactile_zoo.study`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ._common import echo, progress_on

__all__ = ["add_study"]

ACTIONS = ("check", "run", "audit", "report")


def add_study(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="check, run, audit or report a pre-registered study file",
                       description="check: validate the file, print its grids' cells and estimate the CPU-hours. "
                                   "run: freeze the file (its hash and a copy into the results folder), then run "
                                   "every grid with the bench (resumable). audit: check the cells against the "
                                   "study's rules (exit 1 naming each broken one). report: markdown and CSV of the "
                                   "results, the declared reads (recorded once) and the rules' outcomes.")
    p.add_argument("action", choices=ACTIONS, help="what to do with the study")
    p.add_argument("file", help="the study file (YAML)")
    p.add_argument("--history", action="append", default=None, metavar="DIR",
                   help="check: folders of earlier bench results to estimate the cost from, searched recursively "
                        "(repeatable; default: ./benchmarks/results when it exists; the study's own folder always)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="report: where to write report.md, summary.csv and reads.csv (default RESULTS/study)")
    p.add_argument("-q", "--quiet", action="store_true", help="run: no progress")
    p.set_defaults(handler=_cmd_study)


def _cmd_study(args: argparse.Namespace) -> int:
    from ..study import audit, load_study, run_study, write_report
    from ..study.checks import describe, plans
    from ..study.freeze import freeze_status
    from ..study.plan import check_lines

    study = load_study(args.file)
    if args.action == "check":
        history = [Path(h) for h in args.history] if args.history is not None else \
            [p for p in (Path(os.getcwd()) / "benchmarks" / "results",) if p.is_dir()]
        for line in [*describe(study), *freeze_status(study), *check_lines(study, plans(study), history)]:
            echo(line)
        return 0
    if args.action == "run":
        return run_study(study, quiet=not progress_on(args)).exit_code
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
