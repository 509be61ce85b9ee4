"""Ev-Objects / Ev-Containers on the real zips (read-only data home) and on crafted bad archives."""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

import tactile_zoo
from tactile_zoo.cli import main
from tactile_zoo.data.datasets import EvContainers, EvObjects
from tactile_zoo.data.datasets.ev import EV_CONTAINERS_CLASSES, EV_OBJECTS_CLASSES
from tactile_zoo.errors import ConfigError, DatasetError

CASES = [  # name, class, classes, T, train, test
    ("ev_objects", EvObjects, 36, 250, 576, 144),
    ("ev_containers", EvContainers, 20, 325, 240, 60),
]


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))}


@pytest.fixture(scope="module")
def untouched(shared_data: Path):
    """Fails the module's tests if anything under the shared data home was created or modified."""
    before = _snapshot(shared_data)
    yield shared_data
    assert _snapshot(shared_data) == before, "something was written under the read-only data home"


@pytest.mark.real_data
@pytest.mark.parametrize("name, cls, classes, steps, n_train, n_test", CASES)
def test_real_release(untouched: Path, name: str, cls: type, classes: int, steps: int, n_train: int,
                      n_test: int) -> None:
    full = tactile_zoo.load_dataset(name, root=untouched)
    assert isinstance(full, cls) and full.num_folds == 1 and len(full) == n_train + n_test
    assert full.spec.num_classes == classes == len(full.spec.class_names)
    assert (full.spec.num_steps, full.spec.num_nodes, full.spec.num_channels, full.spec.num_globals) == \
        (steps, 39, 2, 0)
    assert full.spec.sensor.name == "neutouch"
    assert full.x.dtype == torch.float32 and set(full.x.unique().tolist()) == {0.0, 1.0}
    assert full.g.shape == (n_train + n_test, steps, 0)
    splits = {s: tactile_zoo.load_dataset(name, root=untouched, split=s) for s in ("train", "val", "test")}
    assert len(splits["test"]) == n_test and len(splits["train"]) + len(splits["val"]) == n_train
    # one fixed stratified split: every class has the same count in train (16/12) and test (4/3)
    per_class = n_test // classes
    assert torch.bincount(splits["test"].y, minlength=classes).tolist() == [per_class] * classes
    train_val = torch.cat([splits["train"].y, splits["val"].y])
    assert torch.bincount(train_val, minlength=classes).tolist() == [4 * per_class] * classes
    # val is carved stratified (20 % of each class) and is disjoint from train
    val_counts = torch.bincount(splits["val"].y, minlength=classes)
    assert (val_counts == round(0.2 * 4 * per_class)).all()
    keys = {s: {x.numpy().tobytes() for x in ds.x} for s, ds in splits.items()}
    assert not keys["train"] & keys["val"]
    sample = splits["test"][0]
    assert sample.x.shape == (steps, 39, 2) and sample.g.shape == (steps, 0) and isinstance(sample.y, int)
    with pytest.raises(ConfigError, match="fold"):
        tactile_zoo.load_dataset(name, root=untouched, fold=1)


@pytest.mark.real_data
def test_first_test_sample_is_the_transposed_file(untouched: Path) -> None:
    with zipfile.ZipFile(untouched / "ev_objects" / "raw" / "Ev-Objects.zip") as zf:
        raw = np.load(io.BytesIO(zf.read("Ev-Objects/test/sample_0_label_20.npy")), allow_pickle=False)
    test = EvObjects(root=untouched, split="test")
    assert test.y[0] == 20  # the label comes from the file name
    assert torch.equal(test.x[0], torch.from_numpy(raw).permute(2, 0, 1))  # (39, 2, T) -> (T, 39, 2)


@pytest.mark.real_data
def test_cli_info_and_download_on_the_real_home(untouched: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["info", "ev_objects", "--root", str(untouched)]) == 0
    out = capsys.readouterr().out
    assert '"num_classes": 36' in out and '"num_steps": 250' in out and '"sensor": "neutouch"' in out
    assert '"test": 144' in out and "003_cracker_box" in out
    assert main(["download", "ev_containers", "--root", str(untouched)]) == 0
    assert "present" in capsys.readouterr().out
    assert EvContainers.availability(untouched) == (True, str(untouched / "ev_containers" / "raw" /
                                                          "Ev-Containers.zip"))


@pytest.mark.real_data
def test_time_warp_augments_real_events(untouched: Path) -> None:
    plain = EvContainers(root=untouched, split="train")
    aug = EvContainers(root=untouched, split="train", augment="time_warp", augment_factor=2)
    n = len(plain)
    assert len(aug) == 2 * n and set(aug.x[n:].unique().tolist()) <= {0.0, 1.0}
    assert not torch.equal(aug.x[n:], plain.x)
    assert len(EvContainers(root=untouched, split="val", augment="time_warp", augment_factor=2)) == 40


def test_class_names_follow_the_issue() -> None:
    assert len(EV_OBJECTS_CLASSES) == 36 and len(set(EV_OBJECTS_CLASSES)) == 36
    assert EV_OBJECTS_CLASSES[0] == "003_cracker_box" and EV_OBJECTS_CLASSES[-1] == "107-b_pepsi_bottle"
    assert EV_CONTAINERS_CLASSES[:6] == ("107-a_pepsi_bottle", "107-b_pepsi_bottle", "107-c_pepsi_bottle",
                                         "107-d_pepsi_bottle", "107-e_pepsi_bottle", "108-a_tuna_fish_can")
    assert EV_CONTAINERS_CLASSES[-1] == "110-e_coffee_can" and len(EV_CONTAINERS_CLASSES) == 20
    meta = tactile_zoo.registry.get_dataset_entry("ev_objects").meta
    assert "unverified" in meta["description"] and meta["num_classes"] == 36 and meta["folds"] == 1
    assert EvObjects.downloadable and EvContainers.downloadable


