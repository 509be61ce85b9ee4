"""Issue 38, what ``predict`` and ``stream --file`` do with their inputs: values that overflow float32 are refused by
file, row and column (not answered with p = nan); any number of files is read and classified in bounded batches; and
pretrained weights' preprocessing (BioTac-DoS's normalisation) is applied to a raw recording by default, said in the
output, and turned off by ``--raw`` / ``raw=True``. The real BioTac-DoS file, with the shipped pack, is checked in
``test_shipped_weights.py``."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from weights_helpers import MODEL, Trained, sample_table, write_csv

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.data.datasets import BioTacDoS
from tactile_zoo.data.datasets.biotac_dos import CLASSES, normalize_recording
from tactile_zoo.errors import DatasetError
from tactile_zoo.weights import WeightEntry, entry_preprocessing, iter_predict, read_recording

engine_evaluate = importlib.import_module("tactile_zoo.engine.evaluate")  # the module (the package exports a function)


def _local(trained: Trained) -> list[str]:
    return ["--weights", str(trained.file), "--manifest", str(trained.manifest)]


# ----------------------------------------------------------------------------------------------- item 4: float32
def test_a_value_beyond_float32_is_refused_not_answered_with_nan(trained: Trained, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture) -> None:
    table = sample_table(trained.test, 0).astype(np.float64)
    table[6, 2] = 1e300  # finite in float64, inf in float32, NaN scores in the model
    huge = write_csv(tmp_path / "huge.csv", table)
    with pytest.raises(DatasetError, match=r"huge.csv: line 8, column 3: reading 1e\+300 is beyond float32's range"):
        tz.predict(trained.model, [huge])
    np.save(tmp_path / "huge.npy", table)
    with pytest.raises(DatasetError, match=r"huge.npy: index \(6, 2\): reading 1e\+300 is beyond float32's range"):
        tz.predict(trained.model, [tmp_path / "huge.npy"])
    with pytest.raises(DatasetError, match=r"<array 0>: index \(6, 2\): reading 1e\+300"):
        tz.predict(trained.model, [table])
    capsys.readouterr()
    assert main(["predict", MODEL, *_local(trained), str(huge)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1 and f"{huge}: line 8, column 3: reading 1e+300" in err
    assert main(["stream", MODEL, *_local(trained), "--file", str(huge)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.splitlines()) == 1 and f"{huge}: line 8, column 3: reading 1e+300" in err


# ----------------------------------------------------------------------------------------------- item 15: batches
def test_inputs_are_read_and_classified_in_bounded_batches(trained: Trained, tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """No more than ``batch_size`` recordings are held (read, stacked, run) at once, whatever the number of files;
    the answers are those of one big batch."""
    files = []
    for i in range(len(trained.test)):
        files.append(tmp_path / f"s{i}.npy")
        np.save(files[-1], sample_table(trained.test, i))
    whole = tz.predict(trained.model, files, batch_size=len(files))
    seen: list[int] = []
    real = engine_evaluate.predict_scores

    def counting(model: torch.nn.Module, x: torch.Tensor, *args: object, **kwargs: object) -> torch.Tensor:
        seen.append(int(x.shape[0]))
        return real(model, x, *args, **kwargs)

    monkeypatch.setattr(engine_evaluate, "predict_scores", counting)
    batched = tz.predict(trained.model, files, batch_size=3)
    assert seen and max(seen) <= 3 and sum(seen) == len(files)
    assert [p.index for p in batched] == [p.index for p in whole]
    assert np.allclose([p.probabilities for p in batched], [p.probabilities for p in whole], atol=1e-6)
    seen.clear()
    answers = iter_predict(trained.model, files, batch_size=4)
    first = next(answers)  # the first answer comes after one batch was read, not all of them
    assert seen == [4] and first.source == str(files[0])
    assert [p.index for p in [first, *answers]] == [p.index for p in whole]
    assert tz.predict(trained.model, files).__len__() == len(files)  # the default batch


# ----------------------------------------------------------------------------------------------- item 16: preprocessing
HEADER = ",".join(f"ff_e{i}" for i in range(1, 25))


def _raw_biotac(seed: int, rows: int = 25) -> np.ndarray:
    """Raw electrode values as the release has them (about 1900-3750, dropping under contact)."""
    rng = np.random.default_rng(seed)
    drop = np.cumsum(rng.integers(0, 40, size=(rows, 24)), axis=0)
    return np.clip(rng.integers(3000, 3700, size=24) - drop, 1900, 3750).astype(np.float64)


def _write_raw(path: Path, table: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join([HEADER] + [",".join(str(int(v)) for v in row) for row in table]) + "\n")
    return path


def _pretrained_on_biotac(dataset_kwargs: dict[str, object], window: int) -> torch.nn.Module:
    """A small model that says it holds weights trained on BioTac-DoS with ``dataset_kwargs`` (as loading pretrained
    weights sets ``zoo_pretrained``); its weights are seeded, not trained: only what it is fed matters here."""
    spec = tz.DatasetSpec("biotac_dos", 7, CLASSES, window, 24, 1, 0, tz.get_sensor("biotac_sp")).to_dict()
    entry = WeightEntry(tag="cnn_lstm.full_biotac_dos", model="cnn_lstm", dataset="biotac_dos", spec=spec,
                        sha256="0" * 64, dataset_kwargs=dataset_kwargs)
    torch.manual_seed(0)
    model = tz.create_model("cnn_lstm", entry.dataset_spec(), conv_channels=[4, 8], frame_features=12, hidden=12)
    model.zoo_pretrained = entry
    return model.eval()


@pytest.mark.parametrize(("kwargs", "window"), [({"normalize": "minmax", "window": 10}, 10),
                                                ({"window": 5}, 5)])  # baseline: 10 readings, more than the window
def test_pretrained_weights_preprocess_a_raw_recording_as_their_dataset_does(tmp_path: Path, kwargs: dict[str, object],
                                                                             window: int) -> None:
    """A release file read by ``predict`` gives exactly the loader's first window of that recording; ``raw=True``
    feeds the file as read; both say what they did."""
    home = tmp_path / "home"
    for c in CLASSES:
        for i, obj in enumerate(("pen", "case", "sponge", "hd", "bottle", "brush", "plate")):
            _write_raw(home / "biotac_dos" / "raw" / "csvs" / c / f"{obj}{i}.csv", _raw_biotac(len(c) * 10 + i))
    ds = BioTacDoS(root=home, **kwargs)  # every window of every recording
    path = home / "biotac_dos" / "raw" / "csvs" / "s" / "bottle4.csv"
    rec_index = [p for c in CLASSES for p in sorted((home / "biotac_dos" / "raw" / "csvs" / c).iterdir())].index(path)
    loader_first = ds.x[ds.groups == rec_index][0]  # (W, 24, 1)
    model = _pretrained_on_biotac(kwargs, window)
    applied = entry_preprocessing(model.zoo_pretrained)
    name = f"biotac_dos normalize={kwargs.get('normalize', 'baseline')!r}"
    assert applied is not None and applied.name == name
    read = read_recording(path, model.spec, preprocessing=applied)
    assert torch.allclose(read.x, loader_first, atol=1e-6) and read.preprocessing == name
    answer = tz.predict(model, [path])[0]
    expected = engine_evaluate.predict_scores(model, loader_first[None], None)[0]
    assert answer.preprocessing == name and answer.index == int(expected.argmax())
    assert np.allclose(answer.probabilities, torch.softmax(expected, -1).numpy(), atol=1e-5)
    raw = tz.predict(model, [path], raw=True)[0]
    assert raw.preprocessing is None and not np.allclose(raw.probabilities, answer.probabilities, atol=1e-3)
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    by_hand = normalize_recording(table, kwargs.get("normalize", "baseline"), 10, 1000.0, "x")[:window]
    assert tz.predict(model, [by_hand], raw=True)[0].probabilities == pytest.approx(answer.probabilities, abs=1e-6)
    if window < 10:  # the baseline needs 10 readings even for a 5-step window
        short = _write_raw(tmp_path / "short.csv", table[:window - 1])
        with pytest.raises(DatasetError, match="short.csv: .*fewer than the 10 baseline readings"):
            tz.predict(model, [short], length="pad")


def test_the_cli_says_which_preprocessing_it_applied_and_raw_turns_it_off(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch,
                                                                          capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.cli import weights as cli_weights

    model = _pretrained_on_biotac({"normalize": "minmax", "window": 10}, 10)
    monkeypatch.setattr(cli_weights, "pretrained_model", lambda name, args: model)
    path = _write_raw(tmp_path / "grasp.csv", _raw_biotac(3))
    assert main(["predict", "cnn_lstm", "--pretrained", "biotac_dos", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == ("preprocessing: biotac_dos normalize='minmax': each reading scaled by its own range over the "
                        "24 electrodes, (max E - E) / (max E - min E) (the weights' own, from their manifest; --raw "
                        "turns it off)")
    assert main(["predict", "cnn_lstm", "--pretrained", "biotac_dos", str(path), "--raw", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["preprocessing"] is None and out["predictions"][0]["preprocessing"] is None
    assert main(["predict", "cnn_lstm", "--pretrained", "biotac_dos", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["preprocessing"] == out["predictions"][0]["preprocessing"] == "biotac_dos normalize='minmax'"


def test_stream_takes_raw_only_with_a_file(trained: Trained, capsys: pytest.CaptureFixture) -> None:
    capsys.readouterr()
    assert main(["stream", MODEL, *_local(trained), "--index", "0", "--raw"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "tactile-zoo: error: --raw goes with --file (your recording): a dataset sample is already what its loader "
        "made of the raw recording"]


def _checkpoint_on_biotac(tmp_path: Path, dataset_kwargs: dict[str, object], window: int, recorded: bool) -> Path:
    """A ``train --save`` checkpoint of a model trained on BioTac-DoS with ``dataset_kwargs``; ``recorded``: with the
    ``preprocessing`` that ``train --save`` records (else as a checkpoint from before it did)."""
    from tactile_zoo.engine import save_checkpoint
    from tactile_zoo.weights import preprocessing_of

    model = _pretrained_on_biotac(dataset_kwargs, window)
    spec = model.zoo_pretrained.spec
    hparams = {"conv_channels": [4, 8], "frame_features": 12, "hidden": 12}
    config = {"model": "cnn_lstm", "hparams": hparams, "dataset": "biotac_dos", "dataset_kwargs": dataset_kwargs,
              "fold": 0, "seed": 0, "recipe": {"loss": "ce"}, "spec": dict(spec)}
    if recorded:
        config["preprocessing"] = preprocessing_of("cnn_lstm", "biotac_dos", spec, hparams, dataset_kwargs)
    return save_checkpoint(tmp_path / "biotac.pt", model, config)


@pytest.mark.parametrize("recorded", [True, False])
def test_a_checkpoint_preprocesses_a_raw_recording_as_its_dataset_did(tmp_path: Path, recorded: bool,
                                                                       capsys: pytest.CaptureFixture) -> None:
    """Issue 49 item 7: a checkpoint carries its dataset's preprocessing as weights do; ``stream --file`` and
    ``predict`` (Python, and the command on a checkpoint file) apply it, and ``--raw`` / ``raw=True`` turn it off."""
    from tactile_zoo.engine import build_from_checkpoint, load_checkpoint

    kwargs = {"normalize": "minmax", "window": 10}
    ckpt = _checkpoint_on_biotac(tmp_path, kwargs, 10, recorded)
    raw_file = _write_raw(tmp_path / "grasp.csv", _raw_biotac(3))
    by_hand = normalize_recording(np.loadtxt(raw_file, delimiter=",", skiprows=1), "minmax", 10, 1000.0, "x")
    done = tmp_path / "done.npy"
    np.save(done, by_hand)
    blob = load_checkpoint(ckpt)
    model = build_from_checkpoint(blob, tz.DatasetSpec.from_dict(blob["config"]["spec"]))
    answer = tz.predict(model, [raw_file])[0]
    assert answer.preprocessing == "biotac_dos normalize='minmax'"
    assert answer.probabilities == pytest.approx(tz.predict(model, [done], raw=True)[0].probabilities, abs=1e-6)
    assert tz.predict(model, [raw_file], raw=True)[0].preprocessing is None

    def stream(*extra: str) -> dict:
        assert main(["stream", str(ckpt), "--json", "-q", *extra]) == 0
        return json.loads(capsys.readouterr().out)

    applied, reference = stream("--file", str(raw_file)), stream("--file", str(done), "--raw")
    assert applied["preprocessing"] == "biotac_dos normalize='minmax'" and reference["preprocessing"] is None
    assert applied["final_scores"] == pytest.approx(reference["final_scores"], abs=1e-5)
    assert stream("--file", str(raw_file), "--raw")["final_scores"] != pytest.approx(applied["final_scores"],
                                                                                     abs=1e-3)
    assert main(["predict", str(ckpt), str(raw_file), "--json"]) == 0
    said = json.loads(capsys.readouterr().out)
    assert said["checkpoint"] == str(ckpt) and said["model"] == "cnn_lstm" and said["weights"] is None
    assert said["preprocessing"] == said["predictions"][0]["preprocessing"] == "biotac_dos normalize='minmax'"
    assert said["predictions"][0]["top_k"][0]["probability"] == pytest.approx(max(answer.probabilities), abs=1e-6)
    assert main(["predict", str(ckpt), str(done), "--raw", "--json"]) == 0
    top, expected = json.loads(capsys.readouterr().out)["predictions"][0]["top_k"], said["predictions"][0]["top_k"]
    assert [t["class"] for t in top] == [t["class"] for t in expected]
    assert [t["probability"] for t in top] == pytest.approx([t["probability"] for t in expected], abs=1e-6)
    assert main(["predict", str(ckpt), str(raw_file)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == f"cnn_lstm with checkpoint {ckpt} (trained on biotac_dos)"
    assert main(["stream", str(ckpt), "--file", str(raw_file), "-q"]) == 0
    assert ("preprocessing: biotac_dos normalize='minmax': each reading scaled by its own range over the 24 "
            "electrodes, (max E - E) / (max E - min E) (the checkpoint's own, as it was trained; --raw turns it "
            "off)") in capsys.readouterr().out.splitlines()
