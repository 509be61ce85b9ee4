"""The bottom layer's edge cases (:mod:`tactile_zoo._yaml`, :mod:`._files`, :mod:`._owned`, :mod:`._signals`,
:mod:`._env`): a settings file that is empty, not UTF-8 or nested too deeply; temporary names that all clash; a
writer that changes a file's permissions; folders and files that cannot be listed or written; SIGTERM as an
interrupt and where it is left alone; matplotlib absent."""

from __future__ import annotations

import errno
import os
import signal
import stat
import sys
import threading
from pathlib import Path

import pytest

from tactile_zoo import _files, _owned
from tactile_zoo._env import check_matplotlib_backend
from tactile_zoo._signals import TERMINATED_EXIT, Terminated, terminate_as_interrupt
from tactile_zoo._yaml import load_yaml, read_yaml_file
from tactile_zoo.errors import ConfigError

FOLDER = _owned.FolderRule("--out", "bench", "run.json", "a bench folder to resume")
FILE = _owned.FileRule("--save", "tactile-zoo checkpoint", "a checkpoint `train --save` wrote", "MODEL.pt")


# ------------------------------------------------------------------------------------------------ YAML
@pytest.mark.parametrize("text", ["", "# only a comment\n", "---\n"])
def test_an_empty_document_is_none(text: str) -> None:
    assert load_yaml(text, "c.yaml") is None


def _depth() -> int:
    frame, depth = sys._getframe(), 0
    while frame is not None:
        frame, depth = frame.f_back, depth + 1
    return depth


@pytest.mark.parametrize("text", ["[" * 200 + "]" * 200, "a:\n" + "".join(" " * i + "b:\n" for i in range(1, 200))])
def test_a_document_nested_too_deeply_is_one_error_naming_it(text: str) -> None:
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(_depth() + 150)  # 200 levels need twice as many frames: far beyond (and the test quick)
    try:
        with pytest.raises(ConfigError, match="^--config c.yaml: nested too deeply$"):
            load_yaml(text, "--config c.yaml")
    finally:
        sys.setrecursionlimit(limit)
    assert load_yaml("[" * 50 + "]" * 50, "c.yaml") == eval("[" * 50 + "]" * 50)  # noqa: S307 - a literal


def test_a_file_that_is_not_utf8_is_refused_naming_it_and_the_byte(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_bytes(b"epochs: 3\nnote: caf\xe9\n")
    with pytest.raises(ConfigError, match=r"^--config c.yaml: not UTF-8 text \(invalid continuation byte at byte "
                                          r"19\)$"):
        read_yaml_file(path, "--config c.yaml")


# ------------------------------------------------------------------------------------------------ files
def test_temporary_names_that_all_clash_give_up(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_files.secrets, "token_hex", lambda n: "0" * (2 * n))
    fd, first = _files.open_temporary(tmp_path / "w.pt")
    os.close(fd)
    assert first.name == ".w.pt.000000000000.tmp"
    with pytest.raises(FileExistsError, match=f"^cannot create a temporary file next to {tmp_path / 'w.pt'}$"):
        _files.open_temporary(tmp_path / "w.pt")


def test_a_writer_that_narrows_the_permissions_gets_the_umasks_back(tmp_path: Path) -> None:
    plain = tmp_path / "plain"
    plain.write_text("x")
    with _files.atomic_path(tmp_path / "w.safetensors", fsync=False) as tmp:
        tmp.unlink()
        tmp.write_bytes(b"data")
        os.chmod(tmp, 0o600)  # as safetensors creates its files
    final = tmp_path / "w.safetensors"
    assert final.read_bytes() == b"data"
    assert stat.S_IMODE(final.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode) != 0o600


def test_a_folder_that_cannot_be_listed_is_left_to_the_write_check(monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(path: object) -> list[str]:
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(_owned.os, "listdir", denied)
    assert _owned.check_folder("/somewhere", FOLDER, lambda: False) == []


def test_a_file_of_no_known_kind_is_said_so() -> None:
    assert _owned._what(stat.S_IFDIR) == "a folder"
    assert _owned._what(0) == "not a regular file"


def test_a_file_whose_folder_cannot_be_written_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def full(path: object) -> tuple[int, Path]:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_owned, "open_temporary", full)
    target = tmp_path / "sub" / "m.pt"
    with pytest.raises(ConfigError) as caught:
        _owned.check_file(target, FILE, lambda p: False)
    assert str(caught.value) == (f"--save {target}: cannot write in folder {target.parent} (No space left on "
                                 f"device); choose a writable folder")


# ------------------------------------------------------------------------------------------------ SIGTERM
@pytest.fixture
def default_sigterm() -> object:
    """SIGTERM at its default action for the test (pytest or a plugin may have set a handler)."""
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    yield
    signal.signal(signal.SIGTERM, previous)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.usefixtures("default_sigterm")
def test_sigterm_raises_terminated_once_then_the_default_returns() -> None:
    caught = []
    with pytest.raises(Terminated) as raised, terminate_as_interrupt():
        assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL  # else the kill below would end pytest
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            caught.append("not raised")
        except Terminated:
            caught.append("raised")
            os.kill(os.getpid(), signal.SIGTERM)  # a second one during the cleanup: ignored
            caught.append("cleaned up")
            raise
    assert caught == ["raised", "cleaned up"]
    assert isinstance(raised.value, KeyboardInterrupt) and raised.value.exit_code == TERMINATED_EXIT == 143
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.usefixtures("default_sigterm")
def test_sigterm_is_left_alone_off_the_main_thread_and_where_a_handler_is_set() -> None:
    seen = []

    def in_thread() -> None:
        with terminate_as_interrupt():
            seen.append(signal.getsignal(signal.SIGTERM))

    thread = threading.Thread(target=in_thread)
    thread.start()
    thread.join()
    assert seen == [signal.SIG_DFL]

    def mine(signum: int, frame: object) -> None:
        pass

    signal.signal(signal.SIGTERM, mine)
    with terminate_as_interrupt():
        assert signal.getsignal(signal.SIGTERM) is mine
    assert signal.getsignal(signal.SIGTERM) is mine


# ------------------------------------------------------------------------------------------------ environment
def test_without_matplotlib_a_backend_is_not_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MPLBACKEND", "no-such-backend")
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    check_matplotlib_backend()