# ----------------------------------------------------------------------------------------------- bad archives
def _npy(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=allow_pickle)
    return buf.getvalue()


def _events(t: int = 250, seed: int = 0) -> np.ndarray:
    return (np.random.default_rng(seed).random((39, 2, t)) < 0.1).astype(np.float32)


def _home(tmp_path: Path, members: dict[str, bytes]) -> Path:
    """A data home holding an Ev-Objects.zip with ``members`` (plus one valid sample per partition)."""
    raw = tmp_path / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    base = {"Ev-Objects/train/sample_0_label_0.npy": _npy(_events()),
            "Ev-Objects/test/sample_0_label_0.npy": _npy(_events(seed=1))}
    with zipfile.ZipFile(raw / "Ev-Objects.zip", "w") as zf:
        for name, data in {**base, **members}.items():
            zf.writestr(name, data)
    return tmp_path


def test_a_valid_repacked_zip_loads_without_checksum(tmp_path: Path) -> None:
    home = _home(tmp_path, {"Ev-Objects/train/sample_1_label_3.npy": _npy(_events(seed=2)),
                            "Ev-Objects/train/.DS_Store": b"junk", "Ev-Objects/readme.txt": b"ignored"})
    ds = EvObjects(root=home, verify_checksum=False)
    assert len(ds) == 3 and ds.y.tolist() == [0, 3, 0]
    with pytest.raises(DatasetError, match="sha256 .* does not match") as err:
        EvObjects(root=home)  # the default refuses anything but the release
    assert "verify_checksum=False" in str(err.value)


_BAD = [
    ("sample_1_label_1.npy", _npy(np.array([{"a": 1}], dtype=object), allow_pickle=True), "pickled"),
    ("sample_1_label_1.npy", pickle.dumps(_events()), "not a .npy file"),
    ("sample_1_label_1.npy", _npy(_events())[:-100], "truncated"),
    ("sample_1_label_1.npy", _npy(np.zeros((39, 3, 250), np.float32)), r"shape \(39, 3, 250\)"),
    ("sample_1_label_1.npy", _npy(np.zeros((39, 2, 250), np.complex64)), "dtype complex64"),
    ("sample_1_label_1.npy", _npy(_events(t=200)), "200 time bins"),
    ("sample_1_label_1.npy", _npy(np.where(_events() > 0, np.nan, 0).astype(np.float32)), "non-finite"),
    ("sample_1_label_1.npy", _npy(_events() * 2), "only 0/1 events"),
    ("sample_1_label_36.npy", _npy(_events()), "label 36 is outside the 36 classes"),
    ("sample_one_label_1.npy", _npy(_events()), "unexpected file name"),
]


@pytest.mark.parametrize("member, data, message", _BAD, ids=[m for *_, m in _BAD])
def test_bad_members_raise_one_dataset_error_naming_the_member(tmp_path: Path, member: str, data: bytes,
                                                               message: str) -> None:
    home = _home(tmp_path, {f"Ev-Objects/train/{member}": data})
    with pytest.raises(DatasetError, match=message) as err:
        EvObjects(root=home, verify_checksum=False)
    assert f"Ev-Objects.zip:Ev-Objects/train/{member}" in str(err.value)


def test_empty_split_folder_and_broken_zip(tmp_path: Path) -> None:
    raw = tmp_path / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    with zipfile.ZipFile(raw / "Ev-Objects.zip", "w") as zf:
        zf.writestr("Ev-Objects/train/sample_0_label_0.npy", _npy(_events()))
        zf.writestr("Ev-Objects/test/", b"")
    with pytest.raises(DatasetError, match=r"no samples in .*Ev-Objects/test/"):
        EvObjects(root=tmp_path, verify_checksum=False)
    (raw / "Ev-Objects.zip").write_bytes(b"PK\x03\x04 this is not really a zip")
    with pytest.raises(DatasetError, match="not a readable zip"):
        EvObjects(root=tmp_path, verify_checksum=False)


def test_extracted_folder_errors(tmp_path: Path) -> None:
    folder = tmp_path / "ev_objects" / "raw" / "Ev-Objects"
    (folder / "train").mkdir(parents=True)
    (folder / "train" / "sample_0_label_0.npy").write_bytes(_npy(_events()))
    with pytest.raises(DatasetError, match=r"Ev-Objects/test is missing"):
        EvObjects(root=tmp_path)
    (folder / "test").mkdir()
    (folder / "test" / "sample_0_label_1.npy").write_bytes(_npy(_events().astype(np.float64)))
    ds = EvObjects(root=tmp_path)  # a folder has no checksum to verify; float64 events are accepted
    assert ds.x.dtype == torch.float32 and ds.y.tolist() == [0, 1]
    os.remove(folder / "test" / "sample_0_label_1.npy")
    (folder / "test" / "sample_0_label_1.npy").write_bytes(_npy(np.zeros((2, 39, 250), np.float32)))
    with pytest.raises(DatasetError, match=r"sample_0_label_1.npy: shape \(2, 39, 250\)"):
        EvObjects(root=tmp_path)
