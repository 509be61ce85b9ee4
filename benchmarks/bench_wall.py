"""Wall-clock time and peak memory of ``tactile-zoo bench --models all`` on the embedded default.

The command runs as a child process, as a new user would run it: a fresh ``--out`` folder, an empty data home
(``TACTILE_ZOO_DATA``), so the grid is every model on the simulated datasets that ship with the package, and a fresh
processed-data cache (``TACTILE_ZOO_CACHE``), so generating the simulated data is included. ``--device`` is passed
on; ``--threads`` sets the number of worker processes. Peak memory is the bench process's own resident-set
high-water mark, ``VmHWM`` read from ``/proc/self/status`` as it exits, and the largest per-cell peak the harness
recorded (``max_cell_peak_mb``: with the process executor the cells run in worker processes, whose memory the
parent's high-water mark does not see). Not ``getrusage(RUSAGE_CHILDREN).ru_maxrss``: Linux starts a spawned child's
``ru_maxrss`` at the spawning process's peak (recorded at ``exec``), so after the other benchmarks it would report
this process's size. Where ``/proc`` is
missing, ``ru_maxrss`` from ``os.wait4`` is used, an upper bound (``rss_source`` says which).

The command is the README's first one (``make bench``): ``--executor process --workers N`` with N = ``--threads``,
one torch thread per worker. The full grid trains every model with its whole recipe; ``--quick`` runs ``tactile-zoo
bench --quick`` instead (2 epochs on small subsets). With ``BENCH_WALL_KEEP=DIR`` in the environment the run's output
folder (leaderboard, report, plots, cell files) is copied to DIR instead of being thrown away; ``BENCH_WALL_EPOCHS=N``
passes ``--epochs N`` (the full grid shortened to fit a time budget, as ``benchmarks.gpu_check`` runs it; the row's
``case`` and ``command`` say so).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tactile_zoo.bench.records import run_records

from .common import Context, write_csv

NAME = "bench_wall"
TITLE = "Wall-clock and peak RSS of `tactile-zoo bench --models all` on the embedded default (simulated data)"
COLUMNS = ("command", "exit_code", "cells", "cells_not_ok", "wall_s", "cpu_s", "peak_rss_mb", "rss_source",
           "max_cell_peak_mb")

# the console script's main(), then the process's own peak RSS (VmHWM of its address space since exec) into argv[1]
_LAUNCH = """
import sys
from tactile_zoo.cli import main
code = main(sys.argv[2:])
try:
    with open("/proc/self/status") as fh:
        hwm = [line.split()[1] for line in fh if line.startswith("VmHWM:")]
    with open(sys.argv[1], "w") as fh:
        fh.write(hwm[0])
except (OSError, IndexError):
    pass
sys.exit(code)
"""


def launch_measured(args: list[str], env: dict[str, str], log: Path, hwm: Path
                    ) -> tuple[int, float, Any, int, str]:
    """Run ``tactile-zoo ARGS`` as a child process, its output into ``log``: exit code, wall seconds, its rusage, and
    its peak RSS in kB with where that came from (``vmhwm``, which the child writes into ``hwm`` as it exits, else
    ``ru_maxrss``, in kB on every platform)."""
    hwm.unlink(missing_ok=True)
    with log.open("w") as out:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _LAUNCH, str(hwm), *args], env=env, stdout=out,
                                stderr=subprocess.STDOUT)
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        except BaseException:  # interrupted: do not leave the child running
            proc.kill()
            proc.wait()
            raise
        wall = time.perf_counter() - start
    proc.returncode = code = os.waitstatus_to_exitcode(status)  # reaped here, so Popen must not wait again
    rss_kb, source = (int(hwm.read_text()), "vmhwm") if hwm.exists() else (usage.ru_maxrss, "ru_maxrss")
    if source == "ru_maxrss" and sys.platform == "darwin":
        rss_kb //= 1024  # bytes there, kB on Linux
    return code, wall, usage, rss_kb, source


def bench_args(ctx: Context, out: Path, models: str = "all", datasets: str | None = None,
               extra: tuple[str, ...] = ()) -> list[str]:
    """The ``tactile-zoo bench`` arguments: the README's command on ``ctx.device``, with one worker process per
    thread of the budget and one torch thread each (bench's default); ``--epochs`` from ``$BENCH_WALL_EPOCHS``."""
    args = ["bench", "--models", models, "--out", str(out), "--device", str(ctx.device), "--executor", "process",
            "--workers", str(ctx.threads), "-q"]
    if datasets:
        args += ["--datasets", datasets]
    if ctx.quick:
        args.append("--quick")
    epochs = os.environ.get("BENCH_WALL_EPOCHS")
    if epochs:
        args += ["--epochs", str(int(epochs))]  # int(): a typo fails here, not as a bench usage error
    return args + list(extra)


def run(ctx: Context, models: str = "all", datasets: str | None = None, extra: tuple[str, ...] = ()) -> Path:
    with tempfile.TemporaryDirectory(prefix="tz-bench-wall-") as tmp:
        tmp_path = Path(tmp)
        (tmp_path / "data").mkdir()
        args = bench_args(ctx, tmp_path / "out", models, datasets, extra)
        env = {**os.environ, "TACTILE_ZOO_DATA": str(tmp_path / "data"), "TACTILE_ZOO_CACHE": str(tmp_path / "cache")}
        log = tmp_path / "log.txt"
        code, wall, usage, rss_kb, rss_source = launch_measured(args, env, log, tmp_path / "vmhwm")
        records = run_records(tmp_path / "out")
        statuses = [str(r.get("status")) for r in records]
        cells, failed = statuses.count("ok"), sum(1 for s in statuses if s != "ok")
        cell_peaks = [r["peak_memory_mb"] for r in records if r.get("peak_memory_mb") is not None]
        keep = os.environ.get("BENCH_WALL_KEEP")
        if keep:
            shutil.copytree(tmp_path / "out", keep, dirs_exist_ok=True)
        if code != 0:  # a failed run is no measurement
            raise RuntimeError(f"tactile-zoo bench exited with {code}:\n{log.read_text()[-3000:]}")
    cpu = usage.ru_utime + usage.ru_stime
    command = "tactile-zoo " + " ".join(a if "tz-bench-wall-" not in a else "<fresh tmp dir>" for a in args)
    epochs = os.environ.get("BENCH_WALL_EPOCHS")
    case = "quick" if ctx.quick else (f"{int(epochs)} epochs" if epochs else "full")
    row = {"case": case, "command": command, "exit_code": code,
           "cells": cells, "cells_not_ok": failed, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss_kb / 1024,
           "rss_source": rss_source, "max_cell_peak_mb": max(cell_peaks) if cell_peaks else None,
           "note": "empty data home (simulated datasets only), fresh cache (includes generating them)"}
    ctx.log(f"  {command}: {wall:.0f} s wall, {cpu:.0f} s CPU, {cells} cells ok ({failed} not), peak RSS "
            f"{rss_kb / 1024:.0f} MB")
    return write_csv(ctx, NAME, COLUMNS, [row])


__all__ = ["run", "bench_args", "NAME", "TITLE"]
