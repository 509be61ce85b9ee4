"""``examples/studies/my_recordings.yaml``: a study on a user's own recordings passes ``study check`` once the trials
are there, and says where they belong when they are not (run in a subprocess: its plugin registers a dataset)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "studies"


def _check(folder: Path) -> subprocess.CompletedProcess[str]:
    argv = ["study", "check", str(folder / "my_recordings.yaml"), "--history", str(folder / "none")]
    return subprocess.run([sys.executable, "-m", "tactile_zoo.cli", *argv], capture_output=True, text=True,
                          timeout=300)


def test_the_recordings_study_checks_on_the_users_trials(tmp_path: Path) -> None:
    for name in ("my_recordings.yaml", "my_grasps.py"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    missing = _check(tmp_path)
    assert missing.returncode == 2 and "my_grasps" in missing.stderr and "raw" in missing.stderr, missing.stderr
    rng = np.random.default_rng(0)
    for label in ("cup", "sponge"):
        folder = tmp_path / "my-data" / "my_grasps" / "raw" / label
        folder.mkdir(parents=True)
        for trial in range(5):  # a BioTac SP: 24 taxels x 1 channel, 12 steps
            np.savetxt(folder / f"{trial}.csv", rng.normal(size=(12, 24)), delimiter=",")
    done = _check(tmp_path)
    assert done.returncode == 0, done.stderr
    assert "30 cells: 2 model(s) x 1 dataset(s)" in done.stdout
    assert "my_grasps: protocol fixed, folds 0..4 of 5" in done.stdout
    assert "x_tacformer x my_grasps, 15 cell(s): no earlier cell" in done.stdout
    assert "estimate: none (no pair of the grids has an earlier cell" in done.stdout
