"""benchmarks.dcnn_memory: each case in a fresh child, the tuned malloc beside glibc's defaults, the same logits."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import common, dcnn_memory  # noqa: E402
from tactile_zoo.engine.malloc import SETTINGS, apply_mallopt  # noqa: E402


def test_tuned_malloc_row_computes_the_same_logits(tmp_path: Path) -> None:
    ctx = common.Context(threads=1, quick=True, repeats=1, out=tmp_path, log=lambda _msg: None)
    with dcnn_memory.run(ctx, samples=8, test_samples=8).open() as fh:  # the logits of 8 test samples compared
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["benchmark", "case", *dcnn_memory.COLUMNS, "note", *common.ENV_COLUMNS]
    assert [r["case"] for r in rows] == ["index_only", "maxpool2d", "index_only_tuned"]
    assert rows[0]["malloc"] == rows[1]["malloc"] == "default"
    tuned = " ".join(f"{name}={value}" for name, value in SETTINGS.items())
    glibc = apply_mallopt({}) is not None  # an empty call changes nothing: it only says whether mallopt exists
    assert rows[2]["malloc"] == (tuned if glibc else "default (not glibc)")
    for row in rows:  # allocation never changes arithmetic: the tuned child's test logits are the default's
        assert float(row["max_logit_diff"]) == 0.0, row
        assert int(row["train_page_faults"]) > 0 and float(row["train_sys_s"]) >= 0
        assert float(row["peak_rss_mb"]) > 0 and row["samples"] == "8"
