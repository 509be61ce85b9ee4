"""``export`` under faults, with real processes (issue 49, items 11 and 12): a full disk, SIGTERM, SIGKILL, and two
exports into one folder at once.

The exports in child processes export ``gated``, a tiny model (below) whose forward waits for a gate file: the
staging folder exists while it waits, so a test can signal the export, or start a second one, at that point and
nowhere else. Every child is bounded by a timeout and killed in ``finally``. The other exports are D-CNN's forward in
TorchScript: a real model's file of half a megabyte, without the graph library's import (2 s in every child) or a
step to trace; which model it is does not matter to the folder.

The children are ``tactile-zoo export`` command lines forked from the warm server of tests/forked_bench.py (torch
and the package imported once per test process; a fresh interpreter spent 3-4 CPU seconds importing them, six
times): processes of their own, with a new interpreter's signal dispositions, so SIGTERM and SIGKILL end them as
they end ``python -m tactile_zoo.cli``, their stdout and stderr in files, the file size limit set before ``main``.
"""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

import pytest
from forked_bench import ForkedBench, fork_python

from tactile_zoo.cli import main
from tactile_zoo.export.folder import MARKER

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals, flock and RLIMIT_FSIZE")

DCNN = ["export", "dcnn", "--spec-from", "sim_biotac_slip", "--steps", "4", "--format", "torchscript"]
#: a tiny model whose forward waits (at most 120 s) until the file $GATE exists, when $GATE is set
GATED = '''
import os, time
import torch
from torch import nn
import tactile_zoo as tz


@tz.register_model("gated", tags=["test"], causal=False, streaming=False)
class Gated(nn.Module):
    def __init__(self, spec):
        super().__init__()
        self.head = nn.Linear(spec.num_nodes * spec.num_channels, spec.num_classes)

    def forward(self, x, g=None):
        gate, deadline = os.environ.get("GATE"), time.time() + 120
        while gate and not os.path.exists(gate) and time.time() < deadline:
            time.sleep(0.05)
        return self.head(x.mean(1).flatten(1))
'''
TIMEOUT = 240  # seconds any child may take: imports on a loaded two-core machine take 10-20 s


