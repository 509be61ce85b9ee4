"""``examples/studies/my_recordings.yaml``: a study on a user's own recordings passes ``study check`` once the trials
are there, and says where they belong when they are not (run in a child process: its plugin registers a dataset; the
child is forked from the warm server of tests/forked_bench.py, torch and the package already imported)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
from forked_bench import run_python

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "studies"
#: ``study check`` of each study file given, in one child (one start-up for both): [exit code, stdout, stderr] each.
#: The plugin module is imported once, from the first folder (the same file in each), as a second --plugin-module is.
CHECKS = """
import contextlib, io, json, sys
from tactile_zoo.cli import main
out = []
for study in sys.argv[1:]:
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["study", "check", study, "--history", study + ".none"])
    out.append([code, stdout.getvalue(), stderr.getvalue()])
print(json.dumps(out))
"""


def _checks(log: Path, *folders: Path) -> list[tuple[int, str, str]]:
    studies = [str(folder / "my_recordings.yaml") for folder in folders]
    out, _ = run_python(CHECKS, studies, log)
    return [tuple(result) for result in json.loads(out.splitlines()[-1])]


def test_the_recordings_study_checks_on_the_users_trials(tmp_path: Path) -> None:
    missing, present = tmp_path / "missing", tmp_path / "present"
    for folder in (missing, present):
        folder.mkdir()
        for name in ("my_recordings.yaml", "my_grasps.py"):
            shutil.copy(EXAMPLES / name, folder / name)
    rng = np.random.default_rng(0)
    for label in ("cup", "sponge"):
        folder = present / "my-data" / "my_grasps" / "raw" / label
        folder.mkdir(parents=True)
        for trial in range(5):  # a BioTac SP: 24 taxels x 1 channel, 12 steps
            np.savetxt(folder / f"{trial}.csv", rng.normal(size=(12, 24)), delimiter=",")
    (code, _, err), (done, out, err2) = _checks(tmp_path / "checks", missing, present)
    assert code == 2 and "my_grasps" in err and "raw" in err, err
    assert done == 0, err2
    assert "30 cells: 2 model(s) x 1 dataset(s)" in out
    assert "my_grasps: protocol fixed, folds 0..4 of 5" in out
    assert "x_tacformer x my_grasps, 15 cell(s): no earlier cell" in out
    assert "estimate: none (no pair of the grids has an earlier cell" in out
