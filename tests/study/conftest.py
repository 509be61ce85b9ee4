"""The quickstart study run once for every test of the folder (:mod:`study_helpers`); a test that changes it works
on a copy."""

from __future__ import annotations

import pytest
from study_helpers import QUICKSTART, QuickstartRun, tz


@pytest.fixture(scope="package")
def quickstart(tmp_path_factory: pytest.TempPathFactory) -> QuickstartRun:
    """The example as shipped but for its executor: its cells run in this process, not in two spawned workers (each
    would import torch and the package again, ~4 s apiece); the process executor is tests/bench/test_executors.py's,
    which checks it gives what this one does."""
    folder = tmp_path_factory.mktemp("quickstart")
    (folder / "quickstart.yaml").write_text(QUICKSTART.read_text().replace("executor: process\n", "executor: local\n"))
    study = str(folder / "quickstart.yaml")
    check = tz("study", "check", study, "--history", str(folder / "no-history"))
    run = tz("study", "run", study, "-q")
    return QuickstartRun(folder, check, run, tz("study", "audit", study), tz("study", "report", study))
