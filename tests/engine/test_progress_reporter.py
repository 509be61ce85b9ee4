"""Progress of long tasks (issue 38, item 17): a bar on a terminal, log lines when stderr is piped, nothing with
``-q``, for ``train``, ``evaluate``, ``export``, ``stream`` and ``tz.fit``."""

from __future__ import annotations

import io
import logging
import os
import select
import sys
import time
from pathlib import Path

import pytest
import torch
from forked_bench import fork_python

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.engine import save_checkpoint
from tactile_zoo.engine.progress import Progress

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent
# the tiny zoo's model and dataset: two epochs in well under a second
TRAIN = ["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--epochs", "2"]


def _epoch_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("train TinyMLP on tiny_blobs: ")]


# ``tactile-zoo TRAIN`` with stderr (``"2"``) or stdout and stderr (``"1 2"``) on the file that $TZ_TEST_STDIO names
# (a FIFO: a pipe; a pseudo-terminal's follower: a terminal), in a child forked from the warm server of
# tests/forked_bench.py (torch, the package and the tiny zoo imported once), not a new interpreter (5-6 s each)
_CHILD = """
import os, sys
fd = os.open(os.environ["TZ_TEST_STDIO"], os.O_WRONLY | os.O_NOCTTY)
for target in map(int, os.environ["TZ_TEST_FDS"].split()):
    os.dup2(fd, target)
os.close(fd)
# new text streams on them, buffered as a new interpreter's are (line by line on a terminal)
sys.stdout, sys.stderr = open(1, "w", closefd=False), open(2, "w", closefd=False)
from tactile_zoo.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _run_on(path: Path, leader: int, keep: int, fds: str, log: Path, timeout: float = 300) -> tuple[int, str]:
    """``tactile-zoo TRAIN`` in a forked child writing on ``path``; its exit status and what this process read from
    ``leader``. ``keep``, this process's own descriptor of ``path``, stays open until the child ends, so that the
    reads wait for the child rather than end before it has opened its side."""
    child = fork_python(_CHILD, TRAIN, log, TZ_TEST_STDIO=str(path), TZ_TEST_FDS=fds,
                        PYTHONPATH=os.pathsep.join([str(REPO), str(TESTS)]))
    chunks: list[bytes] = []

    def read(wait: float) -> None:  # until nothing comes for ``wait`` seconds, or the other side is closed
        while select.select([leader], [], [], wait)[0]:
            try:
                data = os.read(leader, 65536)
            except OSError:  # a terminal whose other side is closed
                return
            if not data:
                return
            chunks.append(data)

    deadline = time.monotonic() + timeout
    try:
        while child.poll() is None and time.monotonic() < deadline:
            read(0.2)
        code = child.wait(timeout=60)
        os.close(keep)
        keep = -1
        read(1.0)
    finally:
        child.kill()
        for fd in (keep, leader):
            if fd >= 0:
                os.close(fd)
    return code, b"".join(chunks).decode("utf-8", "replace")


def test_piped_train_logs_a_line_per_epoch_and_q_silences_them(tmp_path: Path, capsys: pytest.CaptureFixture
                                                               ) -> None:
    """``train`` printed nothing until it ended. Piped (no terminal), each epoch is one plain line on stderr, with no
    carriage return; ``-q`` (the command's, or tactile-zoo's before it) leaves only the result."""
    fifo = tmp_path / "stderr"
    os.mkfifo(fifo)
    leader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    code, err = _run_on(fifo, leader, os.open(fifo, os.O_WRONLY), "2", tmp_path / "train")
    assert code == 0, err
    lines = _epoch_lines(err)
    assert [line.split(": ")[1].split(",")[0] for line in lines] == ["1/2 epochs", "2/2 epochs"], err
    assert "\r" not in err and "val_acc" in lines[0]
    assert "test accuracy" in (tmp_path / "train.out").read_text()  # stdout was not on the pipe
    in_process = [a for a in TRAIN if a not in ("--plugin-module", "tiny_zoo")]  # the tiny zoo is registered here
    for argv in ([*in_process, "-q"], ["-q", *in_process]):
        assert main(argv) == 0
        captured = capsys.readouterr()
        assert captured.err == "" and "test accuracy" in captured.out


@pytest.mark.skipif(sys.platform == "win32", reason="needs a pseudo-terminal")
def test_train_on_a_terminal_shows_a_bar(tmp_path: Path) -> None:
    """On a terminal the epochs are a live bar (redrawn with carriage returns), not log lines. tqdm hid every bar on
    a terminal reporting 0 rows; the bar is drawn there too (a new pseudo-terminal, whose size the kernel reports
    as 0 x 0: nobody set it, as under ``script`` or ``docker exec -t``)."""
    import pty

    leader, follower = pty.openpty()
    code, text = _run_on(Path(os.ttyname(follower)), leader, follower, "1 2", tmp_path / "train")
    assert code == 0, text
    assert "\r" in text and "|" in text and "train TinyMLP on tiny_blobs" in text and "/2" in text, text
    assert "epochs, loss" not in text  # no log lines
    assert "test accuracy" in text  # stdout was on the terminal too


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