#: ``tactile-zoo ARGV[1:]`` as ``python -m tactile_zoo.cli`` runs it, with ARGV[0] first on the module path (where
#: gated_model.py is); with ``TZ_TEST_FSIZE`` set, under that file size limit, which fails a write as a full disk
#: does (EFBIG: the child inherits the server interpreter's SIGXFSZ ignored, as every new interpreter sets it)
_CLI = """import os, resource, sys
sys.stderr.reconfigure(line_buffering=True)  # as a new interpreter's stderr is: a line is seen when it is said
sys.path.insert(0, sys.argv[1])
if os.environ.get("TZ_TEST_FSIZE"):
    sys.dont_write_bytecode = True  # no cached module past the limit either
    limit = int(os.environ["TZ_TEST_FSIZE"])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from tactile_zoo.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _cli(tmp_path: Path, argv: list[str], log: str, **env: str) -> ForkedBench:
    """``tactile-zoo ARGV`` in a child forked from the warm server, its stdout and stderr in ``tmp_path/log.*``."""
    return fork_python(_CLI, [str(tmp_path), *argv], tmp_path / log, **{"GATE": "", "TZ_TEST_FSIZE": "", **env})


def _export(tmp_path: Path, out: Path, gate: Path | None, log: str = "gated") -> ForkedBench:
    (tmp_path / "gated_model.py").write_text(GATED)
    argv = ["export", "gated", "--plugin-module", "gated_model", "--spec-from", "sim_biotac_slip", "--steps", "4",
            "--format", "torchscript", "--out", str(out)]
    return _cli(tmp_path, argv, log, **({} if gate is None else {"GATE": str(gate)}))


def _staging(out: Path) -> list[Path]:
    return sorted(out.glob(".tactile-zoo-export.*.tmp")) if out.is_dir() else []


def _wait_for_staging(proc: ForkedBench, out: Path) -> Path:
    deadline = time.time() + TIMEOUT
    while time.time() < deadline:
        found = _staging(out)
        if found:
            return found[0]
        if proc.poll() is not None:
            pytest.fail(f"the export ended before it staged anything: {proc.communicate()}")
        time.sleep(0.05)
    pytest.fail("no staging folder appeared")


def _finish(proc: ForkedBench) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=TIMEOUT)
    finally:
        proc.kill()
        proc.wait(timeout=30)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_sigterm_removes_the_staging_folder(tmp_path: Path) -> None:
    """SIGTERM left ``.tactile-zoo-export.*.tmp`` behind, and a later export did not remove it."""
    out = tmp_path / "robot"
    assert main([*DCNN, "--out", str(out)]) == 0
    before = _snapshot(out)
    proc = _export(tmp_path, out, tmp_path / "never")
    try:
        _wait_for_staging(proc, out)
        proc.send_signal(signal.SIGTERM)
    finally:
        _, err = _finish(proc)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == f"tactile-zoo: error: terminated (SIGTERM); the export stopped and left " \
                                           f"{out} as it was"
    assert _snapshot(out) == before and not _staging(out)


def test_a_killed_exports_staging_is_removed_by_the_next_export(tmp_path: Path) -> None:
    out = tmp_path / "robot"
    proc = _export(tmp_path, out, tmp_path / "never")
    try:
        stale = _wait_for_staging(proc, out)
        proc.send_signal(signal.SIGKILL)  # no cleanup at all: what a power cut leaves
    finally:
        _finish(proc)
    assert stale.is_dir()
    assert main([*DCNN, "--out", str(out)]) == 0
    assert not _staging(out)
    assert {p.name for p in out.iterdir()} == {MARKER, "dcnn.forward.pt", "dcnn.export.json"}


def test_two_exports_into_one_folder_take_turns(tmp_path: Path) -> None:
    """Two exports at once raced on the folder's marker. Now the second waits for the first (and leaves its staging
    folder alone: it is a live export's, not a stale one), then both sets are in the folder and the marker."""
    out, gate = tmp_path / "robot", tmp_path / "open"
    first = _export(tmp_path, out, gate)
    second = None
    try:
        staging = _wait_for_staging(first, out)
        second = _cli(tmp_path, [*DCNN, "--out", str(out)], "second")
        seen, err, deadline = [], second.log.with_suffix(".err"), time.time() + TIMEOUT
        while time.time() < deadline and second.poll() is None:  # it says it waits, and then does (the first
            seen = err.read_text().splitlines() if err.exists() else []  # still holds the folder)
            if any("waiting for it to finish" in line for line in seen):
                break
            time.sleep(0.05)
        assert seen and seen[-1].strip() == f"another tactile-zoo export is writing into {out}; waiting for it to " \
                                            f"finish", seen
        time.sleep(1.0)
        assert staging.is_dir() and second.poll() is None  # the live export's staging is not "stale"
        gate.touch()
        outputs = [_finish(first), _finish(second)]
    finally:
        for proc in (first, second):
            if proc is not None:
                proc.kill()
                proc.wait(timeout=30)
    assert [first.returncode, second.returncode] == [0, 0], outputs
    marker = json.loads((out / MARKER).read_text())["exports"]
    assert sorted(marker) == ["dcnn", "gated"] and not _staging(out)
    assert {p.name for p in out.iterdir()} == {MARKER, *(f for files in marker.values() for f in files)}


@pytest.mark.parametrize("existing", [False, True])
def test_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path, existing: bool) -> None:
    """A full disk (here a file size limit, which fails a write the same way) aborted the process from C++ (exit
    134: torch writing straight to the file) and left the staging folder."""
    out = tmp_path / "robot"
    if existing:
        assert main([*DCNN, "--out", str(out)]) == 0
    before = _snapshot(out) if existing else None

    proc = _cli(tmp_path, [*DCNN, "--out", str(out)], "full", TZ_TEST_FSIZE="4096")
    _, err = _finish(proc)
    assert proc.returncode == 2, err
    errors = [line for line in err.splitlines() if line.startswith("tactile-zoo: error:")]
    assert errors == [f"tactile-zoo: error: cannot write dcnn.forward.pt into {out}: File too large; the export "
                      f"stopped and left the folder as it was"], err
    assert "Traceback" not in err and "terminate called" not in err
    if existing:
        assert _snapshot(out) == before
    else:
        assert not out.exists()
