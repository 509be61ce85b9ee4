"""The build's one step beyond pyproject.toml: the published sets are package data built from committed cells.

``tactile_zoo/published/*.json.gz`` (what ``tactile-zoo study compare`` reads offline) is derived from the cell files
under ``benchmarks/results``, so it is not committed: results live in one place. ``make install`` writes it into a
checkout (``python -m tools.published_set``, 10 s). A wheel or sdist built from a checkout must carry it, so this
hook refuses to build one without it, rather than ship a package whose ``study compare`` finds no baseline. From an
unpacked sdist the set is already there (the sdist carries it), and an editable install reads the checkout's folder,
so neither needs the hook.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = Path(__file__).resolve().parent
SETS = ("table1-v1.json.gz",)  # tools/published_set.py's sets, newest last


def ensure_published_sets() -> None:
    """Write the missing sets from the checkout's cells, or stop the build naming the file and the command."""
    missing = [name for name in SETS if not (HERE / "tactile_zoo" / "published" / name).is_file()]
    if not missing:
        return
    if not (HERE / "tools" / "published_set.py").is_file():
        raise SystemExit(f"tactile_zoo/published/{missing[0]} is missing from this source tree, and it has no "
                         "tools/published_set.py to build it from: build from a git checkout or the released sdist")
    # the builder imports tactile_zoo (torch included): it runs in this interpreter only when the build is not
    # isolated from the environment the package is installed in (`python -m build --no-isolation`, `make wheel-check`)
    done = subprocess.run([sys.executable, "-m", "tools.published_set"], cwd=HERE, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise SystemExit(f"tactile_zoo/published/{missing[0]} is missing and could not be built here ({tail}): run "
                         "`make install` (or `python -m tools.published_set` where tactile-zoo's dependencies are "
                         "installed), then build again")


class BuildPy(build_py):
    def run(self) -> None:
        if not getattr(self, "editable_mode", False):
            ensure_published_sets()
        super().run()


class Sdist(sdist):
    def run(self) -> None:
        ensure_published_sets()
        super().run()


if __name__ == "__main__":  # setuptools' build backend runs this file as __main__; a test imports it
    setup(cmdclass={"build_py": BuildPy, "sdist": Sdist})
