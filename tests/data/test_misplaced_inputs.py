"""Messages that say what is actually wrong (issue 49, item 13).

* A folder, a symbolic link loop or a broken link named like a dataset's zip was met with "place Ev-Objects.zip at
  <that very path>": the message now names what stands there, and ``download`` refuses it before fetching anything.
* A CSV whose rows mix comma and semicolon separators was called "ragged": the row with the other separator is now
  named, with both separators.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import tactile_zoo
from tactile_zoo.cli import main
from tactile_zoo.data.datasets._io import read_csv_table
from tactile_zoo.data.download import fetch, not_a_file
from tactile_zoo.errors import DatasetError


def _raw(root: Path) -> Path:
    raw = root / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    return raw


def _folder(raw: Path) -> str:
    (raw / "Ev-Objects.zip").mkdir()
    return "a folder"


def _loop(raw: Path) -> str:
    (raw / "Ev-Objects.zip").symlink_to("Ev-Objects.zip")
    return "a symbolic link loop"


def _broken(raw: Path) -> str:
    (raw / "Ev-Objects.zip").symlink_to("elsewhere.zip")
    return "a broken symbolic link (to elsewhere.zip, which does not exist)"


@pytest.mark.parametrize("make", [_folder, _loop, _broken])
def test_loading_names_what_stands_where_the_zip_belongs(tmp_path: Path, make) -> None:
    what = make(_raw(tmp_path))
    zip_path = tmp_path / "ev_objects" / "raw" / "Ev-Objects.zip"
    with pytest.raises(DatasetError) as info:
        tactile_zoo.load_dataset("ev_objects", root=tmp_path, split="train")
    message = str(info.value)
    assert f"{zip_path} is {what}, not the zip file" in message
    assert "Place Ev-Objects.zip (sha256" not in message  # not asked to put it where something already is


@pytest.mark.parametrize("make", [_folder, _loop])
def test_download_refuses_before_fetching(tmp_path: Path, make, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture) -> None:
    what = make(_raw(tmp_path))
    monkeypatch.setenv("TACTILE_ZOO_EV_URL", "http://127.0.0.1:9")  # never reached: the refusal comes first
    assert main(["download", "ev_objects", "--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"Ev-Objects.zip is {what}, not a file" in err
    assert "could not download" not in err


def test_fetch_leaves_a_folder_in_the_way_alone(tmp_path: Path) -> None:
    dest = tmp_path / "x.zip"
    (dest / "inside").mkdir(parents=True)
    with pytest.raises(DatasetError, match=r"x\.zip is a folder, not a file: move it out of the way"):
        fetch("http://127.0.0.1:9/x.zip", dest, "0" * 64)
    assert (dest / "inside").is_dir() and [p.name for p in tmp_path.iterdir()] == ["x.zip"]  # no .part file left


def test_not_a_file_kinds(tmp_path: Path) -> None:
    assert not_a_file(tmp_path / "absent") is None
    (tmp_path / "file").write_bytes(b"")
    assert not_a_file(tmp_path / "file") is None
    (tmp_path / "link").symlink_to("file")
    assert not_a_file(tmp_path / "link") is None  # a link to a file is the file
    assert not_a_file(tmp_path) == "a folder"
    os.mkfifo(tmp_path / "fifo")
    assert not_a_file(tmp_path / "fifo") == "a named pipe (FIFO)"


@pytest.mark.parametrize(("text", "line", "other", "used"), [
    ("1,2,3\n4,5,6\n7;8;9\n", 3, "semicolon", "comma"),  # a whole row with the other separator
    ("1,2,3\n4,5;6\n", 2, "semicolon", "comma"),  # both in one row
    ("1;2;3\n4;5;6\n7;8;9\n1,2,3\n", 4, "comma", "semicolon"),
    ("1\t2\t3\n4\t5\t6\n7,8,9\n", 3, "comma", "tab"),
])
def test_mixed_separators_are_named(tmp_path: Path, text: str, line: int, other: str, used: str) -> None:
    path = tmp_path / "mixed.csv"
    path.write_text(text)
    with pytest.raises(DatasetError) as info:
        read_csv_table(path)
    message = str(info.value)
    assert f"line {line} has" in message
    assert f"separates values with a {other} where the file uses a {used}: mixed separators" in message
    assert "ragged" not in message


def test_a_short_row_is_still_ragged(tmp_path: Path) -> None:
    path = tmp_path / "short.csv"
    path.write_text("1,2,3\n4,5\n")
    with pytest.raises(DatasetError, match=r"line 2 has 2 values, expected 3 \(ragged or truncated row\)"):
        read_csv_table(path)
    path.write_text("1;2;3\n4,5;6\n")  # a decimal comma in a semicolon file is not a second separator
    with pytest.raises(DatasetError, match=r"line 2 has 2 values, expected 3 \(ragged or truncated row\)"):
        read_csv_table(path)
