"""``study run``: freeze the study, then run each grid that is not superseded with the bench (the same cells, in
the grid's folder, resumable: a finished cell is never run again).

The freeze comes first (:func:`~.freeze.freeze`): a file changed after cells exist is refused before any cell runs,
naming what changed. A study that has already spent its CPU-hour budget runs no further cell.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TextIO

from ..bench import run_bench
from ..errors import ConfigError
from .audit import cpu_hours, study_records
from .checks import plans
from .freeze import freeze
from .schema import Study

__all__ = ["StudyOutcome", "run_study"]

logger = logging.getLogger(__name__)


@dataclass
class StudyOutcome:
    exit_code: int = 0
    counts: dict[str, dict[str, int]] = field(default_factory=dict)  # grid -> the bench's counts


def run_study(study: Study, *, quiet: bool = False, out: TextIO | None = None, err: TextIO | None = None,
              plots: bool = False, grids: list[str] | None = None) -> StudyOutcome:
    """Freeze ``study`` and run its grids through :func:`~tactile_zoo.bench.run_bench`; the exit code is the worst
    of the grids' (0 every cell ok). ``grids``: only these, in the file's order (default: every grid)."""
    names = [g.name for g in study.grids()]
    unknown = [g for g in grids or [] if g not in names]
    if unknown:
        raise ConfigError(f"--grid {', '.join(unknown)}: not a grid of {study.where} (its grids: {', '.join(names)})")
    state = freeze(study)
    logger.info("study %s frozen %s (sha256 %s) in %s", study.name, state["time"], state["sha256"][:12],
                study.results / "study")
    budget = study.rules().budget_cpu_hours
    outcome = StudyOutcome()
    all_plans = plans(study)
    for name, plan in all_plans.items():
        if grids is not None and name not in grids:
            continue
        if plan.spec.superseded:
            logger.info("grid %s is superseded (%s): not run", name, plan.spec.superseded)
            continue
        if plan.spec.reused:  # another study's folder: read here, never run or rewritten from here
            logger.info("grid %s is reused (%s): read, not run", name, plan.spec.reused)
            continue
        if budget is not None:  # the study's own cells, as the audit counts them: a reused grid's are not its cost
            spent = cpu_hours([r for grid, recs in study_records(study)[0].items() for r in recs
                               if not all_plans[grid].spec.reused])
            if spent > budget:
                raise ConfigError(f"{study.where}: budget exceeded: {spent:.3f} CPU-hours spent of "
                                  f"rules.budget_cpu_hours {budget:g}; no further cell runs (amend the rule with its "
                                  f"reason while no cell exists, or audit what ran)")
        result = run_bench(plan.config, quiet=quiet, out=out, err=err, plots=plots)
        outcome.counts[name] = dict(result.counts)
        outcome.exit_code = max(outcome.exit_code, result.exit_code)
    return outcome
