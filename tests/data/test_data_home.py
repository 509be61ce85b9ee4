"""Issue 38: where data lives and what a reader accepts. A data home that is a file, a processed-cache file replaced by
a folder, and readings that are finite in float64 but infinite in float32 each get one clear error naming the path
(and the row and column of the reading), never a wrong path in a hint, a traceback or NaN scores."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import tactile_zoo
from tactile_zoo.cli import main
from tactile_zoo.data.base import data_home
from tactile_zoo.data.datasets import define_recordings
from tactile_zoo.data.datasets._io import check_finite, load_npy, read_numeric_csv
from tactile_zoo.errors import ConfigError, DatasetError

WIDTH = 24  # biotac_sp: 24 electrodes x 1 channel, no globals


@pytest.fixture(scope="module")
def grasps() -> str:
    """A recordings dataset on the BioTac SP, registered once for the module."""
    define_recordings("h38_grasps", sensor="biotac_sp", num_channels=1)
    return "h38_grasps"


def _home(root: Path, steps: int = 6) -> Path:
    rng = np.random.default_rng(0)
    for cls in ("a", "b"):
        for trial in range(3):
            path = root / "h38_grasps" / "raw" / cls / f"t{trial}.npy"
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, rng.normal(size=(steps, WIDTH)).astype(np.float32))
    return root


def test_a_data_home_that_is_a_file_is_named_as_a_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str], grasps: str) -> None:
    passwd = tmp_path / "passwd"
    passwd.write_text("root:x:0:0\n")
    with pytest.raises(ConfigError, match=rf"the data root: {passwd} is a file, not a folder"):
        data_home(passwd)
    with pytest.raises(ConfigError, match=rf"{passwd}, a parent of {passwd / 'data'}, is a file"):
        data_home(passwd / "data")
    with pytest.raises(ConfigError, match=r"data home \(from \$TACTILE_ZOO_DATA\): .*passwd is a file"):
        monkeypatch.setenv("TACTILE_ZOO_DATA", str(passwd))
        tactile_zoo.load_dataset(grasps, split="train")
    # the CLI: one line, exit 2, and no hint to put a zip "under" the file
    assert main(["bench", "--models", "sgnet", "--datasets", "ev_objects", "--quick", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"tactile-zoo: error: the data home (from $TACTILE_ZOO_DATA): {passwd} is a file, "
                                f"not a folder; give a folder that holds one folder per dataset "
                                f"(<root>/<dataset>/raw/)"]
    monkeypatch.delenv("TACTILE_ZOO_DATA")
    assert main(["download", "ev_objects", "--root", str(passwd)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"tactile-zoo: error: the data root: {passwd} is a file, not a folder; give a folder that holds one folder "
        f"per dataset (<root>/<dataset>/raw/)"]
    # a home that does not exist yet is fine (a download creates it); an existing folder too
    assert data_home(tmp_path / "new" / "home") == tmp_path / "new" / "home"
    assert data_home(tmp_path) == tmp_path


def test_a_processed_cache_file_replaced_by_a_folder_is_one_error_and_kept(tmp_path: Path, grasps: str) -> None:
    root = _home(tmp_path / "home")
    ds = tactile_zoo.load_dataset(grasps, root=root, split="train")
    cached = ds.processed_dir / f"{ds._cache_key()}.pt"
    assert cached.is_file()
    cached.unlink()
    cached.mkdir()
    (cached / "mine.txt").write_text("a user's file")
    with pytest.raises(DatasetError, match=rf"h38_grasps: the processed cache file {cached} is a folder, not a cache "
                                           rf"file; move it away"):
        tactile_zoo.load_dataset(grasps, root=root, split="train")
    assert (cached / "mine.txt").read_text() == "a user's file"  # never deleted
    os.rename(cached, tmp_path / "moved")
    assert len(tactile_zoo.load_dataset(grasps, root=root, split="train")) == len(ds)  # rebuilt once moved


@pytest.mark.parametrize(("value", "said"), [("1e300", r"reading 1e\+300 is beyond float32's range"),
                                             ("-3.5e38", r"reading -3.5e\+38 is beyond float32's range"),
                                             ("nan", "non-finite reading nan"), ("inf", "non-finite reading inf")])
def test_readings_that_are_not_finite_as_float32_are_refused_by_row_and_column(tmp_path: Path, value: str,
                                                                                said: str) -> None:
    rows = [",".join(["0.5"] * 4) for _ in range(5)]
    rows[3] = ",".join(["0.5", "0.5", value, "0.5"])
    path = tmp_path / "huge.csv"
    path.write_text("a,b,c,d\n" + "\n".join(rows) + "\n")
    with pytest.raises(DatasetError, match=rf"huge.csv: line 5, column 3: {said}.*NaN/Inf readings and values "
                                           r"beyond float32 are refused"):
        read_numeric_csv(path, optional_header=True)
    table = np.full((5, 4), 0.5)
    table[3, 2] = float(value)
    np.save(tmp_path / "huge.npy", table)
    with pytest.raises(DatasetError, match=rf"huge.npy: index \(3, 2\): {said}"):
        check_finite(load_npy(tmp_path / "huge.npy"), tmp_path / "huge.npy")


def test_the_float32_limit_is_exact() -> None:
    largest = float(np.finfo(np.float32).max)
    check_finite(np.array([[largest, -largest, np.nextafter(largest, np.inf)]]), "ok.npy")  # all round to max
    with pytest.raises(DatasetError, match="beyond float32's range"):
        check_finite(np.array([[2.0**128]]), "over.npy")
    check_finite(np.array([[2**62]], dtype=np.int64), "int.npy")  # integers always fit float32's range
