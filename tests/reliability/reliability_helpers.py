"""Shared helpers of the reliability tests: bench subprocesses, stop points, and reading a run folder."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from forked_bench import ForkedBench, fork_bench

from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.runner import BenchOutcome, run_bench
from tactile_zoo.bench.tables import TIMING_COLUMNS

HERE = Path(__file__).resolve().parent
TESTS = HERE.parent
#: 2 models x (tiny_blobs: 1 fold + tiny_kfold: 2 of its 3 folds) x seed 0 = 6 cells of ~0.1 s each
SMALL_ARGS = ["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_blobs,tiny_kfold", "--folds", "2", "--seeds", "0",
              "--threads", "1"]
SMALL = {"models": ["tiny_mlp", "tiny_rate"], "datasets": ["tiny_blobs", "tiny_kfold"], "folds": 2, "seeds": [0],
         "threads": 1}
#: generous: the machines running the suite are shared, and a cold interpreter imports torch first
TIMEOUT = 240.0


def bench_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), str(TESTS), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["OMP_NUM_THREADS"] = "1"
    env.update(extra)
    return env


def start_bench(args: list[str], log: Path, **env: str) -> subprocess.Popen:
    """``python -m tactile_zoo.cli bench --plugin-module tiny_zoo --plugin-module kill_points ARGS`` in the
    background; stdout and stderr go to ``log`` (``.out``/``.err``)."""
    cmd = [sys.executable, "-m", "tactile_zoo.cli", "bench", "--plugin-module", "tiny_zoo", "--plugin-module",
           "kill_points", *args]
    out, err = open(log.with_suffix(".out"), "w"), open(log.with_suffix(".err"), "w")  # noqa: SIM115
    try:
        return subprocess.Popen(cmd, env=bench_env(**env), stdout=out, stderr=err, text=True)
    finally:
        out.close()
        err.close()


def fork_kill_bench(args: list[str], log: Path, **env: str) -> ForkedBench:
    """:func:`start_bench` forked from a warm server instead of started as a new interpreter (tests/forked_bench.py):
    the same command line, ``kill_points`` imported fresh under ``env``, about 6 CPU seconds less per child."""
    return fork_bench(["bench", "--plugin-module", "tiny_zoo", "--plugin-module", "kill_points", *args], log, **env)


def logs(log: Path) -> str:
    return f"stdout:\n{log.with_suffix('.out').read_text()}\nstderr:\n{log.with_suffix('.err').read_text()}"


def wait_for_file(path: Path, proc: subprocess.Popen | ForkedBench, log: Path, timeout: float = TIMEOUT) -> None:
    """Block until ``path`` exists; fail with the process's output if it ends first or the time runs out."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"the bench exited ({proc.returncode}) before reaching its stop point\n{logs(log)}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"no stop signal after {timeout:.0f} s\n{logs(log)}")
        time.sleep(0.02)


def finish(proc: subprocess.Popen | ForkedBench, log: Path) -> tuple[int, str, str]:
    try:
        proc.wait(timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"the bench did not finish in {TIMEOUT:.0f} s\n{logs(log)}") from None
    return proc.returncode, log.with_suffix(".out").read_text(), log.with_suffix(".err").read_text()


def quiet_bench(out: Path, plots: bool = False, **settings: Any) -> tuple[BenchOutcome, str, str]:
    """``run_bench`` in this process, by default without plots (they cost seconds and are not what most of these
    tests check); returns the outcome and what it printed on stdout and stderr."""
    stdout, stderr = io.StringIO(), io.StringIO()
    config = BenchConfig(**{**SMALL, "out": str(out), **settings})
    outcome = run_bench(config, out=stdout, err=stderr, plots=plots)
    return outcome, stdout.getvalue(), stderr.getvalue()


def read_csv(path: Path, drop_timing: bool = True) -> list[dict[str, str]]:
    """Rows of a leaderboard/summary CSV, without the machine-dependent timing columns."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [{k: v for k, v in r.items() if not (drop_timing and k in TIMING_COLUMNS)} for r in rows]


def cell_files(out: Path) -> dict[str, tuple[int, bytes]]:
    """Every finished cell file: name -> (mtime in ns, content). Equal snapshots mean nothing was rewritten."""
    return {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in sorted((out / "cells").glob("*.json"))
            if p.is_file()}


def cell_records(out: Path) -> dict[str, dict[str, Any]]:
    return {p.name: json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json")) if p.is_file()}


def numbers(record: dict[str, Any]) -> dict[str, Any]:
    """What a cell computed, without timings, host and dates: metrics, predictions, probabilities, curves."""
    curve = [{k: v for k, v in row.items() if k != "seconds"} for row in record.get("curve") or []]
    return {"metrics": record.get("metrics"), "predictions": record.get("predictions"), "curve": curve,
            "best_epoch": record.get("best_epoch"), "prefix": record.get("prefix"), "params": record.get("params"),
            "config_hash": record.get("config_hash"), "status": record.get("status")}
