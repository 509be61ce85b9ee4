"""Downloads (against a real HTTP server on 127.0.0.1) and safe zip extraction (zip slip)."""

from __future__ import annotations

import functools
import hashlib
import http.server
import io
import shutil
import socket
import stat
import threading
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_zoo.cli import main
from tactile_zoo.data.datasets import EvObjects
from tactile_zoo.data.download import check_zip_member, fetch, safe_extract, verify_sha256
from tactile_zoo.errors import DatasetError

EV_SHA = "bd8e828064a85c4fc6567789283198ff0b92384ef58aeb2366fa36a963ded867"


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def serve() -> Iterator:
    """``serve(folder) -> base URL`` of a threaded HTTP server on 127.0.0.1 serving ``folder``."""
    servers = []

    def start(folder: Path) -> str:
        handler = functools.partial(_Quiet, directory=str(folder))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_download_of_the_real_zip_from_a_local_server(shared_data: Path, serve, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    url = serve(shared_data / "ev_objects" / "raw")
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", url)
    home = tmp_path / "home"
    ds = EvObjects(root=home, split="test", download=True)
    raw = home / "ev_objects" / "raw"
    assert _leftovers(raw) == ["Ev-Objects.zip"]  # renamed into place, no temporary file left
    assert verify_sha256(raw / "Ev-Objects.zip", EV_SHA) == EV_SHA
    assert len(ds) == 144 and ds.x.shape[1:] == (250, 39, 2)
    # a second load uses the placed zip without the network
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", "http://127.0.0.1:9")
    assert len(EvObjects(root=home, split="train", download=True)) == 468


def test_cli_download_fetches_then_reports_present(shared_data: Path, serve, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", serve(shared_data / "ev_objects" / "raw"))
    assert main(["download", "ev_objects", "--root", str(tmp_path), "--extract"]) == 0
    out = capsys.readouterr().out
    assert "downloaded and verified" in out and "720 samples" in out and "extracted to" in out
    assert (tmp_path / "ev_objects" / "raw" / "Ev-Objects" / "test" / "sample_0_label_20.npy").is_file()
    assert main(["download", "ev_objects", "--root", str(tmp_path)]) == 0
    assert "present" in capsys.readouterr().out


def test_wrong_checksum_is_refused_and_deleted(serve, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    served = tmp_path / "server"
    served.mkdir()
    with zipfile.ZipFile(served / "Ev-Objects.zip", "w") as zf:  # a well-formed zip, just not the release
        zf.writestr("Ev-Objects/train/sample_0_label_0.npy", b"forged")
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", serve(served))
    home = tmp_path / "home"
    with pytest.raises(DatasetError) as err:
        EvObjects(root=home, download=True)
    message = str(err.value)
    assert "sha256" in message and EV_SHA in message and "refused and deleted" in message
    assert str(home / "ev_objects" / "raw" / "Ev-Objects.zip") in message  # says where to place the real file
    assert _leftovers(home / "ev_objects" / "raw") == []


def test_http_error_and_offline_say_what_to_place_where(serve, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", serve(empty))
    target = tmp_path / "home" / "ev_objects" / "raw" / "Ev-Objects.zip"
    with pytest.raises(DatasetError, match="HTTP 404") as err:
        EvObjects(root=tmp_path / "home", download=True)
    assert str(target) in str(err.value)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", f"http://127.0.0.1:{port}")
    with pytest.raises(DatasetError, match="offline") as err:
        EvObjects(root=tmp_path / "home", download=True)
    assert str(target) in str(err.value) and EV_SHA in str(err.value)
    assert _leftovers(target.parent) == []


def test_missing_data_without_download_names_the_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(DatasetError) as err:
        EvObjects(root=tmp_path)
    assert str(tmp_path / "ev_objects" / "raw" / "Ev-Objects.zip") in str(err.value)
    assert "tactile-zoo download ev_objects" in str(err.value)
    assert EvObjects.availability(tmp_path)[0] is False
    assert main(["info", "ev_objects", "--root", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err and "Ev-Objects.zip" in captured.err
    assert not (tmp_path / "ev_objects").exists()  # nothing is created without download=True


def test_fetch_verifies_caps_and_refuses_other_schemes(serve, tmp_path: Path) -> None:
    served = tmp_path / "server"
    served.mkdir()
    payload = np.random.default_rng(0).bytes(300_000)
    (served / "blob.bin").write_bytes(payload)
    url = serve(served) + "/blob.bin"
    sha = hashlib.sha256(payload).hexdigest()
    dest = tmp_path / "out" / "blob.bin"
    assert fetch(url, dest, sha) == dest and dest.read_bytes() == payload
    dest.unlink()
    with pytest.raises(DatasetError, match="exceeds 1000 bytes"):
        fetch(url, dest, sha, max_bytes=1000)
    assert _leftovers(dest.parent) == []
    with pytest.raises(DatasetError, match="only http"):
        fetch(f"file://{served / 'blob.bin'}", dest, sha)
    with pytest.raises(DatasetError, match="does not match"):
        verify_sha256(served / "blob.bin", "0" * 64)


# ----------------------------------------------------------------------------------------------- zip slip
def _zip_with(path: Path, name: str, data: bytes = b"x", mode: int | None = None) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("ok/fine.txt", b"fine")
        info = zipfile.ZipInfo(name)
        if mode is not None:
            info.create_system = 3  # unix, so external_attr carries the file type
            info.external_attr = mode << 16
        zf.writestr(info, data)
    return path


@pytest.mark.parametrize("name, mode, reason", [
    ("/etc/evil.txt", None, "absolute path"),
    ("../evil.txt", None, "'..'"),
    ("ok/../../evil.txt", None, "'..'"),
    ("ok\\..\\..\\evil.txt", None, "'..'"),
    ("C:/evil.txt", None, "absolute path"),
    ("ok/link", stat.S_IFLNK | 0o777, "symbolic link"),
    ("ok/fifo", stat.S_IFIFO | 0o644, "special file"),
])
def test_zip_slip_members_are_refused_before_anything_is_written(tmp_path: Path, name: str, mode: int | None,
                                                                 reason: str) -> None:
    archive = _zip_with(tmp_path / "evil.zip", name, b"/etc/passwd" if mode else b"pwned", mode)
    dest = tmp_path / "out"
    with pytest.raises(DatasetError, match=reason):
        safe_extract(archive, dest)
    assert not dest.exists()  # every member is checked before the first write
    assert not (tmp_path / "evil.txt").exists()


def test_check_zip_member_caps_size_and_refuses_encryption() -> None:
    info = zipfile.ZipInfo("big.bin")
    info.file_size = 10**12
    with pytest.raises(DatasetError, match="cap"):
        check_zip_member(info)
    info = zipfile.ZipInfo("secret.bin")
    info.flag_bits |= 0x1
    with pytest.raises(DatasetError, match="encrypted"):
        check_zip_member(info)
    assert str(check_zip_member(zipfile.ZipInfo("./a//b.npy"))) == "a/b.npy"


def test_safe_extract_writes_a_good_archive(tmp_path: Path) -> None:
    buf = io.BytesIO()
    np.save(buf, np.arange(6, dtype=np.float32))
    with zipfile.ZipFile(tmp_path / "good.zip", "w") as zf:
        zf.writestr("top/", b"")
        zf.writestr("top/a/x.npy", buf.getvalue())
    written = safe_extract(tmp_path / "good.zip", tmp_path / "out")
    assert written == [(tmp_path / "out" / "top" / "a" / "x.npy").resolve()]
    assert np.load(written[0]).tolist() == list(range(6))


def test_hostile_member_inside_an_ev_zip_is_refused(tmp_path: Path) -> None:
    raw = tmp_path / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    _zip_with(raw / "Ev-Objects.zip", "../../escape.npy")
    with pytest.raises(DatasetError, match="zip slip"):
        EvObjects(root=tmp_path, verify_checksum=False)


def test_extracted_folder_reads_like_the_zip(shared_data: Path, tmp_path: Path) -> None:
    raw = tmp_path / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    shutil.copy(shared_data / "ev_objects" / "raw" / "Ev-Objects.zip", raw)
    from_zip = EvObjects(root=tmp_path)
    folder = EvObjects.extract(tmp_path)
    assert folder == raw / "Ev-Objects" and len(list((folder / "train").glob("*.npy"))) == 576
    (raw / "Ev-Objects.zip").unlink()
    from_folder = EvObjects(root=tmp_path)
    assert torch.equal(from_folder.x, from_zip.x) and torch.equal(from_folder.y, from_zip.y)
