"""A reused grid that another study runs (``ran_by``): ``check`` finds the grid in that study's file, and until its
cells are in, the audit reports it waiting, as a grid of the study's own plan not run yet, instead of failing."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactile_zoo.errors import ConfigError
from tactile_zoo.study import audit, load_study
from tactile_zoo.study.checks import check_study
from tactile_zoo.study.freeze import freeze

_SETTINGS = "{models: [cnn_lstm], datasets: sim_evtouch, quick: true, epochs: 1, seeds: %s}"
_RUNNER = f"""\
study: runner
question: Which seeds does the runner run?
results: runner-results
grids:
  - {{name: main, settings: {_SETTINGS % "[0, 1, 2]"}}}
"""
_READER = """\
study: reader
question: What does an ensemble of the runner's seeds score?
results: reader-results
grids:
  - {name: own, settings: %s}
  - {name: theirs, folder: ../runner-results/main, reused: the runner's seeds, ran_by: %s, settings: %s}
reads:
  ensembles: [{name: ens, grid: theirs, dataset: sim_evtouch, members: [{model: cnn_lstm, seeds: [1, 2]}]}]
"""


def _write(tmp_path: Path, ran_by: str = "runner.yaml", seeds: str = "[1, 2]", reused: bool = True) -> Path:
    (tmp_path / "runner.yaml").write_text(_RUNNER)
    text = _READER % (_SETTINGS % "[5]", ran_by, _SETTINGS % seeds)
    if not reused:
        text = text.replace(" reused: the runner's seeds,", "")
    (tmp_path / "reader.yaml").write_text(text)
    return tmp_path / "reader.yaml"


def test_a_grid_run_by_another_study_waits_for_it_in_the_audit(tmp_path: Path) -> None:
    study = load_study(_write(tmp_path))
    check_study(study)
    freeze(study)
    result = audit(study)
    assert not result.failures, result.failures
    assert "grid theirs: not run yet (frozen in runner.yaml, which runs it)" in result.lines
    assert "ensemble ens: waits for its members (grid theirs not run yet)" in result.lines
    # without ran_by the same state is a broken rule: the folder is missing and so are the members
    plain = tmp_path / "plain.yaml"
    plain.write_text((tmp_path / "reader.yaml").read_text().replace(" ran_by: runner.yaml,", "")
                     .replace("study: reader", "study: plain").replace("reader-results", "plain-results"))
    study = load_study(plain)
    freeze(study)
    broken = {rule for rule, held in audit(study).rules.items() if not held}
    assert {"cells present", "ensemble members"} <= broken


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"ran_by": "nosuch.yaml"}, r"grids.theirs.ran_by: no study file .*nosuch.yaml"),
    ({"seeds": "[2, 3]"}, r"grid main of .*runner.yaml runs .* but not seed\(s\) \[3\]"),
    ({"reused": False}, r"grids.theirs.ran_by: only a reused grid"),
])
def test_check_refuses_a_ran_by_that_does_not_hold(tmp_path: Path, kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        check_study(load_study(_write(tmp_path, **kwargs)))


def test_check_refuses_a_study_that_does_not_run_the_folder(tmp_path: Path) -> None:
    path = _write(tmp_path)
    path.write_text(path.read_text().replace("../runner-results/main", "../runner-results/other"))
    with pytest.raises(ConfigError, match=r"runner.yaml has no grid that runs .*runner-results/other"):
        check_study(load_study(path))


def test_a_reused_grid_is_neither_run_nor_paid_for(tmp_path: Path) -> None:
    """The budget counts the study's own cells, in ``study run`` as in the audit: the runner's cells (planted at an
    hour each) are read by the reader, not paid for, so the reader's own grid still runs under its small budget; and
    ``study run`` leaves the runner's folder alone."""
    from tactile_zoo.bench.records import run_records
    from tactile_zoo.bench.rundir import RunDir
    from tactile_zoo.study import run_study

    path = _write(tmp_path)
    path.write_text(path.read_text().replace("reads:\n", "rules: {budget_cpu_hours: 0.5}\nreads:\n", 1))
    assert run_study(load_study(tmp_path / "runner.yaml"), quiet=True).exit_code == 0
    folder = tmp_path / "runner-results" / "main"
    for record in run_records(folder):
        RunDir(folder).write_cell({**record, "seconds": 3600.0})
    before = {f.name: f.read_bytes() for f in folder.iterdir() if f.is_file()}
    outcome = run_study(load_study(path), quiet=True)
    assert outcome.exit_code == 0 and outcome.counts["own"]["ok"] == 1
    # the reused grid is read, not run: the runner's folder is not rewritten from the reader (run.json, leaderboard)
    assert list(outcome.counts) == ["own"]
    assert {f.name: f.read_bytes() for f in folder.iterdir() if f.is_file()} == before
    result = audit(load_study(path))
    assert result.rules["budget"] and any("(reused cells not counted)" in line for line in result.lines)
