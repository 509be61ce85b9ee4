"""A successful export is quiet: onnxruntime, which runs the check of every ONNX file, logs errors only.
The multi-barrel SNN's graph made its optimiser print "[W:onnxruntime:...] Could not find a CPU kernel and hence
can't constant fold CastLike node" lines straight to stderr (from C++, past Python's streams), though the docs
promise no warnings on success (issue 49, item 15)."""

from __future__ import annotations

from pathlib import Path

import pytest
from export_cases import child_export

from tactile_zoo.export import onnx_available, onnxruntime_available


@pytest.mark.slow
@pytest.mark.xdist_group("export_multibarrel")  # the worker that exports it for tests/weights/test_export.py
@pytest.mark.skipif(not (onnx_available() and onnxruntime_available()),
                    reason='needs onnx, onnxscript and onnxruntime: pip install "tactile-zoo[export]"')
def test_the_multibarrel_onnx_export_prints_nothing(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The multi-barrel SNN as tests/weights/test_export.py exports it (small, two steps of its columns: 12 of these
    warnings from the check's session when it logs warnings too), to TorchScript and ONNX, in a child process with
    a bare environment and stdout and stderr of its own (export_cases.child_export): the export whose files
    test_export.py then checks (one export for both, per worker)."""
    proc, out = child_export("multibarrel", ("torchscript", "onnx"), tmp_path_factory.mktemp("multibarrel_child"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "exported\n"
    assert "onnxruntime" not in proc.stderr and "CastLike" not in proc.stderr
    assert proc.stderr == ""
    assert Path(out, "multibarrel.forward.onnx").is_file()
