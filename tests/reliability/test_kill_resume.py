"""SIGKILL at chosen points of a real ``tactile-zoo bench`` subprocess, and two bench processes on one folder.

The stop points come from kill_points.py (the process announces it has reached the point, then waits for the
kill), so every kill lands where the test says on any machine, however loaded. The killed processes are forked from
a warm server (tests/forked_bench.py): processes of their own, without an interpreter's start-up each. One chain of
runs on one folder is killed four times and finally completes (that last run in this process); after every kill the
rerun must keep each finished cell file byte for byte (not lost, not recomputed), and the final leaderboard must
equal an uninterrupted run's.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
from reliability_helpers import (
    SMALL_ARGS,
    cell_files,
    cell_records,
    finish,
    fork_kill_bench,
    numbers,
    quiet_bench,
    read_csv,
    wait_for_file,
)

pytestmark = pytest.mark.slow


def _killed_at(point: str, out: Path, tmp: Path, name: str) -> str:
    """Run the small grid on ``out`` until ``point``, SIGKILL it there; returns its stdout."""
    log, signal_file = tmp / name, tmp / f"{name}.reached"
    proc = fork_kill_bench([*SMALL_ARGS, "--out", str(out)], log, TZ_RELIABILITY_STOP=point,
                           TZ_RELIABILITY_SIGNAL=str(signal_file))
    wait_for_file(signal_file, proc, log)
    proc.kill()
    code, stdout, _ = finish(proc, log)
    assert code == -9  # really killed, not exited
    return stdout


def _torn(folder: Path) -> list[Path]:
    return sorted(folder.glob(".*.tmp"))


def test_killed_four_times_then_resumed_equals_an_uninterrupted_run(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    reference = cell_records(reference_run)
    assert len(reference) == 6

    # 1. inside the first cell: computed, not yet written -> nothing is finished
    _killed_at("cell:1", out, tmp_path, "kill1")
    assert cell_files(out) == {}
    assert json.loads((out / "run.json").read_text())["status"] == "running"

    # 2. between cells: the rerun finishes cells 1 and 2 and is killed before claiming the third
    text = _killed_at("claim:3", out, tmp_path, "kill2")
    assert "6 cells, 0 already finished, 6 to run" in text
    after2 = cell_files(out)
    assert len(after2) == 2

    # 3. in the middle of writing the fourth cell's file: a torn temporary file, never a torn cell file
    text = _killed_at("cellwrite:2", out, tmp_path, "kill3")
    assert "6 cells, 2 already finished, 4 to run" in text
    after3 = cell_files(out)
    assert len(after3) == 3 and {k: after3[k] for k in after2} == after2  # the finished two: untouched
    (torn,) = _torn(out / "cells")
    with pytest.raises(ValueError):
        json.loads(torn.read_text())

    # 4. in the middle of writing summary.csv, after every cell and leaderboard.csv are written
    text = _killed_at("table:summary.csv", out, tmp_path, "kill4")
    assert "6 cells, 3 already finished, 3 to run" in text
    after4 = cell_files(out)
    assert len(after4) == 6 and {k: after4[k] for k in after3} == after3
    assert not (out / "summary.csv").exists() and len(_torn(out)) == 1
    assert read_csv(out / "leaderboard.csv") == read_csv(reference_run / "leaderboard.csv")

    # 5. the same grid once more (in this process: nothing is killed any more): nothing left to compute, every
    # output rebuilt, the plots included
    outcome, stdout, stderr = quiet_bench(out, plots=True)
    code = outcome.exit_code
    assert code == 0, stderr
    assert "6 cells, 6 already finished, 0 to run" in stdout and "done: 6 ok, 0 failed" in stdout
    assert cell_files(out) == after4  # not one cell recomputed
    assert read_csv(out / "leaderboard.csv") == read_csv(reference_run / "leaderboard.csv")
    assert read_csv(out / "summary.csv") == read_csv(reference_run / "summary.csv")
    records = cell_records(out)
    assert {k: numbers(v) for k, v in records.items()} == {k: numbers(v) for k, v in reference.items()}
    assert json.loads((out / "run.json").read_text())["status"] == "finished"
    assert (out / "report.md").is_file() and (out / "plots" / "heatmap.png").is_file()


def test_two_processes_on_one_folder_share_the_cells(reference_run: Path, tmp_path: Path) -> None:
    """Process A stops inside cell 2 holding its claim; process B (this one) starts on the same folder, reuses cell 1,
    computes cells 3-6, says it waits for A's cell, and takes A's result. Neither computes a cell twice."""
    out = tmp_path / "run"
    log, reached, go = tmp_path / "a", tmp_path / "a.reached", tmp_path / "a.go"
    proc = fork_kill_bench([*SMALL_ARGS, "--out", str(out)], log, TZ_RELIABILITY_STOP="cell:2",
                           TZ_RELIABILITY_SIGNAL=str(reached), TZ_RELIABILITY_GO=str(go))
    try:
        wait_for_file(reached, proc, log)
        first = sorted(cell_files(out))
        assert len(first) == 1
        others = {n for n in cell_records(reference_run)} - set(first)

        def release_a_when_b_is_done() -> None:  # B blocks on A's claim once its own cells are written
            deadline = time.monotonic() + 240
            while time.monotonic() < deadline and len(set(cell_files(out)) & others) < 4:
                time.sleep(0.05)
            go.touch()

        helper = threading.Thread(target=release_a_when_b_is_done, daemon=True)
        helper.start()
        outcome, text_b, err_b = quiet_bench(out)
        helper.join()
    finally:
        go.touch()
    code, text_a, err_a = finish(proc, log)
    assert code == 0, err_a
    assert outcome.exit_code == 0, err_b
    assert f"is running (pid {proc.pid} on " in text_b and "waiting for 1 cell(s) that another tactile-zoo bench" \
        in text_b
    # A computed cells 1 and 2 and found the other four finished by B; B computed exactly those four
    ran_a = [line for line in text_a.splitlines() if line.startswith("[") and "finished by another" not in line]
    assert len(ran_a) == 2 and text_a.count("(finished by another process)") == 4
    ran_b = {f"{c}.json" for c in outcome.ran}
    assert len(ran_b) == 4 and len(outcome.reused) == 2 and ran_b < others
    records = cell_records(out)
    assert set(records) - ran_b - set(first) == others - ran_b  # the one cell A held: computed by A only
    assert len(records) == 6 and not list((out / "cells").glob(".*.tmp"))
    assert {k: numbers(v) for k, v in records.items()} == \
        {k: numbers(v) for k, v in cell_records(reference_run).items()}
    assert read_csv(out / "leaderboard.csv") == read_csv(reference_run / "leaderboard.csv")
