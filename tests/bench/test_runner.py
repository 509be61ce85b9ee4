from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import pytest
import torch
from conftest import SMALL, read_board, run_cli

from tactile_zoo.bench import executors, rundir
from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.runner import run_bench

#: these tests share the session's reference run: one xdist worker computes it once
pytestmark = pytest.mark.xdist_group("tiny_bench")


def _copy(reference_run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    return out


def _mtimes(out: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}


def test_a_run_writes_every_output_and_cell_records_hold_everything(reference_run: Path) -> None:
    out = reference_run
    for name in ("leaderboard.csv", "summary.csv", "report.md", "run.json", "plots/heatmap.png",
                 "plots/early_tiny_blobs.png", "plots/bars_tiny_kfold.png", "plots/curves_tiny_blobs.png",
                 "plots/confusion/tiny_blobs__tiny_rate.png"):
        assert (out / name).is_file(), name
    cells = [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))]
    assert len(cells) == 6 and all(c["status"] == "ok" for c in cells)
    cell = next(c for c in cells if c["model"] == "tiny_rate" and c["dataset"] == "tiny_blobs")
    assert set(cell["predictions"]) == {"test", "test_shifted"}
    probs = cell["predictions"]["test"]["probabilities"]
    assert len(probs) == cell["n_test"] and all(abs(sum(p) - 1) < 1e-5 for p in probs)
    assert all(v == round(v, 6) for row in probs for v in row)  # stored to 6 decimals
    # an extra test split keeps what a per-set accuracy needs, not a second copy of the probabilities
    assert set(cell["predictions"]["test_shifted"]) == {"targets", "predictions"}
    assert cell["metrics"]["test"]["accuracy"] == pytest.approx(
        sum(p == t for p, t in zip(cell["predictions"]["test"]["predictions"], cell["predictions"]["test"]["targets"]))
        / cell["n_test"])
    assert cell["config"]["recipe"]["loss"] == "mse_rate" and cell["config"]["dataset"] == "tiny_blobs"
    # the CPU's kernel level and vector flags: the same seed can round differently on another CPU type
    assert cell["cpu_isa"]["capability"] == torch.backends.cpu.get_cpu_capability()
    assert isinstance(cell["cpu_isa"]["flags"], list)
    assert cell["prefix"]["causal"] is True and cell["prefix"]["input"] == "causal"
    mlp = next(c for c in cells if c["model"] == "tiny_mlp")
    assert mlp["prefix"]["causal"] is False and mlp["prefix"]["input"] == "truncated"
    assert len(cell["curve"]) == cell["epochs_run"] and 1 <= cell["best_epoch"] <= cell["epochs_run"]
    assert cell["infer_ms_per_sample"] > 0 and cell["params"] > 0 and cell["peak_memory_mb"] > 0
    assert cell["versions"]["torch"] and cell["device"] == "cpu"
    from tactile_zoo.bench.environment import git_commit

    assert cell["commit"] == git_commit()  # the checkout's commit (with +dirty for uncommitted changes)
    assert cell["test_reads"] == 1
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "finished" and run["environment"]["cpu_cores"] >= 1
    assert len(run["grid"]["cells"]) == 6 and run["environment"]["versions"]["tactile_zoo"]
    board = read_board(out, drop_timing=False)
    assert len(board) == 6 and {r["status"] for r in board} == {"ok"}
    assert {"accuracy_test_shifted", "accuracy_at_10", "accuracy_at_100", "earliness"} <= set(board[0])


def test_rerun_resumes_without_recomputing(reference_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture
                                           ) -> None:
    out = _copy(reference_run, tmp_path)
    before = _mtimes(out)
    assert run_cli([*SMALL, "--out", str(out)]) == 0
    assert "6 already finished, 0 to run" in capsys.readouterr().out
    assert _mtimes(out) == before
    assert read_board(out, drop_timing=False) == read_board(reference_run, drop_timing=False)


def test_same_command_same_numbers(reference_run: Path, tmp_path: Path) -> None:
    assert run_cli([*SMALL, "--out", str(tmp_path / "again"), "-q"]) == 0
    assert read_board(tmp_path / "again") == read_board(reference_run)


