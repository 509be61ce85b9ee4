"""What the study tests share: the in-process CLI, and the quickstart run (``study check`` before it, ``study run``,
``study audit`` and ``study report`` after), which a test that plants a violation copies into its tmp_path."""

from __future__ import annotations

import contextlib
import io
import shutil
from dataclasses import dataclass
from pathlib import Path

from tactile_zoo.cli import main

QUICKSTART = Path(__file__).resolve().parents[2] / "examples" / "studies" / "quickstart.yaml"


def tz(*argv: str) -> tuple[int, str, str]:
    """``tactile-zoo ARGV`` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


@dataclass
class QuickstartRun:
    folder: Path  # holds quickstart.yaml and quickstart-results/
    check: tuple[int, str, str]
    run: tuple[int, str, str]
    audit: tuple[int, str, str]
    report: tuple[int, str, str]

    @property
    def file(self) -> Path:
        return self.folder / "quickstart.yaml"

    def copy(self, where: Path) -> Path:
        """A copy of the study file and its results under ``where``; returns the copied study file."""
        shutil.copytree(self.folder, where / "study", ignore=shutil.ignore_patterns("*.lock", "claims", "progress"))
        return where / "study" / "quickstart.yaml"
