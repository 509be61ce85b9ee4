"""Bench input is checked before anything runs: one line on stderr, exit 2, no output folder (issue 38, items 3 and
5-8). What a check lets through still runs: a model that cannot consume a dataset is a skipped cell, not an error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from conftest import read_board, run_cli

from tactile_zoo import registry
from tactile_zoo.errors import ConfigError


def _refused(capsys: pytest.CaptureFixture, out: Path, *words: str) -> str:
    """The command printed one error line holding ``words``, nothing on stdout, and left no output folder.

    (A library's deprecation warning on its first import in this process may precede the line: the CLI shows every
    warning; a fresh ``tactile-zoo`` process prints the error line alone.)"""
    captured = capsys.readouterr()
    assert captured.out == "", captured.out
    lines = [line for line in captured.err.splitlines() if not line.startswith("tactile-zoo: warning:")]
    assert len(lines) == 1 and lines[0].startswith("tactile-zoo: error:"), captured.err
    for word in words:
        assert word in lines[0], captured.err
    assert not out.exists()
    return lines[0]


# ----------------------------------------------------------------------------------------------- item 3: hparams
@pytest.mark.parametrize("value", ["abc", "-4", "3.7"])
def test_a_bad_hyper_parameter_value_is_refused_before_any_cell(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                value: str) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--hparam", f"hidden={value}", "--out",
                    str(out)]) == 2
    shown = {"abc": "'abc'"}.get(value, value)  # the value as parsed: a string, an int, a float
    _refused(capsys, out, f"--hparam hidden={shown}:", "'tiny_mlp'", "'tiny_blobs'")


@pytest.mark.parametrize("value", ["abc", "-4", "3.7"])
def test_the_issue_reproduction_tacformer_dim(tmp_path: Path, capsys: pytest.CaptureFixture, value: str) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tacformer", "--datasets", "sim_evtouch", "--quick", "--hparam", f"dim={value}",
                    "--out", str(out)]) == 2
    _refused(capsys, out, "--hparam dim=", "'tacformer'", "'sim_evtouch'")


def test_a_bad_value_fails_the_dry_run_too(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--hparam", "tiny_mlp:hidden=abc",
                    "--dry-run", "--out", str(tmp_path / "run")]) == 2
    _refused(capsys, tmp_path / "run", "hidden='abc'")


def test_a_model_that_cannot_consume_a_dataset_is_still_a_skip_with_hparams(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_picky", "--datasets", "tiny_kfold", "--folds", "1", "--hparam", "hidden=8",
                    "--out", str(out), "-q", "--no-plots"]) == 0
    (row,) = read_board(out)
    assert row["status"] == "skipped" and "needs global features" in row["error"]


class _Refuses(torch.nn.Module):
    """A model whose constructor raises a plain ConfigError (not ModelCannotConsume)."""

    def __init__(self, spec: object, **kw: object) -> None:
        super().__init__()
        raise ConfigError("zt_refuses: a configuration error, not a dataset it cannot consume")


def test_a_plain_config_error_from_a_constructor_is_never_a_skip(tmp_path: Path) -> None:
    registry.register_model("zt_refuses")(_Refuses)
    try:
        out = tmp_path / "run"
        assert run_cli(["--models", "zt_refuses", "--datasets", "tiny_blobs", "--out", str(out), "-q",
                        "--no-plots"]) == 1
        (path,) = (out / "cells").glob("*.json")
        record = json.loads(path.read_text())
        assert record["status"] == "failed" and "a configuration error" in record["error"]
    finally:
        registry._unregister("model", "zt_refuses")


# ------------------------------------------------------------------------------------------- item 5: device, threads
@pytest.mark.parametrize("device", ["tpu9", "cuda:99", "meta"])
def test_a_device_this_machine_cannot_run_is_refused_up_front(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                              device: str) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--device", device, "--out", str(out)]) == 2
    _refused(capsys, out, f"--device {device!r}")


def test_a_remote_scheduler_s_device_is_checked_by_name_only() -> None:
    from tactile_zoo.bench.config import BenchConfig

    with pytest.raises(ConfigError, match="not a device name"):
        BenchConfig(executor="dask", scheduler="tcp://gpu-node:8786", device="tpu9")
    assert BenchConfig(executor="dask", scheduler="tcp://gpu-node:8786", device="cuda:3").device == "cuda:3"


def test_a_bad_lif_backend_is_refused_by_the_config_too(monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo.bench.config import BenchConfig

    monkeypatch.setenv("TACTILE_ZOO_LIF_BACKEND", "bogus")
    with pytest.raises(ConfigError, match="TACTILE_ZOO_LIF_BACKEND='bogus'"):
        BenchConfig(models=["tiny_mlp"], datasets=["tiny_blobs"])


def test_threads_above_the_cap_are_refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                           capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.bench import config as bench_config

    monkeypatch.setattr(bench_config, "cpu_count", lambda: 2)
    with pytest.raises(ConfigError, match=r"--threads 100000: at most 8 \(4 x the 2 core"):
        bench_config.BenchConfig(threads=100000)
    assert bench_config.BenchConfig(threads=8).threads == 8
    with pytest.raises(ConfigError, match="at most 256"):  # a remote cluster's cores are not this machine's
        bench_config.BenchConfig(executor="dask", scheduler="tcp://host:8786", threads=257)
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--threads", "100000", "--dry-run",
                    "--out", str(out)]) == 2
    _refused(capsys, out, "--threads 100000")


# ----------------------------------------------------------------------------------------------- item 6: grid size
def test_a_huge_seed_range_is_refused_with_its_count_without_listing_it(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0-20000", "--dry-run",
                    "--out", str(out)]) == 2
    _refused(capsys, out, "20,001 seeds")
    from tactile_zoo.bench.parsing import MAX_CELLS, parse_seeds

    with pytest.raises(ConfigError, match=r"--seeds 0-100000000: 100,000,001 seeds; .* at most 10,000 cells"):
        parse_seeds("0-100000000")
    with pytest.raises(ConfigError, match="1,000,000,000,001 seeds"):
        parse_seeds("0-1000000000000")
    assert parse_seeds(f"0-{MAX_CELLS - 1}") == list(range(MAX_CELLS))
    assert parse_seeds("0-6000,3000-9999") == list(range(10_000))  # overlaps count once


def test_a_grid_above_the_cap_is_refused_with_its_count(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.bench import grid

    monkeypatch.setattr(grid, "MAX_CELLS", 5)
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_blobs,tiny_kfold", "--folds", "2",
                    "--dry-run", "--out", str(out)]) == 2
    _refused(capsys, out, "the grid has 6 cells (2 model(s) x 3 dataset fold(s) x 1 seed(s)); a bench command runs "
                          "at most 5")


# ----------------------------------------------------------------------------------------------- item 7: workers
def test_a_pool_starts_no_more_workers_than_cells_and_warns_above_the_cores(monkeypatch: pytest.MonkeyPatch,
                                                                            caplog: pytest.LogCaptureFixture) -> None:
    from tactile_zoo.bench import executors

    monkeypatch.setattr(executors, "cpu_count", lambda: 2)
    pool = executors.make_executor("process", workers=1000, threads=1, cells=6)
    try:
        assert pool.workers == 6 and pool.slots == 6
    finally:
        pool.shutdown(cancel=True)
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "6 worker process(es) x 1 thread(s) = 6 threads on 2 core(s)" in warned[0]
    caplog.clear()
    assert executors.pool_size(1, 6, 1) == 1 and executors.pool_size(None, 0) == 1
    assert not caplog.records  # within the cores: nothing to say


def test_workers_that_would_oversubscribe_the_machine_are_refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.bench import config as bench_config
    from tactile_zoo.bench import executors

    monkeypatch.setattr(executors, "cpu_count", lambda: 2)
    monkeypatch.setattr(bench_config, "cpu_count", lambda: 2)
    out = tmp_path / "run"
    args = ["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_blobs,tiny_kfold", "--folds", "2",
            "--executor", "process", "--workers", "1000", "--out", str(out), "--dry-run"]
    assert run_cli([*args, "--threads", "2"]) == 2  # 6 cells x 2 threads on 2 cores
    _refused(capsys, out, "--workers 1000: 6 worker process(es) x 2 thread(s) for 6 cell(s)", "at most 8")
    assert run_cli(args) == 0  # 6 x 1: capped at the cells, and a warning when it runs


# ----------------------------------------------------------------------------------------------- item 8: weights
def test_save_weights_with_quick_is_refused_before_anything_is_trained(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--quick", "--save-weights", "--out",
                    str(out)]) == 2
    _refused(capsys, out, "--save-weights with --quick", "not publishable")


def test_run_json_is_finished_even_when_the_weights_manifest_is_refused(monkeypatch: pytest.MonkeyPatch,
                                                                        tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.weights import manifest

    def refuse(record: dict, run_dir: object = None, **kw: object) -> None:
        raise ConfigError(f"cell {record['cell_id']}: refused on purpose")

    monkeypatch.setattr(manifest, "entry_from_record", refuse)
    out = tmp_path / "run"
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--epochs", "1", "--save-weights", "--out",
                    str(out), "-q", "--no-plots"]) == 1
    assert "refused on purpose" in capsys.readouterr().err
    assert json.loads((out / "run.json").read_text())["status"] == "finished"