def test_a_changed_hyper_parameter_gives_new_cells(reference_run: Path, tmp_path: Path) -> None:
    out = _copy(reference_run, tmp_path)
    cfg = BenchConfig(models=["tiny_mlp", "tiny_rate"], datasets=["tiny_blobs", "tiny_kfold"], folds=2, threads=1,
                      out=str(out), model_overrides={"tiny_mlp": {"hparams": {"hidden": 8}}})
    outcome = run_bench(cfg, quiet=True, plots=False)  # the plots cost seconds and are not what is checked here
    assert outcome.exit_code == 0
    assert sorted({c.split("__")[0] for c in outcome.ran}) == ["tiny_mlp"] and len(outcome.ran) == 3
    assert len(outcome.reused) == 3 and all(c.startswith("tiny_rate") for c in outcome.reused)
    assert len(list((out / "cells").glob("*.json"))) == 9  # the old tiny_mlp cells stay, unused
    board = read_board(out)
    assert len(board) == 6  # the leaderboard is this run's grid only
    assert "3 cell file(s) in the folder belong to another configuration" in (out / "report.md").read_text()


def test_failures_are_isolated_and_retried(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    args = ["--models", "tiny_mlp,tiny_broken,tiny_nan,tiny_oom", "--datasets", "tiny_blobs", "--out",
            str(tmp_path / "run"), "--threads", "1"]
    assert run_cli(args) == 1
    text = capsys.readouterr().out
    assert "1 ok, 3 failed" in text
    board = {r["model"]: r for r in read_board(tmp_path / "run")}
    assert board["tiny_mlp"]["status"] == "ok" and float(board["tiny_mlp"]["accuracy"]) > 0.5
    assert "exploded on purpose" in board["tiny_broken"]["error"]
    assert "became nan" in board["tiny_nan"]["error"]
    assert "out of memory" in board["tiny_oom"]["error"]
    cfg = BenchConfig(models=["tiny_mlp", "tiny_broken", "tiny_nan", "tiny_oom"], datasets=["tiny_blobs"],
                      out=str(tmp_path / "run"), threads=1)
    again = run_bench(cfg, quiet=True, plots=False)  # the same plots as the first run's: drawn once
    assert again.exit_code == 1 and len(again.ran) == 3 and len(again.reused) == 1  # failed cells are retried


def test_a_model_that_refuses_a_dataset_is_skipped(tmp_path: Path) -> None:
    assert run_cli(["--models", "tiny_picky", "--datasets", "tiny_kfold", "--folds", "1", "--out",
                    str(tmp_path / "run")]) == 0
    (row,) = read_board(tmp_path / "run")
    assert row["status"] == "skipped" and "needs global features" in row["error"]


def test_a_failing_write_keeps_earlier_cells_and_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    real = rundir.RunDir.write_cell
    calls = []

    def flaky(self: rundir.RunDir, record: dict) -> Path:
        calls.append(record["cell_id"])
        if len(calls) == 2:
            raise rundir.CellWriteError(28, f"cannot write cell file {record['cell_id']}: No space left on device")
        return real(self, record)

    monkeypatch.setattr(rundir.RunDir, "write_cell", flaky)
    assert run_cli([*SMALL, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and "intact" in err
    files = list((out / "cells").glob("*.json"))
    assert len(files) == 1 and json.loads(files[0].read_text())["status"] == "ok"
    assert len(read_board(out)) == 1
    monkeypatch.setattr(rundir.RunDir, "write_cell", real)
    assert run_cli([*SMALL, "--out", str(out), "-q"]) == 0
    assert len(read_board(out)) == 6


def test_ctrl_c_stops_cleanly_and_the_rerun_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    real = executors.run_cell
    calls = []

    def interrupted(task: object, progress: bool = False) -> dict:
        calls.append(task)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(task, progress)

    monkeypatch.setattr(executors, "run_cell", interrupted)
    assert run_cli([*SMALL, "--out", str(out)]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert len(list((out / "cells").glob("*.json"))) == 2 and len(read_board(out)) == 2
    assert not list((out / "claims").iterdir())  # every claim released
    assert json.loads((out / "run.json").read_text())["status"] == "interrupted"
    monkeypatch.setattr(executors, "run_cell", real)
    outcome = run_bench(BenchConfig(models=["tiny_mlp", "tiny_rate"], datasets=["tiny_blobs", "tiny_kfold"], folds=2,
                                    threads=1, out=str(out)), quiet=True, plots=False)  # plots: seconds, unchecked
    assert outcome.exit_code == 0 and len(outcome.reused) == 2 and len(outcome.ran) == 4


def test_quick_and_refit(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--quick", "--refit", "--dataset-arg",
                    "n_train=40", "--out", str(out), "-q"]) == 0
    (cell,) = [json.loads(p.read_text()) for p in (out / "cells").glob("*.json")]
    assert cell["n_train"] == 64 and cell["n_val"] <= 32 and cell["n_test"] <= 64
    assert cell["epochs_run"] <= 2 and cell["config"]["refit"] is True
    assert len(cell["refit_curve"]) == cell["best_epoch"]


def test_a_cell_record_keeps_the_recording_of_each_window_when_windows_share_one() -> None:
    from tactile_zoo.bench.worker import _eval_dict
    from tactile_zoo.engine.evaluate import EvalResult

    result = EvalResult({"accuracy": 0.5}, [0, 1], [[0.1234567, 0.8765433], [0.5, 0.5]], [0, 0])
    windows = _eval_dict(result, [7, 7], probabilities=True)
    assert windows["groups"] == [7, 7] and windows["probabilities"][0] == [0.123457, 0.876543]
    assert "groups" not in _eval_dict(result, [3, 9], probabilities=False)  # each sample its own unit: implicit
    assert "probabilities" not in _eval_dict(result, None, probabilities=False)


def test_a_large_test_split_keeps_predictions_but_not_probabilities(monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo.bench import worker
    from tactile_zoo.engine.evaluate import EvalResult

    monkeypatch.setattr(worker, "MAX_PROBABILITY_ROWS", 2)
    small = EvalResult({"accuracy": 1.0}, [0, 1], [[0.9, 0.1], [0.2, 0.8]], [0, 1])
    large = EvalResult({"accuracy": 1.0}, [0, 1, 1], [[0.9, 0.1], [0.2, 0.8], [0.3, 0.7]], [0, 1, 1])
    assert worker._eval_dict(small, None, probabilities=True)["probabilities"] == [[0.9, 0.1], [0.2, 0.8]]
    out = worker._eval_dict(large, [4, 4, 5], probabilities=True)
    assert "probabilities" not in out and out["predictions"] == [0, 1, 1] and out["groups"] == [4, 4, 5]


def test_a_too_large_main_split_leaves_its_probabilities_to_its_subsets(monkeypatch: pytest.MonkeyPatch) -> None:
    # BioTac-DoS: the whole test split is too large, its unseen sets are not; a seed ensemble on textures needs theirs
    from types import SimpleNamespace

    from tactile_zoo.bench import worker
    from tactile_zoo.engine.evaluate import EvalResult

    monkeypatch.setattr(worker, "MAX_PROBABILITY_ROWS", 2)
    whole = EvalResult({"accuracy": 1.0}, [0, 1, 1], [[0.9, 0.1], [0.2, 0.8], [0.3, 0.7]], [0, 1, 1])
    part = EvalResult({"accuracy": 1.0}, [0, 1], [[0.9, 0.1], [0.2, 0.8]], [0, 1])
    stored = worker._predictions(SimpleNamespace(tests={"test": whole, "test_a": part}, test_groups={}))
    assert "probabilities" not in stored["test"] and stored["test_a"]["probabilities"] == [[0.9, 0.1], [0.2, 0.8]]
    # a main split small enough keeps the only copy
    stored = worker._predictions(SimpleNamespace(tests={"test": part, "test_a": part}, test_groups={}))
    assert "probabilities" in stored["test"] and "probabilities" not in stored["test_a"]


def test_a_cell_claimed_elsewhere_waits_until_the_rest_is_done_then_is_taken_over(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """The first cell's claim is held by "another process" when the runner first looks (the non-blocking claim
    fails): the runner runs the other cell first, then says it waits, takes the claim (the holder stopped without
    writing a record) and runs the deferred cell itself; every claim is released."""
    cfg = BenchConfig(models=["tiny_mlp", "tiny_rate"], datasets=["tiny_blobs"], threads=1, out=str(tmp_path / "run"))
    first, second = (c.cell_id for c in run_bench(cfg, dry_run=True, out=io.StringIO()).grid.cells)
    real = rundir.RunDir.claim
    asked: list[tuple[str, bool]] = []

    def held_once(self: rundir.RunDir, cell_id: str, blocking: bool = False) -> rundir.Claim | None:
        asked.append((cell_id, blocking))
        if cell_id == first and not blocking and asked.count((first, False)) == 1:
            return None  # held by someone else the first time we look
        return real(self, cell_id, blocking)

    monkeypatch.setattr(rundir.RunDir, "claim", held_once)
    outcome = run_bench(cfg, plots=False)  # the plots cost seconds and are not what is checked here
    text = capsys.readouterr().out
    assert outcome.exit_code == 0 and outcome.ran == [second, first] and outcome.reused == []
    assert asked == [(first, False), (second, False), (first, True)]  # deferred, then the blocking wait
    assert "waiting for 1 cell(s) that another tactile-zoo bench" in text
    assert text.index("[1/2]") < text.index("waiting for") < text.index("[2/2]")
    records = {p.stem: json.loads(p.read_text()) for p in (tmp_path / "run" / "cells").glob("*.json")}
    assert {k: r["status"] for k, r in records.items()} == {first: "ok", second: "ok"}
    assert not list((tmp_path / "run" / "claims").iterdir())
