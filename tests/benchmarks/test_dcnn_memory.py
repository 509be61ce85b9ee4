"""benchmarks.dcnn_memory: each case in a fresh child, the tuned malloc beside glibc's defaults, the same logits.

The three children are forked from the warm server of tests/forked_bench.py (it imported torch and the package once
per test process, and never tunes malloc: each child starts with glibc's defaults and a heap of its own, as a new
interpreter does) instead of spawned as ``python -m benchmarks.dcnn_memory --child JOB``: an interpreter's start-up
(torch, the package, torch._dynamo for the first Adam) was about 4 of each child's 5 CPU seconds. The child runs the
same entry point, ``main(["--child", JOB])``.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any

import pytest
from forked_bench import run_python

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import common, dcnn_memory  # noqa: E402
from tactile_zoo.engine.malloc import SETTINGS, apply_mallopt  # noqa: E402

# what ``python -m benchmarks.dcnn_memory ARGV`` runs, in a child forked from the warm server
_CHILD = f"import sys; sys.path.insert(0, {str(REPO)!r}); from benchmarks.dcnn_memory import main; " \
    "sys.exit(main(sys.argv[1:]))"


def test_tuned_malloc_row_computes_the_same_logits(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cases: list[str] = []

    def forked(job: dict[str, Any], variant: str, malloc: str | dict[str, int] | None, env: dict[str, str]
               ) -> dict[str, Any]:
        cases.append(f"{variant}-{malloc}")
        out, _ = run_python(_CHILD, ["--child", json.dumps({**job, "variant": variant, "malloc": malloc})],
                            tmp_path / cases[-1])
        return json.loads(out.strip().splitlines()[-1])

    monkeypatch.setattr(dcnn_memory, "child", forked)
    ctx = common.Context(threads=1, quick=True, repeats=1, out=tmp_path, log=lambda _msg: None)
    with dcnn_memory.run(ctx, samples=8, test_samples=8).open() as fh:  # the logits of 8 test samples compared
        rows = list(csv.DictReader(fh))
    assert cases == ["index_only-None", "maxpool2d-None", "index_only-tuned"]  # one child each
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
