"""benchmarks.multibarrel_cost: a cell's CPU-hours are the registered epochs times the last measured epoch, each
epoch's CPU seconds are the child's between two epochs' ends; without Ev-Objects it skips, saying why. The child
(minutes of training, 11-12 GB) is not run here: its answer is given, as the real child prints it."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, common, multibarrel_cost  # noqa: E402


def test_the_cell_costs_its_epochs_times_the_last_measured_epoch(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "data" / "ev_objects" / "raw").mkdir(parents=True)
    (tmp_path / "data" / "ev_objects" / "raw" / "Ev-Objects.zip").touch()
    answer = {"epochs": [{"epoch": 1, "wall_s": 120.0, "cpu_s": 90.0}, {"epoch": 2, "wall_s": 80.0, "cpu_s": 72.0}],
              "max_epochs": 200, "batch_size": 600, "micro_batch_size": 120, "n_train": 468, "n_val": 108,
              "peak_rss_mb": 11800.0, "cpu_capability": "AVX2"}
    asked: list[Any] = []
    real = subprocess.run

    def child(argv: list[str], **kwargs: Any) -> subprocess.CompletedProcess:
        if "benchmarks.multibarrel_cost" not in argv:  # the CSV's environment columns (git, the CPU) run for real
            return real(argv, **kwargs)
        asked.append(json.loads(argv[-1]))
        assert argv[1:4] == ["-m", "benchmarks.multibarrel_cost", "--child"] and kwargs["env"]["OMP_NUM_THREADS"] == "1"
        return subprocess.CompletedProcess(argv, 0, "a log line\n" + json.dumps(answer) + "\n", "")

    monkeypatch.setattr(multibarrel_cost.subprocess, "run", child)
    ctx = common.Context(threads=1, out=tmp_path, root=tmp_path / "data", log=lambda _msg: None)
    with multibarrel_cost.run(ctx).open() as fh:
        rows = list(csv.DictReader(fh))
    assert asked == [{"root": str(tmp_path / "data"), "epochs": 2, "revision": 1}]  # the registered revision
    assert [(r["case"], r["epoch"], r["cpu_s"]) for r in rows] == [("epoch", "1", "90.0"), ("epoch", "2", "72.0"),
                                                                  ("cell", "2", "72.0")]
    assert float(rows[-1]["cpu_hours"]) == 4.0 and rows[-1]["peak_rss_mb"] == "11800.0"  # 72 s x 200 epochs
    assert {r["cpu_capability"] for r in rows} == {"AVX2"}  # the child's, where the epochs ran
    assert BENCHMARKS["multibarrel_cost"] == "multibarrel_cost"


def test_without_ev_objects_it_skips_naming_what_it_needs(tmp_path: Path) -> None:
    ctx = common.Context(threads=1, out=tmp_path, root=tmp_path, log=lambda _msg: None)
    with pytest.raises(common.BenchmarkSkipped, match="needs Ev-Objects"):
        multibarrel_cost.run(ctx)
    assert not list(tmp_path.iterdir())


def test_revisions_run_side_by_side_in_alternating_rounds_and_each_cell_is_a_median(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "data" / "ev_objects" / "raw").mkdir(parents=True)
    (tmp_path / "data" / "ev_objects" / "raw" / "Ev-Objects.zip").touch()
    last = {1: iter([80.0, 90.0, 70.0]), 2: iter([60.0, 50.0, 66.0])}  # each revision's last epoch, round by round
    asked: list[int] = []
    real = subprocess.run

    def child(argv: list[str], **kwargs: Any) -> subprocess.CompletedProcess:
        if "benchmarks.multibarrel_cost" not in argv:
            return real(argv, **kwargs)
        revision = json.loads(argv[-1])["revision"]
        asked.append(revision)
        answer = {"epochs": [{"epoch": 1, "wall_s": 1.0, "cpu_s": 100.0},
                             {"epoch": 2, "wall_s": 1.0, "cpu_s": next(last[revision])}],
                  "max_epochs": 200, "batch_size": 600, "micro_batch_size": 120, "n_train": 468, "n_val": 108,
                  "peak_rss_mb": 10000.0 + 1000 * revision, "cpu_capability": "AVX2"}
        return subprocess.CompletedProcess(argv, 0, json.dumps(answer) + "\n", "")

    monkeypatch.setattr(multibarrel_cost.subprocess, "run", child)
    ctx = common.Context(threads=1, out=tmp_path, root=tmp_path / "data", log=lambda _msg: None)
    with multibarrel_cost.run(ctx, revisions=[1, 2], rounds=3).open() as fh:
        rows = list(csv.DictReader(fh))
    assert asked == [1, 2, 2, 1, 1, 2]
    cells = {r["revision"]: r for r in rows if r["case"] == "cell"}
    assert float(cells["1"]["cpu_s"]) == 80.0 and float(cells["2"]["cpu_s"]) == 60.0  # medians, not the last round
    assert float(cells["2"]["cpu_hours"]) == pytest.approx(60.0 * 200 / 3600, abs=1e-3)
    assert cells["2"]["peak_rss_mb"] == "12000.0"
    assert [r["round"] for r in rows if r["case"] == "epoch" and r["revision"] == "1"] == ["0", "0", "1", "1", "2", "2"]


def test_the_child_trains_with_the_bench_workers_malloc_settings_at_the_asked_revision(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A cell's cost is that of a bench worker, which tunes malloc before anything trains (page faults cost this
    model about 1.4x under glibc's defaults); the revision's compute keywords reach the model."""
    import tactile_zoo as tz
    from tactile_zoo.engine import malloc
    from tactile_zoo.registry import lookup

    order: list[str] = []
    fitted: dict[str, Any] = {}
    monkeypatch.setattr(malloc, "tune_malloc", lambda: order.append("malloc"))
    monkeypatch.setattr(lookup, "load_dataset", lambda name, **kw: order.append(f"load {kw['split']}") or kw["split"])

    class Result:
        recipe = type("R", (), {"batch_size": 600, "micro_batch_size": 120})()
        n_train, n_val = 468, 108

    def fit(model: str, train: Any, **kwargs: Any) -> Result:
        order.append("fit")
        fitted.update(kwargs)
        kwargs["callback"]({"epoch": 1, "seconds": 1.0})
        return Result()

    monkeypatch.setattr(tz, "fit", fit)
    out = multibarrel_cost._child("ROOT", 1, 2)
    assert order == ["malloc", "load train", "load val", "fit"]
    assert fitted["hparams"] == {"alif_backend": "compiled"} and fitted["epochs"] == 1
    assert out["epochs"][0]["epoch"] == 1 and out["n_train"] == 468
    assert out["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
