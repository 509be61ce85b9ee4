"""Augment8000 on fixture files written in the release's exact CSV format."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import tactile_zoo
from tactile_zoo.data.datasets import Augment8000
from tactile_zoo.data.datasets.augment8000 import (
    REAL_FILE,
    SOURCE_MEAN,
    SOURCE_STD,
    TRAIN_FILE,
    compensate_weight,
    read_augment8000,
)
from tactile_zoo.errors import DatasetError

COLUMNS = ("timestep,opto1_x,opto1_y,opto1_z,eucl force 1,opto2_x,opto2_y,opto2_z,eucl force 2,opto3_x,opto3_y,"
           "opto3_z,eucl force 3,finger1_pos,finger2_pos,finger3_pos")
# the issue's statement of the source's training statistics, copied independently of the implementation
ISSUE_MEAN = [-0.2332938, 0.43448809, -0.02102928, 0.565528053, 0.0387262300, 0.0398179976, 0.567078027, 0.716047705,
              -0.30245472, 0.286651377, 0.0750420239, 0.468298448, 33.11166, 33.593965, 33.577765]
ISSUE_STD = [0.39165433, 0.57594662, 0.21116683, 0.6734428, 0.267279, 0.26111209, 0.67091961, 0.72118393,
             0.28212706, 0.27444994, 0.19451229, 0.39772967, 6.77925638, 7.47350691, 7.58818243]


def _sample(rng: np.random.Generator, label: int, steps: int = 50) -> np.ndarray:
    """(steps, 15) features: forces around the class, |F| per sensor, finger positions 20-50."""
    forces = rng.normal(0.1 * (label % 5), 0.3, size=(steps, 3, 3))
    norms = np.linalg.norm(forces, axis=2, keepdims=True)
    pos = np.clip(20 + np.cumsum(rng.uniform(0, 1.2, size=(steps, 3)), axis=0), 0, 60)
    return np.concatenate([np.concatenate([forces, norms], axis=2).reshape(steps, 12), pos], axis=1)


def write_augment8000(path: Path, samples: list[tuple[int, np.ndarray]], declared: int | None = None) -> None:
    """Write ``(label, (T, 15) features)`` samples in the release's format."""
    n = len(samples) if declared is None else declared
    lines = [f"file header,dataset,0,stamp,0,nSamples,{n},0,0,0,0,0,0,0.0,0.0,0.0"]
    for k, (label, feats) in enumerate(samples):
        start = 1_600_000_000_000_000_000 + k * 10**9
        lines.append(f"header,seq,{k},stamp start,{start},stamp end,{start + 5 * 10**8},nMeas,{len(feats)},"
                     f"class label,{label},0,0,0.0,0.0,0.0")
        lines.append(COLUMNS)
        lines += [",".join([str(t)] + [repr(float(v)) for v in row]) for t, row in enumerate(feats)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def _make(rng: np.random.Generator, per_class: int) -> list[tuple[int, np.ndarray]]:
    return [(label, _sample(rng, label)) for label in range(20) for _ in range(per_class)]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    rng = np.random.default_rng(0)
    train, real = _make(rng, 4), _make(rng, 2)
    both = tmp_path_factory.mktemp("a8k_both")
    write_augment8000(both / "augment8000" / "raw" / TRAIN_FILE, train)
    write_augment8000(both / "augment8000" / "raw" / REAL_FILE, real)
    real_only = tmp_path_factory.mktemp("a8k_real")
    write_augment8000(real_only / "augment8000" / "raw" / REAL_FILE, real)
    return {"both": both, "real_only": real_only, "train": train, "real": real}


def test_reader_returns_the_written_samples(files: dict) -> None:
    feats, labels = read_augment8000(files["both"] / "augment8000" / "raw" / TRAIN_FILE)
    assert feats.shape == (80, 50, 15) and labels.tolist() == [lab for lab, _ in files["train"]]
    assert np.allclose(feats, np.stack([f for _, f in files["train"]]))


def test_weight_compensation_formula() -> None:
    feats = np.zeros((1, 50, 15))
    feats[0, :, 6] = 0.4  # sensor 2 z: the first three are [0.1, 0.2, 0.3] below
    feats[0, :3, 6] = [0.1, 0.2, 0.3]
    feats[0, :, 10] = 0.01  # sensor 3 z: max of the first three 0.05 is not above the threshold
    feats[0, :3, 10] = [0.05, 0.0, 0.02]
    feats[0, :, 13] = np.linspace(20, 110, 50)  # finger 2: theta from 0 to pi/2
    feats[0, :, 5] = 1.0
    out = compensate_weight(feats)
    theta = (feats[0, :, 13] - 20) / 360 * 2 * np.pi
    assert np.allclose(out[0, :, 6], feats[0, :, 6] - 0.2 * np.cos(theta))  # w = mean(0.1, 0.2, 0.3)
    assert np.allclose(out[0, :, 5], 1.0 + 0.2 * np.sin(theta))
    assert np.allclose(out[0, :, [9, 10]], feats[0, :, [9, 10]])  # below threshold: untouched
    untouched = [c for c in range(15) if c not in (5, 6)]
    assert np.array_equal(out[0][:, untouched], feats[0][:, untouched])
    assert np.allclose(out[0, 0, 6], 0.1 - 0.2) and np.allclose(out[0, -1, 5], 1.2)


def test_source_statistics_are_the_issues() -> None:
    assert np.array_equal(SOURCE_MEAN, np.array(ISSUE_MEAN)) and np.array_equal(SOURCE_STD, np.array(ISSUE_STD))


def test_paper_protocol_with_both_files(files: dict) -> None:
    home = files["both"]
    full = Augment8000(root=home)
    assert full.num_folds == 10 and full.x.shape == (120, 50, 3, 4) and full.g.shape == (120, 50, 3)
    assert full.spec.sensor.name == "optoforce3" and full.spec.num_globals == 3 and full.spec.num_classes == 20
    # z-score with the training file's statistics: the training samples are standardised, the test ones are not
    train_feats = torch.cat([full.x[:80].reshape(80, 50, 12), full.g[:80]], dim=2).reshape(-1, 15).double()
    assert torch.allclose(train_feats.mean(0), torch.zeros(15, dtype=torch.float64), atol=1e-5)
    assert torch.allclose(train_feats.std(0, unbiased=False), torch.ones(15, dtype=torch.float64), atol=1e-4)
    raw, _ = read_augment8000(home / "augment8000" / "raw" / TRAIN_FILE)
    comp = compensate_weight(raw).reshape(-1, 15)
    real, _ = read_augment8000(home / "augment8000" / "raw" / REAL_FILE)
    z_real = (compensate_weight(real) - comp.mean(0)) / comp.std(0)
    assert np.allclose(full.x[80:].numpy(), z_real[:, :, :12].reshape(40, 50, 3, 4), atol=1e-5)
    assert np.allclose(full.g[80:].numpy(), z_real[:, :, 12:], atol=1e-5)
    vals = []
    for fold in range(10):
        tr, va, te = (tactile_zoo.load_dataset("augment8000", root=home, split=s, fold=fold)
                      for s in ("train", "val", "test"))
        assert len(te) == 40 and torch.equal(te.y, full.y[80:])  # the real-life file, every fold
        assert not set(tr.groups.tolist()) & set(va.groups.tolist()) and len(tr) + len(va) == 80
        assert torch.bincount(va.y, minlength=20).max() <= 1  # stratified: 4 per class over 10 folds
        vals.append(set(va.groups.tolist()))
    assert set().union(*vals) == set(range(80)) and sum(map(len, vals)) == 80


def test_augmented_copies_stay_in_their_fold(files: dict) -> None:
    home = files["both"]
    tr = Augment8000(root=home, split="train", fold=3, augment=["jitter", "magnitude_warp"], augment_factor=3)
    va = Augment8000(root=home, split="val", fold=3, augment="jitter", augment_factor=3)
    plain = Augment8000(root=home, split="train", fold=3)
    assert len(tr) == 3 * len(plain) and len(va) == 8
    assert set(tr.groups.tolist()) == set(plain.groups.tolist()) and not set(tr.groups.tolist()) & set(
        va.groups.tolist())
    assert torch.equal(tr.g, plain.g.repeat(3, 1, 1)) and not torch.equal(tr.x[len(plain):2 * len(plain)], plain.x)


def test_real_life_only_mode(files: dict) -> None:
    home = files["real_only"]
    with pytest.warns(UserWarning, match=f"{TRAIN_FILE} is missing"):
        full = Augment8000(root=home)
    raw, labels = read_augment8000(home / "augment8000" / "raw" / REAL_FILE)
    z = (compensate_weight(raw) - np.array(ISSUE_MEAN)) / np.array(ISSUE_STD)  # the source's statistics
    assert np.allclose(full.x.numpy(), z[:, :, :12].reshape(40, 50, 3, 4), atol=1e-5)
    assert np.allclose(full.g.numpy(), z[:, :, 12:], atol=1e-5) and full.y.tolist() == labels.tolist()
    tests = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for fold in range(10):  # 2 samples per class, 10 folds: classes rotate through the test folds
            parts = {s: Augment8000(root=home, split=s, fold=fold) for s in ("train", "val", "test")}
            groups = [set(d.groups.tolist()) for d in parts.values()]
            assert not (groups[0] & groups[1] or groups[0] & groups[2] or groups[1] & groups[2])
            assert sum(len(d) for d in parts.values()) == 40
            tests.append(groups[2])
    assert set().union(*tests) == set(range(40)) and sum(map(len, tests)) == 40


def test_source_stats_option_with_the_training_file(files: dict) -> None:
    ds = Augment8000(root=files["both"], stats="source")
    raw, _ = read_augment8000(files["both"] / "augment8000" / "raw" / TRAIN_FILE)
    z = (compensate_weight(raw) - SOURCE_MEAN) / SOURCE_STD
    assert np.allclose(ds.g[:80].numpy(), z[:, :, 12:], atol=1e-5)


# ----------------------------------------------------------------------------------------------- bad input
def _broken(tmp_path: Path, mutate) -> Path:  # noqa: ANN001
    path = tmp_path / "augment8000" / "raw" / TRAIN_FILE
    write_augment8000(path, _make(np.random.default_rng(1), 1))
    lines = path.read_text().splitlines()
    path.write_text("\n".join(mutate(lines)) + "\n")
    return path


def _set_field(line: str, index: int, value: str) -> str:
    fields = line.split(",")
    fields[index] = value
    return ",".join(fields)


_CASES = [
    ("truncated file", lambda ls: ls[:-104], "declares 20 samples, the file ends after 18"),
    ("cut mid-sample", lambda ls: ls[:-60], "sample 19 declares 50 measurements \\(nMeas\\) but has only 42"),
    ("short sample", lambda ls: ls[:10] + ls[15:], "declares 50 measurements \\(nMeas\\) but has only 45"),
    ("label outside", lambda ls: [ls[0], _set_field(ls[1], 10, "25")] + ls[2:], "class label 25 is outside"),
    ("non-numeric", lambda ls: ls[:5] + [_set_field(ls[5], 3, "n/a")] + ls[6:], "line 6, column 4: 'n/a'"),
    ("missing column", lambda ls: ls[:5] + [ls[5].rsplit(",", 1)[0]] + ls[6:], "line 6 has 15 values"),
    ("nan", lambda ls: ls[:7] + [_set_field(ls[7], 2, "nan")] + ls[8:], "line 8, column 3: non-finite"),
    ("inf", lambda ls: ls[:7] + [_set_field(ls[7], 2, "inf")] + ls[8:], "non-finite reading inf"),
    ("extra data", lambda ls: [_set_field(ls[0], 6, "19")] + ls[1:], "data after the 19 samples"),
    ("no column row", lambda ls: ls[:2] + ls[3:], "expected the column-name row"),
    ("bad count", lambda ls: [_set_field(ls[0], 6, "many")] + ls[1:], "number of samples .* is not a number"),
    ("no sample header", lambda ls: [ls[0], _set_field(ls[1], 0, "head")] + ls[2:], "expected the header row"),
]


@pytest.mark.parametrize("case, mutate, message", _CASES, ids=[c[0] for c in _CASES])
def test_bad_files_raise_one_error_naming_the_file(tmp_path: Path, case: str, mutate, message: str) -> None:  # noqa: ANN001
    path = _broken(tmp_path, mutate)
    with pytest.raises(DatasetError, match=message) as err:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            Augment8000(root=tmp_path)
    assert str(path) in str(err.value)


def test_missing_files(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=f"{TRAIN_FILE} and/or .*{REAL_FILE}"):
        Augment8000(root=tmp_path)
    assert Augment8000.availability(tmp_path)[0] is False and not Augment8000.downloadable
