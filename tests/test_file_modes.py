"""Every kind of file tactile-zoo writes gets the permissions the umask allows (0o666 & ~umask), as a plain
``open(path, "w")`` would: a results folder or data home shared with colleagues stays readable to them.

Files written through a temporary file used to be 0o600 whatever the umask (``tempfile.mkstemp`` then
``os.replace``, issue 28); each test below fails on that code.
"""

from __future__ import annotations

import functools
import hashlib
import http.server
import os
import stat
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import tiny_zoo
import torch

from tactile_zoo.cli import main

UMASK = 0o022


@pytest.fixture
def umask() -> Iterator[int]:
    previous = os.umask(UMASK)
    try:
        yield UMASK
    finally:
        os.umask(previous)


@pytest.fixture
def tiny() -> Iterator[None]:
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _modes(folder: Path) -> dict[str, str]:
    """``{relative path: octal mode}`` of every regular file under ``folder``."""
    return {str(p.relative_to(folder)): oct(_mode(p)) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_every_file_of_a_bench_run_is_0644_under_umask_022(tiny: None, umask: int, tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert main(["bench", "--plugin-module", "tiny_zoo", "--models", "tiny_mlp", "--datasets", "tiny_blobs",
                 "--seeds", "0", "--threads", "1", "--save-weights", "--out", str(out), "-q"]) == 0
    modes = _modes(out)
    kinds = {"cells/": ".json", "": "leaderboard.csv", "plots/": ".png", "weights/": ".safetensors"}
    for folder, suffix in kinds.items():  # the run wrote every kind this test is about
        assert any(name.startswith(folder) and name.endswith(suffix) for name in modes), (folder, suffix, modes)
    for name in ("run.json", "summary.csv", "report.md", "weights/manifest.json"):
        assert name in modes, modes
    assert {name: mode for name, mode in modes.items() if mode != oct(0o644)} == {}
    # report rewrites the tables: still the umask's permissions
    (out / "report.md").chmod(0o600)
    assert main(["report", str(out)]) == 0
    assert _mode(out / "report.md") == 0o644 and _mode(out / "leaderboard.csv") == 0o644


def test_a_progress_file_is_0644_under_umask_022(umask: int, tmp_path: Path) -> None:
    from tactile_zoo.bench.progress import ProgressWriter

    cell = {"cell_id": "m__d__f0__s0__abc", "model": "m", "dataset": "d", "fold": 0, "seed": 0}
    writer = ProgressWriter(tmp_path, cell, max_epochs=3)
    writer({"epoch": 1, "train_loss": 1.0, "val_loss": 1.0, "val_accuracy": 0.5, "seconds": 0.1, "lr": 0.1})
    (path,) = [p for p in tmp_path.rglob("*.json")]
    assert _mode(path) == 0o644


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_a_checkpoint_follows_the_umask(tmp_path: Path, mask: int) -> None:
    from tactile_zoo.engine.checkpoint import save_checkpoint

    previous = os.umask(mask)
    try:
        path = save_checkpoint(tmp_path / "model.pt", torch.nn.Linear(2, 2), {"model": "x"})
    finally:
        os.umask(previous)
    assert _mode(path) == 0o666 & ~mask


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args: object) -> None:
        pass


def test_a_download_is_0644_under_umask_022(umask: int, tmp_path: Path) -> None:
    """``tactile-zoo download`` (datasets) and pretrained weights both arrive through ``fetch``."""
    from tactile_zoo.data.download import fetch

    served = tmp_path / "server"
    served.mkdir()
    payload = os.urandom(4096)
    (served / "blob.zip").write_bytes(payload)
    handler = functools.partial(_Quiet, directory=str(served))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/blob.zip"
        dest = fetch(url, tmp_path / "home" / "raw" / "blob.zip", hashlib.sha256(payload).hexdigest())
    finally:
        server.shutdown()
        server.server_close()
    assert dest.read_bytes() == payload and _mode(dest) == 0o644


def test_a_processed_dataset_cache_is_0644_under_umask_022(umask: int, tmp_path: Path) -> None:
    from tactile_zoo.data.datasets.recordings import RecordingsDataset

    tiny_zoo.write_recordings(tmp_path)
    ds = RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1)
    (cache,) = list(ds.processed_dir.glob(f"{ds._cache_key()}.pt"))
    assert _mode(cache) == 0o644


def test_export_files_are_0644_under_umask_022(umask: int, tmp_path: Path) -> None:
    import tactile_zoo as tz
    from tactile_zoo.export import export_model

    spec = tz.load_dataset("sim_evtouch", split="train").spec
    model = tz.create_model("dcnn", spec)
    result = export_model(model, tmp_path / "export", name="dcnn", spec=spec, formats=("torchscript",), batch=1,
                          steps=4, check=False)
    modes = _modes(tmp_path / "export")
    assert result.manifest_path.name in modes and any(n.endswith(".pt") for n in modes), modes
    assert {name: mode for name, mode in modes.items() if mode != oct(0o644)} == {}
