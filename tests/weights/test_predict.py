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


def test_a_batch_with_bad_files_answers_the_good_ones_in_place(trained: Trained, tmp_path: Path) -> None:
    """Issue 28: one unreadable file used to refuse the whole batch. With ``on_error="report"`` each good input is
    answered and each bad one is a Refused in its place, naming it and what is wrong; the default still raises."""
    good = tmp_path / "good.npy"
    np.save(good, sample_table(trained.test, 0))
    nan = sample_table(trained.test, 1)
    nan[2, 3] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    inputs = [good, tmp_path / "nan.npy", tmp_path / "absent.csv", sample_table(trained.test, 2), np.zeros(3)]
    answers = tz.predict(trained.model, inputs, on_error="report")
    assert [type(a).__name__ for a in answers] == ["Prediction", "Refused", "Refused", "Prediction", "Refused"]
    alone = tz.predict(trained.model, [good, sample_table(trained.test, 2)])
    assert answers[0].probabilities == alone[0].probabilities and answers[3].probabilities == alone[1].probabilities
    assert answers[1].source == str(tmp_path / "nan.npy")
    assert answers[1].reason.startswith(f"{tmp_path / 'nan.npy'}: index (2, 3): non-finite reading nan")
    assert answers[2].reason == f"{tmp_path / 'absent.csv'}: file not found"
    assert answers[4].source == "<array 4>" and answers[4].reason.startswith("<array 4>: expected a 2-D real array")
    assert answers[1].to_dict() == {"file": answers[1].source, "error": answers[1].reason}
    with pytest.raises(DatasetError, match="absent.csv: file not found"):  # a missing file: before reading any
        tz.predict(trained.model, inputs)
    with pytest.raises(DatasetError, match="nan.npy: index"):
        tz.predict(trained.model, inputs[:2])
    with pytest.raises(ConfigError, match="on_error must be one of raise, report"):
        tz.predict(trained.model, inputs, on_error="skip")


def test_semicolon_tab_and_quoted_files_give_the_same_answer_as_comma(trained: Trained, tmp_path: Path) -> None:
    table = sample_table(trained.test, 4)
    comma = write_csv(tmp_path / "comma.csv", table)
    files = [comma]
    for name, sep, quote in (("semicolon", ";", ""), ("tab", "\t", ""), ("quoted", ",", '"')):
        lines = [sep.join(f"{quote}c{j}{quote}" for j in range(table.shape[1]))]
        lines += [sep.join(f"{quote}{v:.9g}{quote}" for v in row) for row in table]
        files.append(tmp_path / f"{name}.csv")
        files[-1].write_text("\n".join(lines) + "\n")
    preds = tz.predict(trained.model, files)
    assert all(p.probabilities == preds[0].probabilities for p in preds)
    assert all(p.steps_read == 12 for p in preds)


def test_a_frames_layout_is_read_or_refused_with_the_transpose_that_fixes_it(tmp_path: Path) -> None:
    """The Ev-Touch zips keep each sample as (39 taxels, 2 channels, T). Issue 28: that layout got a rank error with
    no word on how to transpose it; now (T, N, C) is read for a dataset without globals, and another order of the
    same axes is refused naming the layout and the transpose."""
    spec = tz.load_dataset("sim_evtouch", split="test", n_train_per_class=2, n_test_per_class=1).spec
    assert (spec.num_nodes, spec.num_channels, spec.num_globals) == (39, 2, 0)
    model = tz.create_model("sgnet", spec, graph_channels=4, hidden=[8]).eval()
    frames = np.random.default_rng(0).random((spec.num_steps, 39, 2)).round(3).astype(np.float32)  # (T, N, C)
    flat = tmp_path / "flat.npy"
    np.save(flat, frames.reshape(spec.num_steps, 78))
    ev = tmp_path / "ev.npy"
    np.save(ev, frames.transpose(1, 2, 0))  # (N, C, T), as in the zips
    with pytest.raises(DatasetError, match=rf"^{ev}: array of shape \(39, 2, {spec.num_steps}\); expected 2-D "
                                           rf"\(time steps, columns\) = \(T, 78\), 39 taxels x 2 channel\(s\) \+ 0 "
                                           rf"global\(s\), or 3-D \(T, N, C\) = \(T, 39, 2\); its axes look like "
                                           rf"\(N, C, T\): save x\.transpose\(2, 0, 1\) instead$"):
        tz.predict(model, [ev])
    fixed = tmp_path / "fixed.npy"
    np.save(fixed, np.load(ev).transpose(2, 0, 1))  # what the message says
    preds = tz.predict(model, [fixed, flat, frames])
    assert preds[0].probabilities == preds[1].probabilities == preds[2].probabilities
    assert read_recording(fixed, spec).x.numpy().tolist() == frames.tolist()


def test_a_frames_layout_without_the_globals_says_how_to_add_them(trained: Trained, tmp_path: Path) -> None:
    frames = tmp_path / "frames.npy"
    np.save(frames, trained.test.x[0].numpy().transpose(2, 1, 0))  # (C, N, T); the weights' data has 8 globals
    with pytest.raises(DatasetError, match=r"its axes look like \(C, N, T\), without the 8 global\(s\): save "
                                           r"np\.concatenate\(\[x\.transpose\(2, 1, 0\)\.reshape\(x\.shape\[2\], "
                                           r"180\), globals\], axis=1\)"):
        tz.predict(trained.model, [frames])
