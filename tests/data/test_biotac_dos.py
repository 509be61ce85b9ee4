"""BioTac-DoS on fixture files written in the release's exact layout and CSV format."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import tactile_zoo
from tactile_zoo.cli import main
from tactile_zoo.data.datasets import BioTacDoS
from tactile_zoo.data.datasets.biotac_dos import CLASSES, OBJECT_SETS
from tactile_zoo.errors import ConfigError, DatasetError

HEADER = ",".join(f"ff_e{i}" for i in range(1, 25))
ROWS = 35  # 3 windows of 10 (non-overlapping), 5 readings left over


def _recording(seed: int, rows: int = ROWS) -> np.ndarray:
    """Raw integer electrode values as the release has them (about 1900-3750, dropping under contact)."""
    rng = np.random.default_rng(seed)
    rest = rng.integers(3000, 3700, size=24)
    drop = np.cumsum(rng.integers(0, 40, size=(rows, 24)), axis=0)
    return np.clip(rest - drop, 1900, 3750).astype(np.int64)


def _write(path: Path, table: np.ndarray, header: str = HEADER) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [header] + [",".join(str(int(v)) for v in row) for row in table]
    path.write_text("\n".join(lines) + "\n")


def _file_name(obj: str, i: int) -> str:
    return f"{'strippes' if obj == 'striped' else obj}{i}.csv"  # the release's spelling of striped


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every class x every object, one recording each, plus a second recording of each basic object."""
    root = tmp_path_factory.mktemp("biotac_home")
    seed = 0
    for c in CLASSES:
        for objs in OBJECT_SETS.values():
            for obj in objs:
                for i in range(1, 3 if obj in OBJECT_SETS["basic"] else 2):
                    seed += 1
                    _write(root / "biotac_dos" / "raw" / "csvs" / c / _file_name(obj, i), _recording(seed))
    return root


def _recording_files(root: Path) -> list[Path]:
    csvs = root / "biotac_dos" / "raw" / "csvs"
    return [p for c in CLASSES for p in sorted((csvs / c).iterdir())]


def test_windows_are_cut_inside_each_recording(home: Path) -> None:
    ds = BioTacDoS(root=home, normalize="none")
    files = _recording_files(home)
    assert len(ds) == 3 * len(files) and ds.x.shape[1:] == (10, 24, 1) and ds.g.shape[1:] == (10, 0)
    assert ds.spec.sensor.name == "biotac_sp" and ds.spec.num_classes == 7
    for rec, path in enumerate(files):
        table = np.loadtxt(path, delimiter=",", skiprows=1)
        windows = ds.x[ds.groups == rec, :, :, 0].reshape(-1, 24)
        assert np.array_equal(windows.numpy(), table[:30])  # consecutive readings of this file only
        assert (ds.y[ds.groups == rec] == CLASSES.index(path.parent.name)).all()


