"""A manifest entry with a URL and a sha256: downloaded from a real HTTP server on 127.0.0.1 into the cache,
verified, reused, fetched again when the cached copy is damaged, and refused (and deleted) on a sha256 mismatch."""

from __future__ import annotations

import dataclasses
import functools
import http.server
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from weights_helpers import MODEL, Trained

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.engine.evaluate import predict_scores
from tactile_zoo.errors import DatasetError
from tactile_zoo.weights import weights_cache, write_manifest


class _Counting(http.server.SimpleHTTPRequestHandler):
    hits: list[str]

    def do_GET(self) -> None:  # noqa: N802 - the http.server name
        self.hits.append(self.path)
        super().do_GET()

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[str, Path, list[str]]]:
    """``(base URL, served folder, requested paths)``, with the cache in a fresh folder."""
    monkeypatch.setenv("TACTILE_ZOO_CACHE", str(tmp_path / "cache"))
    folder, hits = tmp_path / "served", []
    folder.mkdir()
    handler = functools.partial(type("H", (_Counting,), {"hits": hits}), directory=str(folder))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", folder, hits
    httpd.shutdown()
    httpd.server_close()


def _remote(trained: Trained, url: str, tmp_path: Path) -> Path:
    """A manifest whose only entry names the weights by URL (no local file)."""
    return write_manifest([dataclasses.replace(trained.entry, file=None, url=url)], tmp_path / "remote.json")


def test_a_url_entry_is_downloaded_verified_cached_and_reused(trained: Trained, server: tuple, tmp_path: Path
                                                               ) -> None:
    base, folder, hits = server
    (folder / "cnn.safetensors").write_bytes(trained.file.read_bytes())
    manifest = _remote(trained, f"{base}/cnn.safetensors", tmp_path)
    model = tz.create_model(MODEL, pretrained=manifest)
    assert torch.equal(predict_scores(model, trained.test.x, trained.test.g), trained.logits)
    cached = weights_cache() / f"{trained.entry.sha256[:16]}-cnn.safetensors"
    assert weights_cache() == tmp_path / "cache" / "weights"
    assert sorted(p.name for p in weights_cache().iterdir()) == [cached.name]
    assert cached.read_bytes() == trained.file.read_bytes() and hits == ["/cnn.safetensors"]
    tz.create_model(MODEL, pretrained=manifest)
    assert len(hits) == 1  # served from the cache
    cached.write_bytes(b"damaged on disk")
    model = tz.create_model(MODEL, pretrained=manifest)
    assert len(hits) == 2 and cached.read_bytes() == trained.file.read_bytes()  # fetched again, never trusted
    assert torch.equal(predict_scores(model, trained.test.x, trained.test.g), trained.logits)


def test_a_download_with_the_wrong_sha256_is_refused_and_deleted(trained: Trained, server: tuple,
                                                                  tmp_path: Path) -> None:
    base, folder, hits = server
    blob = bytearray(trained.file.read_bytes())
    blob[-1] ^= 0xFF  # one byte differs: the server's file is not the one the manifest describes
    (folder / "cnn.safetensors").write_bytes(bytes(blob))
    manifest = _remote(trained, f"{base}/cnn.safetensors", tmp_path)
    with pytest.raises(DatasetError, match=rf"download of {base}/cnn.safetensors has sha256 [0-9a-f]{{64}}, expected "
                                           rf"{trained.entry.sha256}; the file was refused and deleted"):
        tz.create_model(MODEL, pretrained=manifest)
    assert hits == ["/cnn.safetensors"]
    assert not weights_cache().exists() or not any(weights_cache().iterdir())  # no file, no partial download
    with pytest.raises(DatasetError, match="HTTP 404"):
        tz.create_model(MODEL, pretrained=_remote(trained, f"{base}/absent.safetensors", tmp_path))


def test_the_listing_names_the_url_of_an_entry_not_downloaded_yet(trained: Trained, server: tuple, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture) -> None:
    base, _, hits = server
    manifest = _remote(trained, f"{base}/cnn.safetensors", tmp_path)
    assert main(["weights", "--manifest", str(manifest)]) == 0
    out = capsys.readouterr().out
    assert f"(download: {base}/cnn.safetensors)" in out and not hits  # listing never downloads
