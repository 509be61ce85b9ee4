"""``tactile_zoo.predict`` and ``read_recording``: recording files in the documented format give exactly
``tactile_zoo.evaluate``'s predictions; lengths are fitted as documented; bad files get one error naming them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from weights_helpers import MODEL, Trained, sample_table, write_csv

import tactile_zoo as tz
from tactile_zoo.engine.evaluate import predict_scores
from tactile_zoo.errors import ConfigError, DatasetError
from tactile_zoo.weights import read_recording


def _write(tmp_path: Path, trained: Trained, indices: range) -> list[Path]:
    files = []
    for i in indices:
        table = sample_table(trained.test, i)
        if i % 2:  # CSV, every other one with a header row
            files.append(write_csv(tmp_path / f"sample{i}.csv", table, header=i % 4 == 1))
        else:
            np.save(tmp_path / f"sample{i}.npy", table)
            files.append(tmp_path / f"sample{i}.npy")
    return files


def test_files_of_test_samples_give_evaluates_prediction_for_each(trained: Trained, tmp_path: Path) -> None:
    result = tz.evaluate(trained.model, trained.test)
    files = _write(tmp_path, trained, range(len(trained.test)))
    preds = tz.predict(MODEL, files, pretrained=trained.manifest, top_k=3)
    assert [p.index for p in preds] == result.predictions
    assert [p.label for p in preds] == [trained.test.spec.class_names[i] for i in result.predictions]
    assert [p.source for p in preds] == [str(f) for f in files]
    probs = torch.tensor([p.probabilities for p in preds])
    assert torch.allclose(probs, torch.tensor(result.probabilities), atol=1e-6)
    assert len({tuple(np.round(row, 4)) for row in probs.tolist()}) == len(files)  # every sample reads differently
    for p in preds:
        assert len(p.top_k) == 3 and p.top_k[0] == (p.label, p.probability)
        assert [q for _, q in p.top_k] == sorted((q for _, q in p.top_k), reverse=True)
        assert p.steps_read == 12 and p.length == "as recorded"
    one = tz.predict(trained.model, files[5])  # a built model knows its spec; one file at a time
    assert one[0].index == result.predictions[5] and len(one[0].top_k) == 5
    arrays = tz.predict(trained.model, [sample_table(trained.test, 2)])
    assert arrays[0].index == result.predictions[2] and arrays[0].source == "<array 0>"


def test_the_column_order_matters_so_the_check_above_can_fail(trained: Trained) -> None:
    x, g = trained.test.x[0], trained.test.g[0]
    channel_major = torch.cat([x.transpose(1, 2).reshape(x.shape[0], -1), g], dim=1).numpy()
    wrong = tz.predict(trained.model, [channel_major])[0].probabilities
    right = tz.predict(trained.model, [sample_table(trained.test, 0)])[0].probabilities
    assert not np.allclose(wrong, right, atol=1e-4)


def test_lengths_are_cropped_padded_or_resampled_as_documented(trained: Trained, tmp_path: Path) -> None:
    spec, table = trained.test.spec, sample_table(trained.test, 3)
    longer = tmp_path / "longer.npy"
    np.save(longer, np.concatenate([table, np.full((5, table.shape[1]), 7.0, dtype=np.float32)]))
    rec = read_recording(longer, spec)
    assert rec.length == "cropped" and rec.steps_read == 17
    assert torch.equal(rec.x, trained.test.x[3]) and torch.equal(rec.g, trained.test.g[3])
    shorter = tmp_path / "shorter.npy"
    np.save(shorter, table[:8])
    with pytest.raises(DatasetError, match=r"shorter.npy: 8 time steps, fewer than the 12 the weights were trained "
                                           r"on \(dataset 'sim_uskin_textures'\).*'pad'.*'resample'"):
        read_recording(shorter, spec)
    padded = read_recording(shorter, spec, length="pad")
    assert padded.length == "padded"
    assert torch.equal(padded.x[:8], trained.test.x[3, :8]) and not padded.x[8:].any() and not padded.g[8:].any()
    pred = tz.predict(trained.model, [shorter], length="pad")[0]
    scores = predict_scores(trained.model, padded.x[None], padded.g[None])
    assert pred.index == int(scores.argmax()) and pred.length == "padded"
    ramp = np.repeat(np.arange(5.0)[:, None], table.shape[1], axis=1)  # 5 rows: 0, 1, 2, 3, 4 in every column
    stretched = read_recording(ramp, spec, length="resample")
    assert stretched.length == "resampled" and stretched.x.shape == (12, 60, 3)
    assert torch.allclose(stretched.x[:, 0, 0], torch.linspace(0, 4, 12)) and torch.allclose(
        stretched.g[:, -1], torch.linspace(0, 4, 12))
    same = read_recording(table, spec, length="resample")
    assert same.length == "as recorded" and torch.equal(same.x, trained.test.x[3])
    assert read_recording(longer, spec, length=None).x.shape[0] == 17  # a stream keeps every row
    with pytest.raises(ConfigError, match="length must be one of crop, pad, resample"):
        read_recording(table, spec, length="stretch")


def test_bad_files_get_one_error_naming_the_file_and_what_is_wrong(trained: Trained, tmp_path: Path) -> None:
    table = sample_table(trained.test, 0)
    nan = table.copy()
    nan[4, 7] = np.nan
    cases = [
        (write_csv(tmp_path / "nan.csv", nan), r"nan.csv: line 6, column 8: non-finite reading nan"),
        (tmp_path / "nan.npy", r"nan.npy: index \(4, 7\): non-finite reading nan"),
        (tmp_path / "taxels.npy", r"taxels.npy: 185 columns, expected 188 = 60 taxels x 3 channel\(s\) \+ 8 "
                                  r"global\(s\) .*that would be 59 taxels: wrong taxel count"),
        (tmp_path / "transposed.npy", r"transposed.npy: 12 columns, expected 188 .*it has 188 rows: transposed\?"),
        (tmp_path / "frames.npy", r"frames.npy: array of shape \(12, 60, 3\); expected 2-D \(time steps, columns\)"),
        (tmp_path / "text.csv", r"text.csv: line 2, column 2: 'abc' is not a number"),
        (tmp_path / "empty.csv", r"empty.csv: empty file"),
        (tmp_path / "sample.txt", r"sample.txt: not a recording file \(expected .csv or .npy\)"),
        (tmp_path / "absent.csv", r"absent.csv: file not found"),
    ]
    np.save(tmp_path / "nan.npy", nan)
    np.save(tmp_path / "taxels.npy", table[:, 3:])
    np.save(tmp_path / "transposed.npy", table.T)
    np.save(tmp_path / "frames.npy", trained.test.x[0].numpy())
    (tmp_path / "text.csv").write_text("1,2\n3,abc\n")
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "sample.txt").write_text("1,2,3\n")
    for path, message in cases:
        with pytest.raises(DatasetError, match=message):
            tz.predict(trained.model, [path])
    with pytest.raises(DatasetError, match=r"<array 0>: expected a 2-D real array"):
        tz.predict(trained.model, [np.zeros(5)])


def test_predict_refuses_what_it_cannot_answer(trained: Trained) -> None:
    with pytest.raises(ConfigError, match="pass pretrained="):
        tz.predict(MODEL, [sample_table(trained.test, 0)])
    with pytest.raises(ConfigError, match="top_k must be a positive integer"):
        tz.predict(trained.model, [sample_table(trained.test, 0)], top_k=0)
    with pytest.raises(ConfigError, match="go with a model name"):
        tz.predict(trained.model, [sample_table(trained.test, 0)], pretrained=trained.manifest)
    with pytest.raises(ConfigError, match="no inputs"):
        tz.predict(trained.model, [])
