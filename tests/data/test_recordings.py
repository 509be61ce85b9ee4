"""The bring-your-own recordings loader and ALU-Textures on fixture trials in the documented folder format."""

from __future__ import annotations

import io
import string
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import tactile_zoo
from tactile_zoo.data.datasets import AluTextures, RecordingsDataset, define_recordings
from tactile_zoo.data.datasets._io import load_npy, read_numeric_csv
from tactile_zoo.errors import ConfigError, DatasetError

WIDTH = 60 * 3 + 8  # uSkin: 60 taxels x [x, y, z] + 8 joint angles


def _trial(seed: int, steps: int = 55, width: int = WIDTH) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(steps, width)).round(4)


def _write_csv(path: Path, table: np.ndarray, header: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [",".join(f"c{j}" for j in range(table.shape[1]))] if header else []
    rows += [",".join(repr(float(v)) for v in row) for row in table]
    path.write_text("\n".join(rows) + "\n")


def _write_npy(path: Path, table: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, table.astype(np.float32))


@pytest.fixture(scope="module")
def alu_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("alu_home")
    seed = 0
    for fabric in ("wool", "denim", "silk"):  # sorted: denim, silk, wool
        for trial in range(6):
            seed += 1
            path = root / "alu_textures" / "raw" / fabric / f"trial{trial:02d}"
            if trial % 2:
                _write_npy(path.with_suffix(".npy"), _trial(seed))
            else:
                _write_csv(path.with_suffix(".csv"), _trial(seed), header=trial == 0)
    return root


def test_alu_textures_reads_the_documented_columns(alu_home: Path) -> None:
    ds = tactile_zoo.load_dataset("alu_textures", root=alu_home)
    assert isinstance(ds, AluTextures) and ds.spec.class_names == ("denim", "silk", "wool")
    assert ds.x.shape == (18, 50, 60, 3) and ds.g.shape == (18, 50, 8)  # cropped to num_steps=50
    assert ds.spec.sensor.name == "uskin_allegro" and ds.num_folds == 5
    table = np.loadtxt(alu_home / "alu_textures" / "raw" / "silk" / "trial02.csv", delimiter=",")
    i = 6 + 2  # silk is label 1; its trials follow denim's six, in file order
    assert ds.y[i] == 1
    assert np.allclose(ds.x[i].numpy(), table[:50, :180].reshape(50, 60, 3), atol=1e-6)  # taxel-major [x, y, z]
    assert np.allclose(ds.x[i, 7, 12, 2].item(), table[7, 12 * 3 + 2], atol=1e-6)
    assert np.allclose(ds.g[i].numpy(), table[:50, 180:], atol=1e-6)
    npy = np.load(alu_home / "alu_textures" / "raw" / "denim" / "trial01.npy")
    assert np.allclose(ds.x[1].numpy(), npy[:50, :180].reshape(50, 60, 3))


def test_kfold_over_trials(alu_home: Path) -> None:
    tests = []
    for fold in range(5):
        parts = {s: AluTextures(root=alu_home, split=s, fold=fold) for s in ("train", "val", "test")}
        ids = [set(d.groups.tolist()) for d in parts.values()]
        assert not (ids[0] & ids[1] or ids[0] & ids[2] or ids[1] & ids[2]) and sum(map(len, ids)) == 18
        tests.append(ids[2])
    assert set().union(*tests) == set(range(18))


def test_class_list_sets_labels_and_refuses_unknown_folders(alu_home: Path) -> None:
    ds = AluTextures(root=alu_home, classes=["wool", "silk", "denim"])
    assert ds.spec.class_names == ("wool", "silk", "denim") and ds.y[:6].tolist() == [0] * 6
    with pytest.raises(DatasetError, match=r"class folder\(s\) \['wool'\] .* not in the class list"):
        AluTextures(root=alu_home, classes=["silk", "denim"])
    with pytest.raises(DatasetError, match=r"no folder for class\(es\) \['linen'\]"):
        AluTextures(root=alu_home, classes=["wool", "silk", "denim", "linen"])


def test_fixed_train_test_folders(tmp_path: Path) -> None:
    for part, n in (("train", 4), ("test", 2)):
        for c in ("a", "b"):
            for k in range(n):
                _write_csv(tmp_path / "grasps" / "raw" / part / c / f"{k}.csv", _trial(k + 10 * n, 20, 12))
    ds = RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=4, split="test")
    assert ds.num_folds == 1 and len(ds) == 4 and ds.spec.class_names == ("a", "b")
    assert ds.x.shape == (4, 20, 3, 4) and ds.g.shape == (4, 20, 0)
    assert len(RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", split="val")) == 2


@pytest.fixture
def unregister() -> Iterator[None]:
    """Keep the session's registry as it was: other tests list the registered datasets."""
    yield
    tactile_zoo.registry._TABLES["dataset"].builtin.pop(tactile_zoo.registry.normalize_name("my_grasps"), None)


def test_define_recordings_registers_a_dataset(tmp_path: Path, unregister: None) -> None:
    for c in ("slip", "hold"):
        for k in range(3):
            _write_csv(tmp_path / "my_grasps" / "raw" / c / f"t{k}.csv", _trial(k, 12, 24))
    cls = define_recordings("my_grasps", sensor="biotac_sp", num_channels=1, description="test recordings")
    assert "my_grasps" in tactile_zoo.list_datasets()
    meta = tactile_zoo.registry.get_dataset_entry("my_grasps").meta
    assert meta["sensor"] == "biotac_sp" and meta["description"] == "test recordings"
    ds = tactile_zoo.load_dataset("my_grasps", root=tmp_path, split="train", num_folds=3)
    assert isinstance(ds, cls) and ds.x.shape[1:] == (12, 24, 1) and ds.num_folds == 3
    assert cls.availability(tmp_path)[0] and not cls.availability(tmp_path / "nowhere")[0]


# ----------------------------------------------------------------------------------------------- bad input
def _home_with(tmp_path: Path, name: str, content: bytes | str) -> Path:
    for k in range(2):
        _write_csv(tmp_path / "alu_textures" / "raw" / "silk" / f"ok{k}.csv", _trial(k))
    bad = tmp_path / "alu_textures" / "raw" / "silk" / name
    if isinstance(content, str):
        bad.write_text(content)
    else:
        bad.write_bytes(content)
    return bad


def _npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=allow_pickle)
    return buf.getvalue()


