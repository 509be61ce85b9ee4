"""``tactile-zoo export``: the files and their description from random, pretrained and checkpoint weights, and one
clear error for a bad argument."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from export_cases import one_onnx_registry
from weights_helpers import DATA_ARGS, Trained

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.engine import save_checkpoint
from tactile_zoo.export import onnx_available, onnxruntime_available
from tactile_zoo.export.folder import MARKER

ONNX = onnx_available() and onnxruntime_available()


@pytest.fixture(autouse=True)
def _one_onnx_registry() -> Iterator[None]:
    """The module's seven ONNX exports (in this process) share the exporter's operator registry, one per opset:
    export_cases.one_onnx_registry (the same files, 0.5 CPU-s less for each export after the first)."""
    with one_onnx_registry():
        yield


def test_export_writes_every_file_and_the_description(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Random weights for a simulator's spec (no data read): forward and step, in both formats where ONNX is
    installed; the printed lines name every file and its check."""
    out = tmp_path / "robot"
    formats = "torchscript,onnx" if ONNX else "torchscript"
    assert main(["export", "cnn_lstm", "--spec-from", "sim_biotac_slip", "--out", str(out), "--steps", "6",
                 "--format", formats, "--seed", "4"]) == 0
    printed = capsys.readouterr().out
    suffixes = ("pt", "onnx") if ONNX else ("pt",)
    want = {f"cnn_lstm.{graph}.{s}" for graph in ("forward", "step") for s in suffixes} | {"cnn_lstm.export.json"}
    assert {p.name for p in out.iterdir()} == want | {MARKER}
    assert all(name in printed for name in want)
    desc = json.loads((out / "cnn_lstm.export.json").read_text())
    assert desc["weights"] is None and desc["initialisation"] == {"random": True, "seed": 4}
    assert desc["spec"]["name"] == "sim_biotac_slip" and desc["preprocessing"]["dataset"] == "sim_biotac_slip"
    assert desc["forward"]["inputs"] == [{"name": "x", "shape": [1, 6, 24, 1], "dtype": "float32"}]
    assert [s["path"] for s in desc["step"]["state"]] == ["core[0]", "core[1]"]  # LSTM (h, c): bins of one frame
    assert all(v["ok"] for k, v in desc["checks"].items() if k != "tolerance")
    # the same seed gives the same weights: the exported forward is the eager model's
    spec = tz.load_dataset("sim_biotac_slip", split="test").spec
    assert desc["spec"] == spec.to_dict()  # the spec read from the registry is the dataset's own
    torch.manual_seed(4)
    model = tz.create_model("cnn_lstm", spec).eval()
    x = torch.rand(1, 6, 24, 1)
    with torch.no_grad():
        assert torch.equal(torch.jit.load(str(out / "cnn_lstm.forward.pt"))(x), model(x))


