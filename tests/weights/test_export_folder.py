"""``export --out`` (issue 38, items 11 and 12): the output-folder rule bench has (a marker; a folder holding files but
no marker refused by name; a model's files replaced as one set), and its arguments checked before any work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tactile_zoo import export as export_pkg
from tactile_zoo.cli import main
from tactile_zoo.export import MAX_STEPS
from tactile_zoo.export.folder import MARKER

# small and quick: TorchScript only, 4 frames of a simulator's spec, random weights
SGNET = ["export", "sgnet", "--spec-from", "sim_biotac_slip", "--steps", "4", "--format", "torchscript"]
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # SGnet's own torch.jit.script use


def _err(capsys: pytest.CaptureFixture) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if not line.startswith("export ")]


def _names(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()}


def test_a_folder_holding_the_users_files_is_refused_by_name(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The user's own ``sgnet.forward.pt`` was silently overwritten."""
    out = tmp_path / "robot"
    out.mkdir()
    (out / "sgnet.forward.pt").write_bytes(b"mine")
    assert main([*SGNET, "--out", str(out)]) == 2
    assert _err(capsys) == [f"tactile-zoo: error: --out {out}: the folder holds other files (sgnet.forward.pt) and is "
                            f"not a tactile-zoo export folder (no {MARKER} marker); choose a new or empty folder, or "
                            f"an export folder to replace a model's files in"]
    assert _names(out) == {"sgnet.forward.pt"} and (out / "sgnet.forward.pt").read_bytes() == b"mine"


def test_a_file_no_export_wrote_is_not_overwritten_in_an_export_folder(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "robot"
    assert main(["export", "dcnn", "--spec-from", "sim_biotac_slip", "--format", "torchscript", "--out",
                 str(out)]) == 0
    (out / "sgnet.forward.pt").write_bytes(b"mine")
    capsys.readouterr()
    assert main([*SGNET, "--out", str(out)]) == 2
    err = _err(capsys)
    assert len(err) == 1 and err[0].startswith(f"tactile-zoo: error: --out {out}: sgnet.forward.pt is not from an "
                                               f"export ({MARKER} does not list it)"), err
    assert (out / "sgnet.forward.pt").read_bytes() == b"mine"


def test_a_second_export_replaces_the_models_files_as_one_set(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A second export of other weights left the first one's files beside a description of the second. Now the
    model's previous set goes, whatever it held (here its step files), and another model's set stays."""
    out = tmp_path / "robot"
    assert main([*SGNET, "--out", str(out)]) == 0  # sim_biotac_slip: forward and step
    assert main(["export", "dcnn", "--spec-from", "sim_biotac_slip", "--format", "torchscript", "--out",
                 str(out)]) == 0
    assert "sgnet.step.pt" in _names(out)
    assert main(["export", "sgnet", "--spec-from", "sim_evtouch", "--steps", "4", "--format", "torchscript",
                 "--no-step", "--out", str(out)]) == 0
    assert _names(out) == {"sgnet.forward.pt", "sgnet.export.json", "dcnn.forward.pt", "dcnn.export.json", MARKER}
    desc = json.loads((out / "sgnet.export.json").read_text())
    assert desc["spec"]["name"] == "sim_evtouch" and desc["step"] is None
    marker = json.loads((out / MARKER).read_text())
    assert marker["exports"] == {"sgnet": ["sgnet.forward.pt", "sgnet.export.json"],
                                 "dcnn": ["dcnn.forward.pt", "dcnn.export.json"]}


def test_a_failed_export_leaves_the_folder_as_it_was(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "robot"
    assert main([*SGNET, "--out", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr("tactile_zoo.export.exporter._trace", broken)
    assert main([*SGNET, "--no-step", "--out", str(out)]) == 2
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no staging folder left either
    assert main([*SGNET, "--out", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()  # a folder the failed export created is removed again


def test_a_folder_an_older_version_exported_into_is_adopted(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "robot"
    assert main([*SGNET, "--out", str(out)]) == 0
    (out / MARKER).unlink()  # as written before the marker existed
    assert main([*SGNET, "--no-step", "--out", str(out)]) == 0
    assert _names(out) == {"sgnet.forward.pt", "sgnet.export.json", MARKER}


# ---------------------------------------------------------------------------------------- item 11: checked first
@pytest.mark.parametrize(("argv", "message"), [
    (["--steps", "100000000"], f"--steps 100000000 is above the cap of {MAX_STEPS} frames: the forward is unrolled "
                               f"over every frame"),
    (["--batch", "100000000"], "export batch 100000000 x steps 100 needs an example input of 2905.7 GiB (78 float32 "
                               "values per frame), above the 1 GiB an export allows"),
])
def test_a_shape_that_cannot_fit_in_memory_is_refused_before_any_work(argv: list[str], message: str, tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    """``--steps 100000000`` was a traceback (cannot allocate 31 GB) after loading everything."""
    out = tmp_path / "robot"
    assert main(["export", "sgnet", "--spec-from", "sim_evtouch", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"tactile-zoo: error: {message}"), err
    assert not out.exists()


@pytest.mark.skipif(not (export_pkg.onnx_available() and export_pkg.onnxruntime_available()),
                    reason="needs onnx, onnxscript and onnxruntime")
def test_an_opset_the_forward_cannot_reach_is_refused_before_the_long_export(tmp_path: Path,
                                                                             capsys: pytest.CaptureFixture,
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """``--opset 15`` was refused after the whole forward was traced (70 s on Ev-Objects), leaving
    ``sgnet.forward.pt`` behind. A short forward tells the converter's verdict first; nothing is traced in full.
    CNN-LSTM here: its forward cannot be converted either, and its short forward costs a third of SGnet's."""
    def traced(*args: object, **kwargs: object) -> None:
        raise AssertionError("the full forward was traced before the opset was known to work")

    monkeypatch.setattr("tactile_zoo.export.exporter._trace", traced)
    out = tmp_path / "robot"
    assert main(["export", "cnn_lstm", "--spec-from", "sim_biotac_slip", "--steps", "8", "--no-step", "--opset", "15",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "at opset 15 failed: onnx's version converter could not convert the graph" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize(("value", "says"), [
    ("rec/text.npy", "rec/text.npy exists but is a .npy file (a recording?"),
    ("rec/missing.safetensors", "rec/missing.safetensors does not exist"),
    ("rec", "rec is a folder"),
])
def test_a_path_given_to_weights_says_what_the_flag_expects(value: str, says: str, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """``--weights rec/text.npy`` answered "no installed weights tagged 'rec/text.npy'"."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / "text.npy").write_bytes(b"\x93NUMPY")
    assert main(["export", "sgnet", "--weights", value, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"tactile-zoo: error: --weights expects a .safetensors weights file (described by --manifest "
                   f"FILE.json, or by FILE.json or manifest.json next to it; installed weights go by --pretrained "
                   f"DATASET|TAG); {says}" + ("" if "(a recording" not in says else
                                               " predict and stream take recordings as FILE arguments or --file)")]