_ROW = ",".join(["0.5"] * WIDTH)
_CASES = [
    ("ragged", "bad.csv", "\n".join([_ROW] * 30 + [",".join(["0.5"] * 100)]), "line 31 has 100 values, expected 188"),
    ("non-numeric", "bad.csv", "\n".join([_ROW] * 3 + [_ROW.replace("0.5", "x", 1)]), "line 4, column 1: 'x'"),
    ("wrong width", "bad.csv", "\n".join([",".join(["1"] * 187)] * 60), "187 columns, expected 188"),
    ("nan", "bad.csv", "\n".join([_ROW] * 20 + [_ROW.replace("0.5", "nan", 1)] + [_ROW] * 40),
     "line 21, column 1: non-finite"),
    ("short", "bad.csv", "\n".join([_ROW] * 49), "49 time steps, shorter than the declared length num_steps=50"),
    ("not utf8", "bad.csv", b"\xff\xfe\x00garbage", "not a UTF-8 text file"),
    ("npy shape", "bad.npy", _npy_bytes(np.zeros((50, 60, 3))), r"shape \(50, 60, 3\), expected \(T, 188\)"),
    ("npy dtype", "bad.npy", _npy_bytes(np.zeros((50, WIDTH), dtype="U2")), "dtype <U2 is not a real number"),
    ("npy pickle", "bad.npy", _npy_bytes(np.array([None, {"x": 1}], dtype=object), True), "pickled"),
    ("npy truncated", "bad.npy", _npy_bytes(np.zeros((50, WIDTH)))[:-8], "truncated"),
    ("npy inf", "bad.npy", _npy_bytes(np.full((50, WIDTH), np.inf)), "non-finite reading inf"),
    ("other file", "notes.txt", "hello", "not a trial file"),
]


@pytest.mark.parametrize("case, name, content, message", _CASES, ids=[c[0] for c in _CASES])
def test_bad_trials_raise_one_error_naming_the_file(tmp_path: Path, case: str, name: str, content: bytes | str,
                                                    message: str) -> None:
    bad = _home_with(tmp_path, name, content)
    with pytest.raises(DatasetError, match=message) as err:
        AluTextures(root=tmp_path)
    assert str(bad) in str(err.value)


def test_unequal_lengths_empty_class_and_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="recordings folder .*alu_textures/raw not found"):
        AluTextures(root=tmp_path)
    _write_csv(tmp_path / "grasps" / "raw" / "a" / "0.csv", _trial(0, 20, 3))
    _write_csv(tmp_path / "grasps" / "raw" / "a" / "1.csv", _trial(1, 18, 3))
    with pytest.raises(DatasetError, match="1.csv: 18 time steps, but .*0.csv has 20"):
        RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1)
    assert len(RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1,
                                 num_steps=15)) == 2
    (tmp_path / "grasps" / "raw" / "b").mkdir()
    with pytest.raises(DatasetError, match="empty class folder"):
        RecordingsDataset(root=tmp_path, folder="grasps", sensor="optoforce3", num_channels=1, num_steps=15)
    with pytest.raises(ConfigError, match="pass sensor="):
        RecordingsDataset(root=tmp_path, folder="grasps")
    with pytest.raises(tactile_zoo.UnknownNameError):
        RecordingsDataset(root=tmp_path, folder="grasps", sensor="no_such_sensor")
    with pytest.raises(ConfigError, match="plain folder name"):
        RecordingsDataset(root=tmp_path, folder="../x", sensor="optoforce3")


# ----------------------------------------------------------------------------------------------- hostile bytes
@settings(max_examples=150, deadline=None)
@given(blob=st.one_of(st.binary(max_size=400),
                      st.binary(max_size=300).map(lambda b: b"\x93NUMPY\x01\x00" + b),
                      st.builds(lambda shape, cut: _npy_bytes(np.zeros(shape, np.float32))[:cut],
                                st.lists(st.integers(0, 6), max_size=3).map(tuple), st.integers(0, 400))))
def test_property_npy_reader_never_fails_uncontrolled(blob: bytes) -> None:
    try:
        array = load_npy(blob, "fuzz.npy")
    except DatasetError as exc:
        assert str(exc).startswith("fuzz.npy: ")
    else:
        assert array.dtype.kind in "biuf"


@settings(max_examples=150, deadline=None)
@given(text=st.text(alphabet=string.digits + ",.-eEnaif \n\r\tx", max_size=300))
def test_property_csv_reader_never_fails_uncontrolled(tmp_path_factory: pytest.TempPathFactory, text: str) -> None:
    path = tmp_path_factory.getbasetemp() / "fuzz.csv"
    path.write_text(text)
    try:
        table = read_numeric_csv(path, optional_header=True)
    except DatasetError as exc:
        assert str(exc).startswith(str(path))
    else:
        assert table.ndim == 2 and np.isfinite(table).all()
        assert torch.from_numpy(table).dtype == torch.float64
