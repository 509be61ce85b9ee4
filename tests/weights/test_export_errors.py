"""``export_model`` and its helpers on the paths the end-to-end export tests do not take: a model the registry does
not know, nothing to export, a full disk on either format, a failing ONNX exporter, and the export folder's lock,
its marker and an older version's descriptions when they are damaged. A tiny linear model, TorchScript only: no
ONNX file is really written here."""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import torch
from torch import nn

from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError, ExportError
from tactile_zoo.export import exporter, folder, onnx_io
from tactile_zoo.export.exporter import _diff, export_model
from tactile_zoo.export.folder import MARKER, ExportFolder, write_file
from tactile_zoo.registry import get_sensor

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.jit.save/load, deprecated in torch

SPEC = DatasetSpec("zt_export", 2, ("a", "b"), 3, 39, 2, 0, get_sensor("neutouch"))


class Unlisted(nn.Module):
    """A model no registry entry describes: its name is its class's, its metadata its ``zoo_meta``."""

    zoo_meta = {"streaming": False}

    def __init__(self) -> None:
        super().__init__()
        self.spec = SPEC
        self.head = nn.Linear(SPEC.num_nodes * SPEC.num_channels, SPEC.num_classes)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.head(x.mean(1).flatten(1))


class Restless(Unlisted):
    """A streaming model whose step is not a function of its state (it draws noise): the state as tensors cannot
    reproduce it."""

    zoo_meta = {"streaming": True}

    def init_state(self, batch: int) -> torch.Tensor:
        return torch.zeros(batch, SPEC.num_classes)

    def step(self, x_t: torch.Tensor, g_t: torch.Tensor | None, state: torch.Tensor) -> tuple[torch.Tensor, Any]:
        new = state + self.head(x_t.flatten(1)) + torch.rand(state.shape)
        return new, new


def test_a_model_the_registry_does_not_know_exports_under_its_class_name(tmp_path: Path) -> None:
    result = export_model(Unlisted(), tmp_path / "out", formats=("torchscript",), progress=False)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted([MARKER, "Unlisted.export.json",
                                                                           "Unlisted.forward.pt"])
    assert result.manifest["checks"]["torchscript.forward"]["ok"] is True
    assert "step" not in result.manifest or not result.manifest["step"]


def test_nothing_to_export_is_refused_before_any_work(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="^nothing to export: forward=False, and Unlisted has no streaming step to "
                                          "export$"):
        export_model(Unlisted(), tmp_path / "out", formats=("torchscript",), forward=False, progress=False)
    assert not (tmp_path / "out").exists()


def test_a_step_its_state_cannot_reproduce_is_refused_naming_the_model(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match=r"^restless: the step with its state as tensors does not reproduce "
                                          r"restless\.step\(\)"):
        export_model(Restless(), tmp_path / "out", name="restless", formats=("torchscript",), forward=False,
                     step=True, progress=False)
    assert not (tmp_path / "out").exists()  # the folder it made is removed again


def test_a_full_disk_names_the_file_and_leaves_no_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def full(path: Path, data: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(exporter, "write_file", full)
    out = tmp_path / "out"
    with pytest.raises(ExportError) as caught:
        export_model(Unlisted(), out, formats=("torchscript",), progress=False)
    assert str(caught.value) == (f"cannot write Unlisted.forward.pt into {out}: No space left on device; the export "
                                 f"stopped and left the folder as it was")
    assert not out.exists()


@pytest.mark.parametrize("cause", [OSError(errno.ENOSPC, "No space left on device"), None])
def test_the_onnx_exporter_failing_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                cause: OSError | None) -> None:
    def failing(graph: Any, inputs: Any, path: Path, opset: Any, optimize: bool) -> None:
        raise ExportError(f"ONNX export of {path.name} failed: it could not") from cause

    monkeypatch.setattr(exporter, "to_onnx", failing)
    out = tmp_path / "out"
    (out / "keep").mkdir(parents=True)
    (out / MARKER).write_text(json.dumps({"format": folder.FOLDER_FORMAT, "exports": {}}))
    with pytest.raises(ExportError) as caught:
        export_model(Unlisted(), out, formats=("onnx",), progress=False)
    if cause is None:  # the exporter's own message, unchanged
        assert str(caught.value) == "ONNX export of Unlisted.forward.onnx failed: it could not"
    else:  # a full disk is said as for any file
        assert str(caught.value) == (f"cannot write Unlisted.forward.onnx into {out}: No space left on device; the "
                                     f"export stopped and left the folder as it was")
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "keep"])  # as it was: no staging folder


