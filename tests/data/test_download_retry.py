"""Retries and the progress bar of :func:`tactile_zoo.data.download.fetch`, against a real HTTP server on 127.0.0.1.

The server answers each request with the next behaviour of a script (a status code, a dropped connection, a body cut
short), then serves the file: so each test states exactly which failures come before the good response, and counts
the requests the download made.
"""

from __future__ import annotations

import hashlib
import http.server
import logging
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from tactile_zoo.data import download
from tactile_zoo.data.download import fetch
from tactile_zoo.errors import DatasetError

PAYLOAD = bytes(range(256)) * 4096  # 1 MiB: more than one read block, so a cut body is a real partial download
SHA = hashlib.sha256(PAYLOAD).hexdigest()


class _Scripted(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    script: list[str | int]  # one step a request: "drop", "short", or an HTTP status; "ok" once exhausted
    seen: list[str]

    def do_GET(self) -> None:  # noqa: N802 - the name http.server calls
        step = self.script.pop(0) if self.script else "ok"
        self.seen.append(str(step))
        if step == "drop":  # close without a status line: the client sees RemoteDisconnected
            self.close_connection = True
            return
        if step == "short":  # promise the whole file, send half, close
            self.send_response(200)
            self.send_header("Content-Length", str(len(PAYLOAD)))
            self.end_headers()
            self.wfile.write(PAYLOAD[: len(PAYLOAD) // 2])
            self.close_connection = True
            return
        if isinstance(step, int):
            self.send_response(step)
            if step in (429, 503):
                self.send_header("Retry-After", "0")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        self.send_response(200)
        self.send_header("Content-Length", str(len(PAYLOAD)))
        self.end_headers()
        self.wfile.write(PAYLOAD)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def scripted() -> Iterator:
    """``scripted(steps) -> (url, seen)``: a server on 127.0.0.1 following ``steps``, and the steps it took."""
    servers: list[http.server.ThreadingHTTPServer] = []

    def start(steps: list[str | int]) -> tuple[str, list[str]]:
        seen: list[str] = []
        handler = type("Handler", (_Scripted,), {"script": list(steps), "seen": seen})
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}/blob.bin", seen

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize("failures", [[503], ["drop"], ["short"], [429, 502]], ids=str)
def test_transient_failures_are_retried_then_the_file_is_verified(scripted, tmp_path: Path, failures: list,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    # the defaults, as every caller (datasets, weights) gets them; only the wait is shortened
    monkeypatch.setattr(download, "BACKOFF_SECONDS", 0.0, raising=False)
    url, seen = scripted(failures)
    dest = tmp_path / "blob.bin"
    assert fetch(url, dest, SHA) == dest
    assert dest.read_bytes() == PAYLOAD  # a retry starts the file afresh: nothing of the failed attempt is kept
    assert seen == [str(f) for f in failures] + ["ok"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blob.bin"]


def test_each_retry_is_logged_as_a_warning(scripted, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    url, _ = scripted([503])
    with caplog.at_level(logging.WARNING, logger="tactile_zoo"):
        fetch(url, tmp_path / "blob.bin", SHA, backoff=0.0, progress=False)
    assert [r.getMessage() for r in caplog.records] == [
        f"download of {url} failed (HTTP 503 Service Unavailable); retry 1 of 3 in 0.0 s"]


def test_a_404_fails_at_once_in_one_line(scripted, tmp_path: Path) -> None:
    url, seen = scripted([404])
    with pytest.raises(DatasetError) as err:
        fetch(url, tmp_path / "blob.bin", SHA, backoff=0.0, progress=False, hint="(place it by hand)")
    assert seen == ["404"]  # not retried
    assert str(err.value) == f"could not download {url}: HTTP 404 Not Found. (place it by hand)"
    assert list(tmp_path.iterdir()) == []


def test_retries_are_bounded(scripted, tmp_path: Path) -> None:
    url, seen = scripted([500] * 10)
    with pytest.raises(DatasetError, match="HTTP 500"):
        fetch(url, tmp_path / "blob.bin", SHA, retries=2, backoff=0.0, progress=False)
    assert seen == ["500"] * 3  # the first attempt and two retries
    assert list(tmp_path.iterdir()) == []


def test_a_wrong_checksum_is_not_retried(scripted, tmp_path: Path) -> None:
    url, seen = scripted([])
    with pytest.raises(DatasetError, match="sha256"):
        fetch(url, tmp_path / "blob.bin", "0" * 64, backoff=0.0, progress=False)
    assert seen == ["ok"] and list(tmp_path.iterdir()) == []


def test_the_progress_bar_goes_to_stderr_only_when_asked(scripted, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    url, _ = scripted([])
    fetch(url, tmp_path / "a.bin", SHA, progress=True)
    shown = capsys.readouterr()
    assert shown.out == "" and "blob.bin" in shown.err and "1.00M" in shown.err  # name and size, in binary units
    url, _ = scripted([])
    fetch(url, tmp_path / "b.bin", SHA)  # the default: stderr is captured here, not a terminal
    assert capsys.readouterr().err == ""
