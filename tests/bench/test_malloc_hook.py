"""The two training entry points apply the start-up malloc settings (tactile_zoo.engine.malloc) once each."""

from __future__ import annotations

import pytest

from tactile_zoo.bench import worker
from tactile_zoo.cli import main
from tactile_zoo.engine import malloc


def test_train_command_tunes_malloc(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    calls: list[str] = []
    monkeypatch.setattr(malloc, "tune_malloc", lambda: calls.append("train"))
    assert main(["train", "tiny_mlp", "tiny_blobs", "--seed", "1", "--epochs", "1", "--json", "-q"]) == 0
    capsys.readouterr()
    assert calls == ["train"]


def test_every_bench_worker_tunes_malloc(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    monkeypatch.setattr(worker, "tune_malloc", lambda: calls.append("worker"))
    worker.setup_worker()
    assert calls == ["worker"]
