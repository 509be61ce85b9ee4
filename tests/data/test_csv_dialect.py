"""Issue 28, CSV parsing of user recordings: the delimiter is detected (comma, semicolon, tab) or refused with a hint
naming what was seen; quoted numbers are read; ``1_0`` is refused (``float()`` reads it as 10); a first row is column
names only when none of its fields is or looks like a number."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_zoo.data.datasets._io import is_number, read_numeric_csv
from tactile_zoo.errors import DatasetError

TABLE = np.array([[0.5, -1.25, 3.0], [2.0, 1e-3, -4.5], [7.0, 8.5, 0.0]])


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def _rows(delimiter: str, header: bool = True) -> list[str]:
    return ([delimiter.join(["x", "y", "z"])] if header else []) + \
        [delimiter.join(repr(float(v)) for v in row) for row in TABLE]


@pytest.mark.parametrize("delimiter", [",", ";", "\t"], ids=["comma", "semicolon", "tab"])
@pytest.mark.parametrize("header", [True, False], ids=["header", "no-header"])
def test_comma_semicolon_and_tab_are_detected(tmp_path: Path, delimiter: str, header: bool) -> None:
    """The old reader split on commas only: a semicolon or tab file lost line 1 as a "header" and failed on line 2."""
    path = _write(tmp_path / "r.csv", _rows(delimiter, header))
    assert np.array_equal(read_numeric_csv(path, optional_header=True), TABLE)


def test_quoted_numbers_are_read(tmp_path: Path) -> None:
    path = _write(tmp_path / "r.csv", ['"x","y","z"'] + [",".join(f'"{float(v)!r}"' for v in row) for row in TABLE])
    assert np.array_equal(read_numeric_csv(path, optional_header=True), TABLE)
    # spaces inside the quotes
    semi = _write(tmp_path / "s.csv", [";".join(f'" {float(v)!r} "' for v in row) for row in TABLE])
    assert np.array_equal(read_numeric_csv(semi, optional_header=True), TABLE)


@pytest.mark.parametrize("field", ["1_0", "1_000.5", "2e1_0"])
def test_underscore_literals_are_refused_naming_line_and_column(tmp_path: Path, field: str) -> None:
    """``float("1_0")`` is 10: the old reader took such a field as a number."""
    assert not is_number(field)
    path = _write(tmp_path / "r.csv", ["x,y,z", "1,2,3", f"4,{field},6"])
    with pytest.raises(DatasetError, match=rf"^{path}: line 3, column 2: '{field}' is not a number; underscores are "
                                           rf"not allowed in numbers$"):
        read_numeric_csv(path, optional_header=True)
    first = _write(tmp_path / "first.csv", [f"{field},2,3", "4,5,6"])  # numeric-looking: data, not a header
    with pytest.raises(DatasetError, match=rf"line 1, column 1: '{field}' is not a number"):
        read_numeric_csv(first, optional_header=True)


def test_non_ascii_digits_are_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "r.csv", ["1,2,3", "4,\u0665,6"])  # ARABIC-INDIC DIGIT FIVE: float() reads 5
    with pytest.raises(DatasetError, match=r"line 2, column 2: '\u0665' is not a number"):
        read_numeric_csv(path, optional_header=True)


@pytest.mark.parametrize("delimiter", [";", "\t"], ids=["semicolon", "tab"])
def test_a_decimal_comma_is_refused_at_line_1_with_a_hint(tmp_path: Path, delimiter: str) -> None:
    """``1,5;2,5``: a European spreadsheet's export. The first row looks numeric, so it is data, not a header, and the
    error names it with the hint (the old reader dropped it as a header and failed on line 2 without one)."""
    lines = [delimiter.join(f"{v:.2f}".replace(".", ",") for v in row) for row in TABLE]
    path = _write(tmp_path / "r.csv", lines)
    with pytest.raises(DatasetError, match=rf"^{path}: line 1, column 1: '0,50' is not a number; a decimal comma\? "
                                           rf"write numbers with '\.' as the decimal mark$"):
        read_numeric_csv(path, optional_header=True)


def test_a_quoted_decimal_comma_in_a_comma_file_gets_the_hint(tmp_path: Path) -> None:
    path = _write(tmp_path / "r.csv", ['"0,5","1,5"', '"2,5","3,5"'])
    with pytest.raises(DatasetError, match=r"line 1, column 1: '0,5' is not a number; a decimal comma\?"):
        read_numeric_csv(path, optional_header=True)


def test_mixed_delimiters_get_a_hint_naming_the_one_seen(tmp_path: Path) -> None:
    path = _write(tmp_path / "r.csv", ["1;2;3", "4,5,6", "7,8,9"])
    with pytest.raises(DatasetError, match=r"line 1, column 1: '1;2;3' is not a number; it holds a semicolon"):
        read_numeric_csv(path, optional_header=True)
    spaces = _write(tmp_path / "s.csv", ["1 2 3", "4 5 6"])
    with pytest.raises(DatasetError, match=r"'1 2 3' is not a number; values separated by spaces\?"):
        read_numeric_csv(spaces, optional_header=True)


@pytest.mark.parametrize(("first", "expected"), [
    ("x,y,z", [[4, 5, 6], [7, 8, 9]]),  # names: skipped
    ("e1,e2,e3", [[4, 5, 6], [7, 8, 9]]),  # names with digits are still names
    ("ff_e1,ff_e2,ff_e3", [[4, 5, 6], [7, 8, 9]]),
    ("1,2,3", [[1, 2, 3], [4, 5, 6], [7, 8, 9]]),  # data
    ("nan,inf,-inf", r"line 1, column 1: non-finite reading nan"),  # numbers: data, refused as readings
    ("1_0,y,z", r"line 1, column 1: '1_0' is not a number; underscores"),  # looks numeric: data, refused
    ("0.5,y,1.5", r"line 1, column 2: 'y' is not a number"),  # a number among names: data, refused
])
def test_a_header_is_recognised_only_when_not_numeric(tmp_path: Path, first: str, expected: list | str) -> None:
    path = _write(tmp_path / "r.csv", [first, "4,5,6", "7,8,9"])
    if isinstance(expected, list):
        assert read_numeric_csv(path, optional_header=True).tolist() == expected
    else:
        with pytest.raises(DatasetError, match=rf"^{path}: {expected}"):
            read_numeric_csv(path, optional_header=True)