def test_diff_is_infinite_for_a_shape_mismatch_or_a_one_sided_nan() -> None:
    nan, inf = math.nan, math.inf
    assert _diff(torch.zeros(2), torch.zeros(3)) == inf
    assert _diff(torch.tensor([1.0, nan]), torch.tensor([1.0, 2.0])) == inf
    assert _diff(torch.tensor([nan, inf, 1.0]), torch.tensor([nan, inf, 1.25])) == 0.25
    assert _diff(torch.tensor([nan, 2.0]), torch.tensor([nan, 2.0])) == 0.0


# ------------------------------------------------------------------------------------------------ ONNX files
def test_to_onnx_without_the_exporter_says_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(onnx_io, "onnx_available", lambda: False)
    with pytest.raises(ExportError, match=r"^ONNX export needs onnx and onnxscript: pip install \"tactile-zoo\[export"):
        onnx_io.to_onnx(nn.Identity(), (torch.zeros(1),), tmp_path / "m.onnx", None, optimize=False)


@pytest.mark.parametrize(("error", "said"), [(RuntimeError("unsupported op aten::foo\n  at line 3"),
                                              "RuntimeError: unsupported op aten::foo"),
                                             (ValueError(""), "ValueError: ValueError")])
def test_an_exporter_failure_is_one_line_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         error: Exception, said: str) -> None:
    def export(*args: Any, **kwargs: Any) -> None:
        raise error

    monkeypatch.setattr(torch.onnx, "export", export)
    graph = SimpleNamespace(input_names=["x"], output_names=["y"])
    with pytest.raises(ExportError) as caught:
        onnx_io.to_onnx(graph, (torch.zeros(1),), tmp_path / "m.forward.onnx", None, optimize=False)
    assert str(caught.value) == f"ONNX export of m.forward.onnx failed: {said}"
    assert caught.value.__cause__ is error


def test_the_opset_of_a_file_onnx_cannot_read_is_unknown(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def load(path: str, load_external_data: bool = True) -> Any:
        raise ValueError(f"Error parsing message with type 'onnx.ModelProto' ({path})")

    monkeypatch.setitem(sys.modules, "onnx", SimpleNamespace(load=load))  # onnx's error, without importing it
    assert onnx_io.opset_of(tmp_path / "m.onnx") is None


def test_quiet_moves_printed_chatter_to_the_debug_log(capsys: pytest.CaptureFixture[str],
                                                      caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.DEBUG, logger="tactile_zoo.export.onnx_io"), onnx_io.quiet():
        print("Applied 3 of general pattern rewrite rules.")
    assert capsys.readouterr().out == ""
    assert "exporter stdout:\nApplied 3 of general pattern rewrite rules." in caplog.messages


# ------------------------------------------------------------------------------------------------ the folder
def _described(out: Path, text: str) -> ExportFolder:
    out.mkdir()
    (out / "m.forward.pt").write_bytes(b"")
    (out / "m.export.json").write_text(text)
    return ExportFolder(out)


@pytest.mark.parametrize("text", ["{not json", json.dumps({"format": "someone-else/1"}), json.dumps([1])])
def test_descriptions_an_export_did_not_write_make_no_export_folder(tmp_path: Path, text: str) -> None:
    out = _described(tmp_path / "out", text)
    assert not out.owned() and out.sets() == {}
    with pytest.raises(ConfigError, match="the folder holds other files"):
        out.check(["m.export.json"])


def test_an_older_versions_descriptions_make_an_export_folder(tmp_path: Path) -> None:
    out = _described(tmp_path / "out", json.dumps({"format": "tactile-zoo-export/1",
                                                   "forward": {"files": {"torchscript": "m.forward.pt"}}}))
    assert out.owned() and out.sets() == {"m": ["m.forward.pt", "m.export.json"]}


@pytest.mark.parametrize("marker", [{"format": "tactile-zoo-export-folder/9", "exports": {}},
                                    {"format": folder.FOLDER_FORMAT, "exports": ["m.forward.pt"]}, "{torn"])
def test_a_marker_of_another_format_is_not_ours(tmp_path: Path, marker: Any) -> None:
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / MARKER).write_text(marker if isinstance(marker, str) else json.dumps(marker))
    (tmp_path / "out" / "notes.txt").write_text("mine")
    assert not ExportFolder(tmp_path / "out").owned()
    with pytest.raises(ConfigError, match=f"--out {tmp_path / 'out'}: the folder holds other files"):
        ExportFolder(tmp_path / "out").check_owner()


