"""Studies: a pre-registered benchmark as a file that tactile-zoo checks, runs, audits and reports.

A study file (:mod:`.schema`) holds the question, one or more grids in the bench settings, the rules (one CPU type,
a CPU-hour budget, whether the test split may be read), the declared reads (ensembles, comparisons, thresholds and
the decision each outcome leads to), the figures it publishes and the external figures it compares with.

- :func:`load_study` reads and checks it (:mod:`.checks`); :mod:`.plan` makes each grid the bench's cells and
  estimates their CPU-hours from earlier cells;
- :func:`run_study` freezes it (:mod:`.freeze`) and runs its grids with the bench (:mod:`.run`);
- :func:`audit` checks the cells against the rules (:mod:`.audit`);
- :func:`write_report` writes the markdown and CSV report, recording each declared read once (:mod:`.reads`).

The package sits between the command line and the harness: ``cli -> study -> bench``.
"""

from __future__ import annotations

from .audit import AuditResult, audit
from .checks import load_study
from .freeze import freeze
from .report import write_report
from .run import StudyOutcome, run_study
from .schema import Study

__all__ = ["Study", "load_study", "freeze", "run_study", "StudyOutcome", "audit", "AuditResult", "write_report"]
