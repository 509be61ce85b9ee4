"""Importing tactile_zoo before torch gives torch's large CPU tensors transparent huge pages (tactile_zoo/__init__.py).

Each check runs in a fresh interpreter, since the setting only acts when tactile_zoo is imported before torch; it
counts the minor page faults of writing a fresh 64 MiB tensor: about 16384 with 4 KiB pages, a few dozen with 2 MiB
ones.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
THP = Path("/sys/kernel/mm/transparent_hugepage/enabled")

_FAULTS = """
import resource, sys
import tactile_zoo, torch
x = torch.empty(64 << 20, dtype=torch.uint8)  # 64 MiB: far over glibc's mmap threshold, so fresh pages
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
x.fill_(1)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(**env: str) -> int:
    full = {k: v for k, v in os.environ.items() if k != "THP_MEM_ALLOC_ENABLE"}  # unset unless given
    full.update(PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]), **env)
    out = subprocess.run([sys.executable, "-c", _FAULTS], env=full, capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not THP.exists() or "[never]" in THP.read_text(), reason="no transparent huge pages here")
def test_importing_tactile_zoo_first_gives_large_tensors_huge_pages() -> None:
    small_pages = _faults(THP_MEM_ALLOC_ENABLE="0")  # the opt-out: torch's default allocation
    assert small_pages > 8000  # 64 MiB in 4 KiB pages, so the count below means something here
    assert _faults() < small_pages / 20
