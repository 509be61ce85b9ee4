"""benchmarks/export_latency.py runs small: one row per runtime with the declared columns, and the exported steps
give the eager scores (no timings are asserted)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, common, export_latency  # noqa: E402
from tactile_zoo.export import onnx_available, onnxruntime_available  # noqa: E402


def test_export_latency_writes_one_row_per_runtime(tmp_path: Path) -> None:
    ctx = common.Context(threads=1, quick=True, repeats=1, out=tmp_path, log=lambda _msg: None)
    path = export_latency.run(ctx, models=["cnn_lstm"], steps=6)
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["benchmark", "case", *export_latency.COLUMNS, "note", *common.ENV_COLUMNS]
    runtimes = ["eager", "torchscript"] + (["onnxruntime"] if onnx_available() and onnxruntime_available() else [])
    assert [r["runtime"] for r in rows] == runtimes
    for row in rows:
        assert row["model"] == "cnn_lstm" and row["steps"] == "6" and row["threads"] == "1"
        assert float(row["median_ms"]) > 0 and float(row["max_abs_diff"]) <= 1e-5
        assert "load average" in row["note"]
    assert BENCHMARKS["export_latency"] == "export_latency"
