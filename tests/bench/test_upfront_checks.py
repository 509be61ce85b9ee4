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
