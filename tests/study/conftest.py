"""The quickstart study run once for every test of the folder (:mod:`study_helpers`); a test that changes it works
on a copy."""

from __future__ import annotations

import shutil

import pytest
from study_helpers import QUICKSTART, QuickstartRun, tz


@pytest.fixture(scope="package")
def quickstart(tmp_path_factory: pytest.TempPathFactory) -> QuickstartRun:
    folder = tmp_path_factory.mktemp("quickstart")
    shutil.copy(QUICKSTART, folder / "quickstart.yaml")
    study = str(folder / "quickstart.yaml")
    check = tz("study", "check", study, "--history", str(folder / "no-history"))
    run = tz("study", "run", study, "-q")
    return QuickstartRun(folder, check, run, tz("study", "audit", study), tz("study", "report", study))