def test_window_and_stride(home: Path) -> None:
    ds = BioTacDoS(root=home, window=8, stride=3)
    assert ds.x.shape[1] == 8 and ds.spec.num_steps == 8
    assert len(ds) == len(_recording_files(home)) * ((ROWS - 8) // 3 + 1)


def test_minmax_normalisation_scales_each_reading_by_its_own_range(home: Path) -> None:
    ds = BioTacDoS(root=home, normalize="minmax")
    path = _recording_files(home)[5]
    table = np.loadtxt(path, delimiter=",", skiprows=1)[:30]
    expected = (table.max(1, keepdims=True) - table) / (table.max(1, keepdims=True) - table.min(1, keepdims=True))
    got = ds.x[ds.groups == 5, :, :, 0].reshape(-1, 24).numpy()
    assert np.allclose(got, expected, atol=1e-6)
    assert np.allclose(got.min(1), 0) and np.allclose(got.max(1), 1)  # per reading, not per window or recording
    assert np.array_equal(got.argmax(1), table.argmin(1))  # pressure (a falling reading) is positive


def test_minmax_of_a_flat_reading_is_zero(home: Path, tmp_path: Path) -> None:
    home = Path(shutil.copytree(home, tmp_path / "home"))  # the module's files stay as they are
    path = _recording_files(home)[0]
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    table[3] = 1234.0  # every electrode equal: no range to scale by
    _write(path, table)
    ds = BioTacDoS(root=home, normalize="minmax")
    assert np.array_equal(ds.x[ds.groups == 0][0, 3, :, 0].numpy(), np.zeros(24, dtype=np.float32))
    with pytest.raises(ConfigError, match="normalize must be one of 'baseline', 'minmax', 'none', got 'zscore'"):
        BioTacDoS(root=home, normalize="zscore")


def test_baseline_normalisation(home: Path) -> None:
    ds = BioTacDoS(root=home)
    path = _recording_files(home)[5]
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = (table[:10].mean(0) - table[:30]) / 1000.0
    assert np.allclose(ds.x[ds.groups == 5, :, :, 0].reshape(-1, 24).numpy(), expected, atol=1e-6)
    assert ds.x[ds.groups == 5][-1].mean() > 0  # readings that dropped under contact are positive


def test_objects_protocol(home: Path) -> None:
    files = _recording_files(home)
    objects = [BioTacDoS.object_of(p) for p in files]
    assert "striped" in objects and "strippes" not in objects
    splits = {s: BioTacDoS(root=home, split=s) for s in ("train", "val", "test", "test_solids", "test_small",
                                                          "test_textures")}
    assert splits["train"].num_folds == 1
    for s in ("train", "val"):
        assert {objects[g] for g in splits[s].groups.tolist()} <= set(OBJECT_SETS["basic"])
    train_recs, val_recs = set(splits["train"].groups.tolist()), set(splits["val"].groups.tolist())
    assert train_recs and val_recs and not train_recs & val_recs  # val carved by whole recordings
    assert sorted(splits["val"].y.unique().tolist()) == list(range(7))  # stratified
    for set_name in ("solids", "small", "textures"):
        got = {objects[g] for g in splits[f"test_{set_name}"].groups.tolist()}
        assert got == set(OBJECT_SETS[set_name])
    unseen = sum(len(splits[f"test_{s}"]) for s in ("solids", "small", "textures"))
    assert len(splits["test"]) == unseen == 3 * 7 * 7
    assert len(splits["train"]) + len(splits["val"]) == 3 * 7 * 8


def test_leave_one_object_out_validation(home: Path) -> None:
    objects = [BioTacDoS.object_of(p) for p in _recording_files(home)]
    test_default = BioTacDoS(root=home, split="test")
    for fold, held_out in enumerate(OBJECT_SETS["basic"]):
        parts = {s: BioTacDoS(root=home, split=s, fold=fold, validation="object") for s in ("train", "val", "test")}
        assert parts["val"].num_folds == 4 and parts["val"].validation_object() == held_out
        assert {objects[g] for g in parts["val"].groups.tolist()} == {held_out}  # every window of that object
        assert {objects[g] for g in parts["train"].groups.tolist()} == set(OBJECT_SETS["basic"]) - {held_out}
        assert len(parts["val"]) == 3 * 7 * 2 and len(parts["train"]) == 3 * 7 * 6  # nothing basic is lost
        assert sorted(parts["val"].y.unique().tolist()) == list(range(7))
        assert parts["test"].groups.tolist() == test_default.groups.tolist()  # the unseen objects, unchanged
    with pytest.raises(ConfigError, match="fold=4 is out of range"):
        BioTacDoS(root=home, split="val", fold=4, validation="object")
    with pytest.raises(ConfigError, match="validation must be one of"):
        BioTacDoS(root=home, validation="objects")
    with pytest.raises(ConfigError, match="belongs to the 'objects' protocol"):
        BioTacDoS(root=home, protocol="kfold", validation="object")


def test_kfold_protocol_keeps_recordings_together(home: Path) -> None:
    seen = []
    for fold in range(4):
        parts = {s: BioTacDoS(root=home, split=s, fold=fold, protocol="kfold", num_folds=4)
                 for s in ("train", "val", "test", "test_textures")}
        assert parts["test"].num_folds == 4
        recs = {s: set(d.groups.tolist()) for s, d in parts.items()}
        assert not recs["train"] & recs["val"] and not recs["train"] & recs["test"] and not recs["val"] & recs["test"]
        assert recs["test_textures"] <= recs["test"]
        seen.append(recs["test"])
    assert set().union(*seen) == set(range(len(_recording_files(home))))
    assert sum(len(s) for s in seen) == len(_recording_files(home))  # the test folds partition the recordings


def test_registry_and_cli(home: Path, capsys: pytest.CaptureFixture) -> None:
    ds = tactile_zoo.load_dataset("biotac_dos", root=home, split="test_small")
    assert len(ds) == 3 * 7 * 2
    assert main(["info", "biotac_dos", "--root", str(home)]) == 0
    assert '"test_textures": 63' in capsys.readouterr().out
    assert BioTacDoS.availability(home)[0] and not BioTacDoS.downloadable
    with pytest.raises(ConfigError, match="protocol"):
        BioTacDoS(root=home, protocol="leave_one_out")


# ----------------------------------------------------------------------------------------------- bad input
def _one_class_home(tmp_path: Path) -> Path:
    for c in CLASSES:
        _write(tmp_path / "biotac_dos" / "raw" / "csvs" / c / "pen1.csv", _recording(1))
    return tmp_path


def _break(tmp_path: Path, text: str, name: str = "pen2.csv", folder: str = "n") -> Path:
    home = _one_class_home(tmp_path)
    bad = home / "biotac_dos" / "raw" / "csvs" / folder / name
    bad.parent.mkdir(parents=True, exist_ok=True)
    bad.write_text(text)
    return bad


_GOOD_ROW = ",".join(["3000"] * 24)
_CASES = [
    ("wrong header", "ff_e1,ff_e2\n" + _GOOD_ROW + "\n", "pen2.csv", "expected the header"),
    ("non-numeric", HEADER + "\n" + ",".join(["3000"] * 23 + ["abc"]) + "\n", "pen2.csv",
     "line 2, column 24: 'abc' is not a number"),
    ("truncated row", HEADER + "\n" + (_GOOD_ROW + "\n") * 12 + "3000,3000,30", "pen2.csv",
     "line 14 has 3 values, expected 24"),
    ("nan", HEADER + "\n" + (_GOOD_ROW + "\n") * 5 + ",".join(["nan"] * 24) + "\n" + (_GOOD_ROW + "\n") * 6,
     "pen2.csv", "line 7, column 1: non-finite"),
    ("too short", HEADER + "\n" + (_GOOD_ROW + "\n") * 4, "pen2.csv", "4 readings, fewer than one window of 10"),
    ("empty", "", "pen2.csv", "empty file"),
    ("unknown object", HEADER + "\n" + (_GOOD_ROW + "\n") * 12, "spoon1.csv", "unknown object 'spoon'"),
    ("bad name", HEADER + "\n" + (_GOOD_ROW + "\n") * 12, "pen.csv", "not <object><id>.csv"),
]


@pytest.mark.parametrize("case, text, name, message", _CASES, ids=[c[0] for c in _CASES])
def test_bad_csv_raises_one_error_naming_the_file(tmp_path: Path, case: str, text: str, name: str,
                                                  message: str) -> None:
    bad = _break(tmp_path, text, name)
    with pytest.raises(DatasetError, match=message) as err:
        BioTacDoS(root=tmp_path)
    assert str(bad) in str(err.value)


def test_unknown_class_folder_and_missing_data(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(DatasetError, match=r"biotac_dos/raw/csvs \(csvs/\{n,s,e,w,cw,aw,t\}"):
        BioTacDoS(root=tmp_path)
    assert main(["download", "biotac_dos", "--root", str(tmp_path)]) == 1  # not downloadable: says where to put it
    assert f"{tmp_path / 'biotac_dos' / 'raw' / 'csvs'}" in capsys.readouterr().out
    assert main(["download", "sim_evtouch"]) == 0 and "simulated" in capsys.readouterr().out
    _break(tmp_path, HEADER + "\n" + (_GOOD_ROW + "\n") * 12, "pen1.csv", folder="north")
    with pytest.raises(DatasetError, match=r"unknown class folder\(s\) \['north'\]"):
        BioTacDoS(root=tmp_path)
    assert main(["info", "biotac_dos", "--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "north" in err and "Traceback" not in err and err.count("\n") == 1
