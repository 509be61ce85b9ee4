"""``tactile-zoo weights --manifest``, ``predict --weights --manifest`` and ``stream --weights --file``: local weights
on the command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from weights_helpers import DATASET, MODEL, Trained, sample_table, write_csv

import tactile_zoo as tz
from tactile_zoo.cli import main


def _local(trained: Trained) -> list[str]:
    return ["--weights", str(trained.file), "--manifest", str(trained.manifest)]


def test_weights_lists_a_manifest(trained: Trained, capsys: pytest.CaptureFixture) -> None:
    assert main(["weights", "--manifest", str(trained.manifest)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["tag", "model", "dataset", "test", "acc", "size", "source"]
    row = lines[1].split()
    kb = f"{trained.file.stat().st_size / 1e3:.1f}"
    assert row[:6] == ["cnn_lstm.full_sim_uskin_textures", MODEL, DATASET, f"{trained.entry.accuracy:.4f}", kb, "kB"]
    assert row[6] == str(trained.manifest)
    assert main(["weights", "--manifest", str(trained.manifest), "sgnet.*"]) == 0
    assert "no weights match 'sgnet.*'" in capsys.readouterr().out
    assert main(["weights", "--manifest", str(trained.manifest), "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["weights"][0]
    assert listed["sha256"] == trained.entry.sha256 and listed["hparams"] == trained.entry.hparams


def test_predict_prints_the_top_classes_of_each_file(trained: Trained, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    result = tz.evaluate(trained.model, trained.test)
    first = write_csv(tmp_path / "grasp0.csv", sample_table(trained.test, 0))
    second = tmp_path / "grasp1.npy"
    np.save(second, np.concatenate([sample_table(trained.test, 1)] * 2))  # 24 rows: cut to the first 12
    assert main(["predict", MODEL, *_local(trained), str(first), str(second), "--json", "--top-k", "4"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [p["index"] for p in out["predictions"]] == result.predictions[:2]
    assert [p["file"] for p in out["predictions"]] == [str(first), str(second)]
    assert [p["length"] for p in out["predictions"]] == ["as recorded", "cropped"]
    assert out["predictions"][1]["steps_read"] == 24 and len(out["predictions"][0]["top_k"]) == 4
    probs = [p["top_k"][0]["probability"] for p in out["predictions"]]
    assert np.allclose(probs, [max(row) for row in result.probabilities[:2]], atol=1e-6)
    assert main(["predict", MODEL, *_local(trained), str(first), str(second), "--top-k", "2"]) == 0
    text = capsys.readouterr().out.splitlines()
    names = trained.test.spec.class_names
    assert text[0].startswith(f"{MODEL} with weights cnn_lstm.full_sim_uskin_textures (trained on {DATASET}")
    assert text[1] == "note: trained by the test suite"
    assert text[2] == f"preprocessing: none ({DATASET} feeds recordings as they are)"
    assert text[3] == f"{first} (12 steps)" and text[6] == f"{second} (24 steps, cropped to 12)"
    assert text[4].split()[:2] == ["1", names[result.predictions[0]]] and text[5].split()[0] == "2"
    assert len(text) == 9


def test_predict_errors_are_one_line_naming_the_file(trained: Trained, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    bad = tmp_path / "bad.npy"
    np.save(bad, sample_table(trained.test, 0)[:, 3:])
    capsys.readouterr()
    assert main(["predict", MODEL, *_local(trained), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"tactile-zoo: error: {bad}: 185 columns, expected 188") and "\n" not in err
    assert main(["predict", MODEL, str(bad)]) == 2
    assert "which weights? give --pretrained" in capsys.readouterr().err
    assert main(["predict", MODEL, "--pretrained", DATASET, *_local(trained), str(bad)]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["predict", "sgnet", *_local(trained), str(bad)]) == 2
    assert "has no entry for" in capsys.readouterr().err


def test_stream_replays_a_recording_file_with_local_weights(trained: Trained, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    exact = tmp_path / "exact.npy"
    np.save(exact, sample_table(trained.test, 2))
    capsys.readouterr()
    assert main(["stream", MODEL, *_local(trained), "--file", str(exact), "--json"]) == 0
    trace = json.loads(capsys.readouterr().out)
    assert trace["file"] == str(exact) and trace["true_class"] is None and trace["num_steps"] == 12
    assert all(step["correct"] is None for step in trace["steps"])
    assert torch.allclose(torch.tensor(trace["final_scores"]), trained.logits[2], atol=1e-5)  # the full forward
    longer = write_csv(tmp_path / "longer.csv", np.concatenate([sample_table(trained.test, 2)] * 2))
    assert main(["stream", MODEL, *_local(trained), "--file", str(longer), "--every", "6"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{MODEL} (weights cnn_lstm.full_sim_uskin_textures) on {longer}: 24 steps")
    assert out[1] == f"preprocessing: none ({DATASET} feeds recordings as they are)"
    assert [line.split()[0] for line in out[3:7]] == ["6", "12", "18", "24"]  # a stream reads every row
    assert out[7].startswith("final prediction: ") and "true class of a file is unknown" in out[7]
    assert main(["stream", MODEL, *_local(trained), "--index", "0", "--file", str(exact)]) == 2
    assert "give --index N (a sample of the dataset) or --file FILE" in capsys.readouterr().err


def test_stream_replays_a_file_through_a_train_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.engine import save_checkpoint

    test = tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=1, num_steps=6)
    torch.manual_seed(0)
    model = tz.create_model("sgnet", test.spec, graph_channels=4, hidden=[8])
    config = {"model": "sgnet", "hparams": {"graph_channels": 4, "hidden": [8]}, "dataset": "sim_biotac_slip",
              "dataset_kwargs": {}, "recipe": {"loss": "mse_rate"}, "spec": test.spec.to_dict()}
    ckpt = save_checkpoint(tmp_path / "sgnet.pt", model, config)
    recording = tmp_path / "r.npy"
    np.save(recording, sample_table(test, 0))
    capsys.readouterr()
    assert main(["stream", str(ckpt), "--file", str(recording), "--json"]) == 0
    trace = json.loads(capsys.readouterr().out)
    assert trace["checkpoint"] == str(ckpt) and trace["weights"] is None and trace["num_steps"] == 6
    assert trace["frame_period_s"] == pytest.approx(0.01)  # the dataset's 100 Hz, from its class
    expected = model.eval()(test.x[:1], None)[0]
    assert torch.allclose(torch.tensor(trace["final_scores"]), expected, atol=1e-6)


def test_predict_answers_each_good_file_and_lists_the_bad_ones(trained: Trained, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture) -> None:
    """Issue 28: ``predict good.npy nan.npy`` refused the whole batch. Now the good file is answered, each bad one
    gets one line naming it and what is wrong, and the exit status is 1 (2 when no file could be read)."""
    good = tmp_path / "good.npy"
    np.save(good, sample_table(trained.test, 0))
    table = sample_table(trained.test, 1)
    table[3, 5] = np.nan
    nan = tmp_path / "nan.npy"
    np.save(nan, table)
    missing = tmp_path / "missing.csv"
    capsys.readouterr()
    assert main(["predict", MODEL, *_local(trained), str(good), str(nan), str(missing)]) == 1
    out, err = capsys.readouterr()
    assert err.splitlines() == [f"tactile-zoo: error: {nan}: index (3, 5): non-finite reading nan (1 non-finite "
                                f"value(s) in all, as float32); NaN/Inf readings and values beyond float32 are refused",
                                f"tactile-zoo: error: {missing}: file not found"]
    lines = out.splitlines()
    assert lines[3] == f"{good} (12 steps)" and len(lines) == 3 + 1 + 3 + 1
    assert lines[-1] == f"2 of 3 file(s) not answered: {nan}, {missing} (why: the error lines on stderr)"
    assert main(["predict", MODEL, *_local(trained), str(good), str(nan), "--json"]) == 1
    out, err = capsys.readouterr()
    listed = json.loads(out)
    assert [p["file"] for p in listed["predictions"]] == [str(good)]
    assert listed["refused"] == [{"file": str(nan), "error": err.splitlines()[0].removeprefix("tactile-zoo: error: ")}]
    assert main(["predict", MODEL, *_local(trained), str(nan), str(missing)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 2
