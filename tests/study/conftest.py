"""The quickstart study run once for every test of the folder (:mod:`study_helpers`); a test that changes it works
on a copy."""

from __future__ import annotations

import pytest
from study_helpers import QUICKSTART, QuickstartRun, tz


@pytest.fixture(scope="package")
def quickstart(tmp_path_factory: pytest.TempPathFactory) -> QuickstartRun:
    """The example as shipped but for its executor and its frames: its cells run in this process, not in two spawned
    workers (each would import torch and the package again, ~4 s apiece; the process executor is
    tests/bench/test_executors.py's, which checks it gives what this one does), on grasps of 20 frames instead of 100
    (``dataset_kwargs``: the same episodes, sampled more coarsely; the cells' compute 7 -> 2 CPU-s, the protocol the
    same)."""
    folder = tmp_path_factory.mktemp("quickstart")
    text = QUICKSTART.read_text()
    assert "executor: process\n" in text and "      workers: 2\n" in text and "dataset_kwargs" not in text
    text = text.replace("executor: process\n", "executor: local\n").replace(
        "      workers: 2\n", "      workers: 2\n      dataset_kwargs: {sim_evtouch: {num_steps: 20}}\n")
    (folder / "quickstart.yaml").write_text(text)
    study = str(folder / "quickstart.yaml")
    check = tz("study", "check", study, "--history", str(folder / "no-history"))
    run = tz("study", "run", study, "-q")
    return QuickstartRun(folder, check, run, tz("study", "audit", study), tz("study", "report", study))
