"""Issue 49 item 11: a processed-data cache that cannot be written for lack of room (a full disk, a file size limit)
is one warning naming the cache file; the data still load, and no partial file is left behind."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]

LOAD = """
import resource, sys, warnings
from pathlib import Path
from tactile_zoo.data.datasets import RecordingsDataset
resource.setrlimit(resource.RLIMIT_FSIZE, (600, 600))  # room for nothing but tiny files
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    ds = RecordingsDataset(root=Path(sys.argv[1]), folder="grasps", sensor="optoforce3", num_channels=1)
print(len(ds.y))
for w in caught:
    print("WARNING", w.message)
"""


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit on this platform")
def test_a_cache_on_a_full_disk_is_one_warning_and_the_data_still_load(tmp_path: Path) -> None:
    sys.path.insert(0, str(TESTS))
    import tiny_zoo

    tiny_zoo.write_recordings(tmp_path / "home")
    cache = tmp_path / "cache"
    env = {**os.environ, "TACTILE_ZOO_CACHE": str(cache), "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, "-c", LOAD, str(tmp_path / "home")], capture_output=True, text=True,
                          env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "4" and len(lines) == 2, done.stdout  # every recording loaded, one warning
    assert lines[1].startswith("WARNING grasps: could not write the processed cache ")
    assert "(the disk is full or a file size limit was hit); continuing without it" in lines[1]
    assert "Traceback" not in done.stderr
    assert [p for p in cache.rglob("*") if p.is_file()] == []  # no torn temporary left
