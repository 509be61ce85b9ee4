"""The import contracts in ``.importlinter`` hold, and they break on an upward import (so they can fail)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# import-linter is in the [test] extra: a missing tool fails here rather than skipping the contracts silently
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(cwd: Path) -> subprocess.CompletedProcess[str]:
    # lint-imports puts the working directory first on sys.path, so a copy of the package in cwd is the one analysed
    return subprocess.run([str(LINT), "--no-cache", "--config", str(cwd / ".importlinter")], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def test_contracts_hold_on_the_package() -> None:
    proc = _lint(REPO)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "6 kept, 0 broken" in proc.stdout


@pytest.mark.parametrize(("module", "line", "contract"), [
    ("nn/surrogate.py", "from tactile_zoo.data import spec as _spec  # noqa", "never import the data package"),
    ("models/_inputs.py", "from tactile_zoo.bench import grid as _grid  # noqa", "Models never import the harness"),
    ("engine/metrics.py", "from tactile_zoo.models import sgnet as _sgnet  # noqa", "No layer imports a model"),
    ("registry/lookup.py", "from tactile_zoo.engine import cell as _cell  # noqa", "Layers: cli -> bench"),
    # the weights layer sits on the engine: the engine never imports it, and it reaches models through the registry
    ("engine/evaluate.py", "from tactile_zoo.weights import entry as _entry  # noqa", "Layers: cli -> bench"),
    ("weights/heads.py", "from tactile_zoo.models import sgnet as _sgnet  # noqa", "No layer imports a model"),
    # the contract suite checks models through the registry, never a model module; the engine never imports it
    ("testing/models.py", "from tactile_zoo.models import sgnet as _sgnet  # noqa", "No layer imports a model"),
    ("engine/build.py", "from tactile_zoo.testing import check_model as _check  # noqa", "Layers: cli -> bench"),
    ("models/sgnet.py", "from tactile_zoo.testing import tiny_spec as _t  # noqa", "Models never import the harness"),
    # the scripts on top: the package never reaches up to them, and the suite never imports the tools
    ("bench/report.py", "import benchmarks.common as _common  # noqa", "never imports the performance suite"),
    ("../benchmarks/lif.py", "import tools.fidelity as _fidelity  # noqa", "never imports the tools"),
])
def test_an_upward_import_breaks_a_contract(tmp_path: Path, module: str, line: str, contract: str) -> None:
    for package in ("tactile_zoo", "benchmarks", "tools"):
        shutil.copytree(REPO / package, tmp_path / package,
                        ignore=shutil.ignore_patterns("__pycache__", "results"))
    shutil.copy(REPO / ".importlinter", tmp_path / ".importlinter")
    target = tmp_path / "tactile_zoo" / module
    target.write_text(target.read_text() + f"\n{line}\n")
    proc = _lint(tmp_path)
    assert proc.returncode != 0, proc.stdout
    broken = [row for row in proc.stdout.splitlines() if row.endswith("BROKEN")]
    assert any(contract in row for row in broken) or contract in proc.stdout.split("Broken contracts")[-1], \
        proc.stdout
