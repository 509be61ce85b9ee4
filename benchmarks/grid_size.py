"""Wall-clock time and peak memory of ``tactile-zoo bench --dry-run`` over a huge seed range (issue 38, item 6).

``--seeds 0-100000000 --dry-run`` once ran for minutes and grew to 16 GB listing a hundred million cells. A bench
command now takes at most ``MAX_CELLS`` cells (:mod:`tactile_zoo.bench.config`) and counts the seeds of a range
before expanding it, so the command answers with the count at once. Each case runs as a child process (a fresh
interpreter, as a user runs it) whose own peak resident set (``VmHWM``) is read as it exits, like ``bench_wall``:

- ``huge_seed_range``: ``--seeds 0-100000000 --dry-run``, refused with the count (exit 2);
- ``startup``: ``tactile-zoo --version``, the interpreter and the package's imports alone (the floor of any command);
- ``one_seed``: the same command with ``--seeds 0``, the baseline (start-up, the dataset probe, one model built);
- ``max_cells``: ``--seeds 0-<MAX_CELLS - 1>``, the largest grid accepted, listed in full.

Target: the huge range in under 5 s with memory no larger than the baseline's (the comparison, not a timed test); on a
loaded machine compare it with ``startup``, which bounds it from below.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from tactile_zoo.bench.parsing import MAX_CELLS

from .bench_wall import launch_measured
from .common import Context, write_csv

NAME = "grid_size"
TITLE = "Wall-clock and peak RSS of `tactile-zoo bench --seeds 0-100000000 --dry-run` (refused with the count)"
COLUMNS = ("command", "exit_code", "wall_s", "peak_rss_mb", "rss_source", "output_lines", "answer")
#: the issue's command, on the smallest simulated dataset
BASE = ("bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--quick", "--dry-run")
CASES = {"huge_seed_range": "0-100000000", "startup": None, "one_seed": "0", "max_cells": f"0-{MAX_CELLS - 1}"}


def _measure(args: list[str], tmp: Path) -> dict[str, object]:
    """Run ``tactile-zoo ARGS`` as a child process: exit code, wall seconds, peak RSS, and what it answered."""
    log = tmp / "log.txt"
    env = {**os.environ, "TACTILE_ZOO_CACHE": str(tmp / "cache")}
    code, wall, _, rss_kb, source = launch_measured(list(args), env, log, tmp / "vmhwm")
    lines = log.read_text().splitlines()
    answer = next((line for line in lines if line.startswith("tactile-zoo: error:")), lines[0] if lines else "")
    return {"exit_code": code, "wall_s": wall, "peak_rss_mb": rss_kb / 1024, "rss_source": source,
            "output_lines": len(lines), "answer": answer[:200]}


def run(ctx: Context, cases: tuple[str, ...] | None = None) -> Path:
    """Measure ``cases`` (default: all; ``--quick``: the huge range and the start-up) and write ``grid_size.csv``."""
    cases = cases or (("huge_seed_range", "startup") if ctx.quick else tuple(CASES))
    rows = []
    with tempfile.TemporaryDirectory(prefix="tz-grid-size-") as folder:
        tmp = Path(folder)
        for case in cases:
            seeds = CASES[case]
            args = ["--version"] if seeds is None else [*BASE, "--seeds", seeds, "--out", str(tmp / "out")]
            row = {"case": case, "command": "tactile-zoo " + " ".join(args).replace(str(tmp), "<tmp>"),
                   **_measure(args, tmp), "note": f"MAX_CELLS = {MAX_CELLS}"}
            ctx.log(f"  {case}: exit {row['exit_code']}, {row['wall_s']:.1f} s, peak RSS {row['peak_rss_mb']:.0f} MB, "
                    f"{row['output_lines']} line(s)")
            rows.append(row)
    return write_csv(ctx, NAME, COLUMNS, rows)


__all__ = ["run", "NAME", "TITLE", "CASES"]