def test_export_of_local_pretrained_weights(trained: Trained, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """--weights/--manifest as predict takes them: the description carries the weights and their preprocessing,
    and the exported forward gives the trained model's logits."""
    assert main(["export", "cnn_lstm", "--weights", str(trained.file), "--manifest", str(trained.manifest),
                 "--out", str(tmp_path), "--format", "torchscript", "--json"]) == 0
    desc = json.loads(capsys.readouterr().out)
    assert desc["weights"]["tag"] == trained.entry.tag and desc["weights"]["sha256"] == trained.entry.sha256
    assert desc["preprocessing"]["dataset_kwargs"] == DATA_ARGS
    assert desc["spec"] == trained.entry.spec
    forward = torch.jit.load(str(tmp_path / "cnn_lstm.forward.pt"))
    with torch.no_grad():
        logits = forward(trained.test.x[:1], trained.test.g[:1])
    assert torch.allclose(logits, trained.logits[:1], rtol=0, atol=1e-5)


def test_export_of_a_train_checkpoint_without_step(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    spec = tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=1,
                           num_steps=8).spec
    torch.manual_seed(0)
    model = tz.create_model("sgnet", spec, graph_channels=4, hidden=[8])
    config = {"model": "sgnet", "hparams": {"graph_channels": 4, "hidden": [8]}, "dataset": "sim_biotac_slip",
              "dataset_kwargs": {"num_steps": 8}, "seed": 0, "recipe": {"loss": "mse_rate"},
              "spec": spec.to_dict()}
    ckpt = save_checkpoint(tmp_path / "sgnet.pt", model, config)
    out = tmp_path / "out"
    assert main(["export", str(ckpt), "--out", str(out), "--format", "torchscript", "--no-step"]) == 0
    assert {p.name for p in out.iterdir()} == {"sgnet.forward.pt", "sgnet.export.json", MARKER}
    desc = json.loads((out / "sgnet.export.json").read_text())
    assert desc["weights"]["checkpoint"] == str(ckpt) and desc["step"] is None and desc["scores"] == "spike_rates"
    assert desc["preprocessing"]["dataset_kwargs"] == {"num_steps": 8}


def test_a_model_that_does_not_stream_exports_its_forward(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["export", "dcnn", "--spec-from", "sim_biotac_slip", "--out", str(tmp_path), "--format",
                 "torchscript"]) == 0
    assert "does not stream" in capsys.readouterr().out
    assert {p.name for p in tmp_path.iterdir()} == {"dcnn.forward.pt", "dcnn.export.json", MARKER}


@pytest.mark.parametrize(("argv", "named"), [
    (["sgnet", "--spec-from", "sim_evtouch", "--format", "pdf"], "--format"),
    (["sgnet", "--spec-from", "sim_evtouch", "--format", ""], "--format"),
    (["sgnet", "--spec-from", "sim_evtouch", "--batch", "0"], "--batch"),
    (["sgnet", "--spec-from", "sim_evtouch", "--steps", "ten"], "--steps"),
    (["sgnet", "--spec-from", "sim_evtouch", "--opset", "-3"], "--opset"),
    (["sgnet"], "which weights"),
    (["sgnet", "--spec-from", "sim_evtouch", "--pretrained", "ev_objects"], "--spec-from"),
    (["no_such_model", "--spec-from", "sim_evtouch"], "no_such_model"),
    (["sgnet", "--spec-from", "no_such_data"], "no_such_data"),
    (["missing.pt"], "missing.pt"),
    (["missing.pt", "--spec-from", "sim_evtouch"], "checkpoint"),
])
def test_a_bad_argument_gets_one_line_naming_it(argv: list[str], named: str, tmp_path: Path,
                                                capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    assert main(["export", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tactile-zoo: error:") and named in err[0], err
    assert not out.exists()  # nothing written


# ------------------------------------------------------------------------------------------- issue 28: opset, folder
#: CNN-LSTM: the cheapest streaming model to export (its forward's opset probe takes 0.6 CPU-s, SGnet's 1.6)
_SMALL = ["cnn_lstm", "--spec-from", "sim_biotac_slip", "--steps", "4", "--format", "onnx"]


def _opsets(path: Path) -> list[tuple[str, int]]:
    import onnx

    return [(o.domain, int(o.version)) for o in onnx.load(str(path)).opset_import if o.domain in ("", "ai.onnx")]


@pytest.mark.skipif(not ONNX, reason="needs onnx, onnxscript and onnxruntime")
def test_export_writes_the_opset_asked_for(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Both files converted (CNN-LSTM: a streaming model whose two ONNX exports take half SGnet's time)."""
    out = tmp_path / "out"
    assert main(["export", *_SMALL, "--opset", "19", "--out", str(out)]) == 0
    err = capsys.readouterr().err.splitlines()  # nothing from the exporters on success, only export's progress
    assert err and all(line.startswith("export cnn_lstm: ") for line in err), err
    files = sorted(out.glob("*.onnx"))
    assert [f.name for f in files] == ["cnn_lstm.forward.onnx", "cnn_lstm.step.onnx"]
    assert all(_opsets(f) == [("", 19)] for f in files)
    assert json.loads((out / "cnn_lstm.export.json").read_text())["exporters"]["onnx_opset"] == 19


@pytest.mark.skipif(not ONNX, reason="needs onnx, onnxscript and onnxruntime")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_an_opset_the_exporter_cannot_write_is_refused_naming_the_range(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    """Issue 28: ``--opset 13`` wrote an opset-18 file, said 18 in export.json, exited 0 and left the version
    converter's traceback on stderr. Now: exit 2, one line naming the supported range, and no file at the wrong
    opset (next test); an opset beyond what onnx knows is refused before anything is written."""
    import onnx

    newest = onnx.defs.onnx_opset_version()
    out = tmp_path / "out"
    assert main(["export", *_SMALL, "--opset", str(newest + 12), "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"tactile-zoo: error: --opset {newest + 12} is not supported: choose 18 to {newest} (older ones "
                   f"down to 7 only where onnx's version converter can convert the graph)"]
    assert not out.exists()


@pytest.mark.skipif(not ONNX, reason="needs onnx, onnxscript and onnxruntime")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_an_opset_the_graph_cannot_be_converted_to_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import onnx

    newest = onnx.defs.onnx_opset_version()
    out = tmp_path / "out"
    assert main(["export", *_SMALL, "--no-step", "--opset", "13", "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"tactile-zoo: error: ONNX export of cnn_lstm.forward.onnx at opset 13 failed: onnx's version "
                   f"converter could not convert the graph (it stayed at opset 18); supported opsets are 18 to "
                   f"{newest}"]
    assert not out.exists()  # neither the opset-18 file nor a description, nor the folder (issue 38: refused
    # before the long export, by a short forward the converter cannot convert either)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_a_read_only_out_folder_is_named(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Issue 28: only torch's internal message ("File ... cannot be opened") said what went wrong. Root ignores
    permission bits, so for root the folder is made immutable instead (chattr +i)."""
    import os
    import stat
    import subprocess

    out = tmp_path / "robot"
    out.mkdir()
    out.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
    immutable = os.geteuid() == 0 and subprocess.run(["chattr", "+i", str(out)], capture_output=True).returncode == 0
    try:
        try:
            (out / "probe").touch()
        except OSError:
            pass
        else:
            pytest.skip("cannot make a folder read-only here (root without chattr)")
        assert main(["export", "dcnn", "--spec-from", "sim_biotac_slip", "--format", "torchscript", "--out",
                     str(out)]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1, err
        # the output-folder rule's one message (bench --out says the same)
        assert err[0].startswith(f"tactile-zoo: error: --out {out}: cannot write there (")
        assert list(out.iterdir()) == []
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(out)], check=True)
        out.chmod(stat.S_IRWXU)
