"""Progress of long tasks (issue 38, item 17): a bar on a terminal, log lines when stderr is piped, nothing with
``-q``, for ``train``, ``evaluate``, ``export``, ``stream`` and ``tz.fit``."""

from __future__ import annotations

import io
import logging
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.engine import save_checkpoint
from tactile_zoo.engine.progress import Progress

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent
# the tiny zoo's model and dataset: two epochs in well under a second
TRAIN = ["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--epochs", "2"]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(TESTS), os.environ.get("PYTHONPATH", "")]),
            "OMP_NUM_THREADS": "1"}


def _epoch_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("train TinyMLP on tiny_blobs: ")]


def test_piped_train_logs_a_line_per_epoch_and_q_silences_them(capsys: pytest.CaptureFixture) -> None:
    """``train`` printed nothing until it ended. Piped (no terminal), each epoch is one plain line on stderr, with no
    carriage return; ``-q`` (the command's, or tactile-zoo's before it) leaves only the result."""
    cmd = [sys.executable, "-m", "tactile_zoo.cli", *TRAIN]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=_env())
    assert proc.returncode == 0, proc.stderr
    lines = _epoch_lines(proc.stderr)
    assert [line.split(": ")[1].split(",")[0] for line in lines] == ["1/2 epochs", "2/2 epochs"], proc.stderr
    assert "\r" not in proc.stderr and "val_acc" in lines[0]
    in_process = [a for a in TRAIN if a not in ("--plugin-module", "tiny_zoo")]  # the tiny zoo is registered here
    for argv in ([*in_process, "-q"], ["-q", *in_process]):
        assert main(argv) == 0
        captured = capsys.readouterr()
        assert captured.err == "" and "test accuracy" in captured.out


def _run_in_pty(cmd: list[str], timeout: float = 300) -> tuple[int, str]:
    """Run ``cmd`` with stdout and stderr on a new pseudo-terminal, as from a terminal window (whose size the kernel
    reports as 0 x 0: nobody set it, as under ``script`` or ``docker exec -t``)."""
    import pty

    leader, follower = pty.openpty()
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=follower, stderr=follower, env=_env(),
                            close_fds=True)
    os.close(follower)
    chunks, deadline = [], time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([leader], [], [], 0.2)
            if ready:
                try:
                    data = os.read(leader, 65536)
                except OSError:  # the terminal closed: the command ended
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
    finally:
        os.close(leader)
    return proc.wait(timeout=60), b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.skipif(sys.platform == "win32", reason="needs a pseudo-terminal")
def test_train_on_a_terminal_shows_a_bar() -> None:
    """On a terminal the epochs are a live bar (redrawn with carriage returns), not log lines. tqdm hid every bar on
    a terminal reporting 0 rows; the bar is drawn there too."""
    code, text = _run_in_pty([sys.executable, "-m", "tactile_zoo.cli", *TRAIN])
    assert code == 0, text
    assert "\r" in text and "|" in text and "train TinyMLP on tiny_blobs" in text and "/2" in text, text
    assert "epochs, loss" not in text  # no log lines


def test_progress_degrades_to_log_lines_and_can_be_turned_off(caplog: pytest.LogCaptureFixture) -> None:
    """The one reporter: log records when the stream is not a terminal (at most one per ``log_every`` seconds, and
    always the last), a bar when it is, nothing when disabled."""
    caplog.set_level(logging.INFO, logger="tactile_zoo.progress")
    with Progress(3, "task", "units", stream=io.StringIO(), log_every=3600) as bar:
        for _ in range(3):
            bar.update(1, "note")
    assert [r.getMessage().split(" (")[0] for r in caplog.records] == ["task: 3/3 units, note"]
    caplog.clear()
    with Progress(3, "task", "units", stream=io.StringIO(), enabled=False) as bar:
        bar.update(3)
    assert caplog.records == []

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    screen = Terminal()
    with Progress(3, "task", "units", stream=screen) as bar:
        assert bar.mode == "bar"
        bar.update(2)
    assert "\rtask: " in screen.getvalue() and "0/3" in screen.getvalue() and caplog.records == []


def test_fit_reports_its_epochs_by_default(caplog: pytest.LogCaptureFixture) -> None:
    """``tz.fit`` defaulted to ``progress=False``: silent for hours. Now it reports by default (a bar on a terminal,
    log records otherwise, which a program sees once it configures logging); ``progress=False`` turns it off."""
    caplog.set_level(logging.INFO, logger="tactile_zoo.progress")
    data = tz.load_dataset("sim_biotac_slip", split="train", n_train_per_class=2, n_test_per_class=1, num_steps=8)
    tz.fit(tz.create_model("sgnet", data.spec, graph_channels=4, hidden=[8]), data, epochs=2)
    lines = [r.getMessage() for r in caplog.records if r.name == "tactile_zoo.progress"]
    assert [line.split(": ")[1].split(",")[0] for line in lines] == ["1/2 epochs", "2/2 epochs"], lines
    caplog.clear()
    tz.fit(tz.create_model("sgnet", data.spec, graph_channels=4, hidden=[8]), data, epochs=2, progress=False)
    assert [r for r in caplog.records if r.name == "tactile_zoo.progress"] == []


@pytest.fixture
def checkpoint(tmp_path: Path) -> Path:
    spec = tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=1,
                           num_steps=8).spec
    torch.manual_seed(0)
    model = tz.create_model("sgnet", spec, graph_channels=4, hidden=[8])
    config = {"model": "sgnet", "hparams": {"graph_channels": 4, "hidden": [8]}, "dataset": "sim_biotac_slip",
              "dataset_kwargs": {"num_steps": 8, "n_train_per_class": 2, "n_test_per_class": 1}, "seed": 0,
              "recipe": {"loss": "mse_rate"}, "spec": spec.to_dict()}
    return save_checkpoint(tmp_path / "sgnet.pt", model, config)


@pytest.mark.parametrize(("argv", "head"), [
    (["evaluate", "{ckpt}"], "evaluate SGNet on sim_biotac_slip: "),
    (["stream", "{ckpt}", "--index", "0"], "stream SGNet: "),
    (["export", "{ckpt}", "--format", "torchscript", "--no-step", "--out", "{tmp}/out"], "export sgnet: "),
])
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_evaluate_stream_and_export_log_progress_when_piped(argv: list[str], head: str, checkpoint: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    """Silent before; piped (pytest's captured stderr is not a terminal) each reports on stderr, ``-q`` not at all."""
    argv = [a.format(ckpt=checkpoint, tmp=checkpoint.parent) for a in argv]
    assert main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    assert err and all(line.startswith(head) for line in err), err
    assert "/" in err[-1]  # "n/total units"
    if argv[0] == "export":
        argv[-1] += "2"  # another folder
    assert main([*argv, "-q"]) == 0
    assert capsys.readouterr().err == ""