def test_what_killed_exports_left_is_removed(tmp_path: Path) -> None:
    staging = tmp_path / ".tactile-zoo-export.abc.tmp"
    (staging / "inner").mkdir(parents=True)
    torn = tmp_path / f".{MARKER}.123.tmp"
    torn.write_text("{")
    assert sorted(ExportFolder(tmp_path).remove_stale()) == sorted([staging.name, torn.name])
    assert list(tmp_path.iterdir()) == []
    assert ExportFolder(tmp_path).remove_stale() == []


def test_write_file_never_overwrites_and_names_the_file(tmp_path: Path) -> None:
    write_file(tmp_path / "a.pt", b"1")
    with pytest.raises(OSError) as caught:
        write_file(tmp_path / "a.pt", b"2")
    assert caught.value.errno == errno.EEXIST and caught.value.filename == str(tmp_path / "a.pt")
    assert (tmp_path / "a.pt").read_bytes() == b"1"


def test_write_error_without_a_file_name_names_the_folder(tmp_path: Path) -> None:
    said = str(ExportFolder(tmp_path).write_error(OSError(errno.EFBIG, "File too large")))
    assert said == f"cannot write into {tmp_path}: File too large; the export stopped and left the folder as it was"


def test_without_flock_the_folder_is_not_locked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(folder, "fcntl", None)
    with ExportFolder(tmp_path).locked():
        holder = os.open(tmp_path, os.O_RDONLY)
        try:
            fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # free: nothing took it
        finally:
            os.close(holder)


def test_a_file_system_without_locks_goes_on_unserialised(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    def flock(fd: int, how: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(folder, "fcntl", SimpleNamespace(LOCK_EX=fcntl.LOCK_EX, LOCK_NB=fcntl.LOCK_NB, flock=flock))
    entered = False
    with caplog.at_level(logging.DEBUG, logger="tactile_zoo.export.folder"), ExportFolder(tmp_path).locked():
        entered = True
    assert entered and any("exports into it are not serialised" in m for m in caplog.messages)


def _hold_then(tmp_path: Path, caplog: pytest.LogCaptureFixture, meanwhile: Any) -> list[str]:
    """Hold the folder's lock while a thread enters :meth:`ExportFolder.locked`; once it says it waits, run
    ``meanwhile`` and release. Returns what the thread saw, in order."""
    seen: list[str] = []
    holder = os.open(tmp_path / "out", os.O_RDONLY)
    fcntl.flock(holder, fcntl.LOCK_EX)

    def export() -> None:
        with ExportFolder(tmp_path / "out").locked():
            seen.append("locked" if (tmp_path / "out").is_dir() else "no folder")

    thread = threading.Thread(target=export)
    with caplog.at_level(logging.INFO, logger="tactile_zoo.export.folder"):
        thread.start()
        deadline = time.monotonic() + 30
        while not any("waiting for it to finish" in m for m in caplog.messages) and time.monotonic() < deadline:
            time.sleep(0.01)
        seen.append("waiting" if any("waiting for it to finish" in m for m in caplog.messages) else "not waiting")
        time.sleep(0.05)
        if thread.is_alive():  # it waits for the lock, not yet in the block
            seen.append("still waiting")
        meanwhile()
        os.close(holder)
        thread.join(30)
    return seen


def test_a_second_export_waits_for_the_lock(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "out").mkdir()
    assert _hold_then(tmp_path, caplog, lambda: None) == ["waiting", "still waiting", "locked"]


def test_a_folder_removed_while_waiting_is_made_again_and_locked(tmp_path: Path,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "out").mkdir()
    assert _hold_then(tmp_path, caplog, lambda: (tmp_path / "out").rmdir()) == ["waiting", "still waiting", "locked"]
    assert (tmp_path / "out").is_dir()
