"""The simulated datasets: the dataset contract (``tactile_zoo.testing.check_dataset``), their shapes, splits,
determinism by seed, size keywords, physics, learnability."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

from tactile_zoo.data.datasets._simulator import _Simulator
from tactile_zoo.data.datasets.sim_biotac_slip import _biotac_raw
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import get_dataset_entry, list_datasets, load_dataset
from tactile_zoo.testing import DATASET_RULES, check_dataset

NAMES = ["sim_evtouch", "sim_biotac_slip", "sim_uskin_textures"]
SHAPES = {  # name: (sensor, classes, T, N, C, G)
    "sim_evtouch": ("neutouch", 10, 100, 39, 2, 0),
    "sim_biotac_slip": ("biotac_sp", 7, 30, 24, 1, 0),
    "sim_uskin_textures": ("uskin_allegro", 10, 50, 60, 3, 8),
}


def _cls(name: str) -> type[_Simulator]:
    return get_dataset_entry(name).obj


def _features(x: np.ndarray, g: np.ndarray, bins: int = 5) -> np.ndarray:
    """Time-averaged and time-binned means of every taxel-channel and global feature."""
    s = x.shape[0]
    xb = np.stack([c.mean(1) for c in np.array_split(x, bins, axis=1)], 1).reshape(s, -1)
    gb = np.stack([c.mean(1) for c in np.array_split(g, bins, axis=1)], 1).reshape(s, -1)
    return np.concatenate([x.mean(1).reshape(s, -1), xb, gb], 1)


def _probe(name: str, shuffle_labels: bool = False) -> float:
    train, test = load_dataset(name, split="train"), load_dataset(name, split="test")
    y_train = train.y.numpy()
    if shuffle_labels:
        y_train = np.random.default_rng(0).permutation(y_train)
    clf = make_pipeline(StandardScaler(), LogisticRegression(C=0.1, max_iter=2000))
    with threadpool_limits(1):  # a multi-threaded BLAS on a busy machine can be 40x slower on this tiny problem
        clf.fit(_features(train.x.numpy(), train.g.numpy()), y_train)
        return float(clf.score(_features(test.x.numpy(), test.g.numpy()), test.y.numpy()))


def test_registered_with_metadata() -> None:
    assert set(NAMES) <= set(list_datasets("sim_*"))
    for name in NAMES:
        meta = get_dataset_entry(name).meta
        sensor, k, t, n, c, g = SHAPES[name]
        assert (meta["sensor"], meta["num_classes"], meta["num_steps"], meta["num_nodes"], meta["num_channels"],
                meta["num_globals"]) == (sensor, k, t, n, c, g)
        assert meta["simulated"] is True and meta["folds"] == 1 and meta["protocol"] == "fixed"
        assert tuple(meta["class_names"]) == _cls(name).class_names
        assert meta["num_samples"] == k * (_cls(name).default_train + _cls(name).default_test)


@pytest.mark.parametrize("name", NAMES)
def test_keeps_the_dataset_contract(name: str) -> None:
    """The public suite (metadata, splits, spec, sample shapes and dtypes, labels, disjoint splits, determinism)."""
    report = check_dataset(name)
    assert sorted(report.rules) == sorted(DATASET_RULES) and not report.skipped, report


@pytest.mark.parametrize("name", NAMES)
def test_shapes_and_spec(name: str) -> None:
    """The simulators' own sizes, and (beyond the contract, which asks it of the training split) every class in every
    split."""
    sensor, k, t, n, c, g = SHAPES[name]
    for split in ("train", "val", "test"):
        ds = load_dataset(name, split=split)
        assert tuple(ds.x.shape[1:]) == (t, n, c) and tuple(ds.g.shape[1:]) == (t, g)
        assert set(ds.y.tolist()) == set(range(k))
    spec = ds.spec
    assert (spec.name, spec.num_classes, spec.num_steps, spec.num_nodes, spec.num_channels, spec.num_globals) == \
        (name, k, t, n, c, g)
    assert spec.sensor.name == sensor and len(spec.sensor.channels) == c and ds.num_folds == 1


@pytest.mark.parametrize("name", NAMES)
def test_splits_disjoint_and_complete(name: str) -> None:
    cls = _cls(name)
    every = load_dataset(name)
    data = cls.generate()
    parts = every.split_indices(data, 0)
    idx = {s: parts[s] for s in ("train", "val", "test")}
    joined = np.concatenate(list(idx.values()))
    assert len(joined) == len(set(joined.tolist())) == len(every)
    assert sorted(joined.tolist()) == list(range(len(every)))
    k = len(cls.class_names)
    assert len(idx["train"]) + len(idx["val"]) == k * cls.default_train and len(idx["test"]) == k * cls.default_test
    for split, ids in idx.items():  # the loaded split holds exactly those samples
        ds = load_dataset(name, split=split)
        assert torch.equal(ds.x, every.x[torch.as_tensor(ids)]) and torch.equal(ds.y, every.y[torch.as_tensor(ids)])


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_by_seed(name: str) -> None:
    cls = _cls(name)
    small = {"n_train_per_class": 3, "n_test_per_class": 2}
    a, b, c = cls.generate(seed=0, **small), cls.generate(seed=0, **small), cls.generate(seed=1, **small)
    assert torch.equal(a.x, b.x) and torch.equal(a.g, b.g) and torch.equal(a.y, b.y)
    assert not torch.equal(a.x, c.x)
    assert torch.equal(load_dataset(name, seed=0, **small).x, a.x)
    assert torch.equal(load_dataset(name, seed=1, **small).x, c.x)
    # train and test come from separate streams: a different test size leaves the training samples unchanged
    d = cls.generate(seed=0, n_train_per_class=3, n_test_per_class=1)
    n_train = len(cls.class_names) * 3
    assert torch.equal(d.x[:n_train], a.x[:n_train]) and len(d.y) == n_train + len(cls.class_names)


@pytest.mark.parametrize("name", NAMES)
def test_size_keywords(name: str) -> None:
    k = SHAPES[name][1]
    train = load_dataset(name, split="train", n_train_per_class=5, n_test_per_class=3, num_steps=24)
    val = load_dataset(name, split="val", n_train_per_class=5, n_test_per_class=3, num_steps=24)
    test = load_dataset(name, split="test", n_train_per_class=5, n_test_per_class=3, num_steps=24)
    assert len(train) + len(val) == 5 * k and len(test) == 3 * k and len(val) >= k
    assert train.x.shape[1] == 24 and train.spec.num_steps == 24


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("bad", [{"n_train_per_class": 1}, {"n_test_per_class": 0}, {"num_steps": 2},
                                 {"seed": -1}, {"seed": "0"}, {"n_train_per_class": 2.5}])
def test_bad_size_keywords(name: str, bad: dict) -> None:
    arg = next(iter(bad))
    with pytest.raises(ConfigError, match=arg):
        load_dataset(name, **bad)


def test_memo_does_not_leak_mutation() -> None:
    ds = load_dataset("sim_biotac_slip", split="train")
    before = ds.x.clone()
    ds.x.mul_(0.0)  # a consumer normalising in place must not change the next load
    assert torch.equal(load_dataset("sim_biotac_slip", split="train").x, before)


def test_events_binary_and_plausible() -> None:
    x = load_dataset("sim_evtouch").x
    assert set(torch.unique(x).tolist()) == {0.0, 1.0}
    on, off = x[..., 0].mean().item(), x[..., 1].mean().item()
    assert 0.005 < off < on < 0.2  # sparse, both polarities, more ON (grasp onset) than OFF
    # the grasp (onset, squeeze) is busier than the late hold: the first half has more events than the last fifth
    t = x.shape[1]
    assert x[:, : t // 2].sum() > x[:, -t // 5:].sum()


def test_biotac_raw_range_and_normalisation() -> None:
    rng = np.random.default_rng(0)
    y = np.repeat(np.arange(7), 4)
    raw, baseline = _biotac_raw(rng, y, 30)
    assert raw.min() >= 1800 and raw.max() <= 3850  # the release's range is roughly 1900-3750
    assert np.all(raw == np.rint(raw))  # integer ADC readings
    assert np.all((baseline[:, None, :] - raw).max(axis=(1, 2)) > 200)  # contact drops the values
    x = load_dataset("sim_biotac_slip").x
    assert x.mean() > 0 and x.max() > 0.3  # normalised: positive under pressure, in units of 1000 raw


def test_uskin_stroke_is_bidirectional() -> None:
    ds = load_dataset("sim_uskin_textures")
    x, g = ds.x.numpy(), ds.g.numpy()
    t = x.shape[1]
    shear = x[..., 0].sum(2)  # (S, T) total shear along the stroke
    fwd, back = shear[:, : int(0.4 * t)].mean(1), shear[:, -int(0.4 * t):].mean(1)
    assert np.mean(np.sign(fwd) != np.sign(back)) > 0.95  # friction reverses with the stroke
    assert np.all(x[..., 2].sum(2).mean(1) > 0)  # pressing: positive total normal force
    # joint angles follow the stroke: out and back to about where they started
    j = g[:, :, 1]
    mid = j[:, t // 2]
    assert np.mean(np.abs(mid - j[:, 0]) > 3 * np.abs(j[:, -1] - j[:, 0])) > 0.8


@pytest.mark.parametrize("name", NAMES)
def test_learnable_by_a_linear_probe(name: str) -> None:
    chance = 1.0 / SHAPES[name][1]
    acc = _probe(name)
    assert acc > 2.5 * chance, f"{name}: linear probe {acc:.3f}, chance {chance:.3f}"
    assert acc < 0.97, f"{name}: linear probe {acc:.3f}; the task should not be trivial"
    # the same probe on labels unrelated to the signals stays near chance, so the threshold above means something
    assert _probe(name, shuffle_labels=True) < 2.5 * chance
