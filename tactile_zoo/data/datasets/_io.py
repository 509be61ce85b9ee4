"""Strict readers shared by the dataset plugins: CSV tables and ``.npy`` arrays.

Every reader turns whatever is wrong with a file into one :class:`~tactile_zoo.errors.DatasetError` that names the
file, the line or column when there is one, and what is wrong. Nothing here unpickles: ``.npy`` files are parsed with
``allow_pickle=False`` after checking the magic string, so a pickle, an ``.npz`` archive or random bytes are refused
rather than executed or half-read.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...errors import DatasetError

__all__ = ["read_csv_lines", "parse_numeric_rows", "read_numeric_csv", "load_npy", "check_finite", "is_number"]

_NPY_MAGIC = b"\x93NUMPY"


def read_csv_lines(path: str | os.PathLike) -> list[tuple[int, list[str]]]:
    """``(line number, stripped fields)`` for every non-blank line of a comma-separated text file."""
    try:
        text = Path(path).read_bytes().decode("utf-8-sig")
    except FileNotFoundError as exc:
        raise DatasetError(f"{path}: file not found") from exc
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not a UTF-8 text file (byte {exc.start} cannot be decoded)") from exc
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    out = []
    for number, line in enumerate(text.splitlines(), start=1):
        if " " in line or "\t" in line:  # stripping every field costs more than splitting; only where needed
            if line.strip():
                out.append((number, [field.strip() for field in line.split(",")]))
        elif line:
            out.append((number, line.split(",")))
    return out


def is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def parse_numeric_rows(rows: Sequence[tuple[int, list[str]]], path: str | os.PathLike, num_columns: int | None
                       ) -> np.ndarray:
    """Convert ``(line, fields)`` rows into a ``float64 [rows, columns]`` array.

    Raises a DatasetError naming the first ragged row (a truncated line included) or non-numeric cell. ``num_columns``
    ``None`` means "whatever the first row has".
    """
    if not rows:
        raise DatasetError(f"{path}: no data rows")
    width = len(rows[0][1]) if num_columns is None else num_columns
    try:  # the fast path; the slow one below only runs to say precisely what is wrong
        if all(len(fields) == width for _, fields in rows):
            return np.array([fields for _, fields in rows], dtype=np.float64)
    except ValueError:
        pass
    for number, fields in rows:
        if len(fields) != width:
            raise DatasetError(f"{path}: line {number} has {len(fields)} values, expected {width} (ragged or "
                               f"truncated row)")
        for col, field in enumerate(fields, start=1):
            if not is_number(field):
                shown = field if len(field) <= 40 else field[:37] + "..."
                raise DatasetError(f"{path}: line {number}, column {col}: {shown!r} is not a number")
    raise DatasetError(f"{path}: could not be parsed as a numeric table")  # pragma: no cover (numpy-only quirks)


def read_numeric_csv(path: str | os.PathLike, num_columns: int | None = None, header: Sequence[str] | None = None,
                     optional_header: bool = False) -> np.ndarray:
    """Read a numeric CSV table into ``float64 [rows, columns]``.

    Args:
        header: the exact header row the file must start with (compared after stripping spaces).
        optional_header: skip a first row in which no field is a number (column names); any other non-numeric cell
            is an error.
    """
    lines = read_csv_lines(path)
    if not lines:
        raise DatasetError(f"{path}: empty file")
    if header is not None:
        number, fields = lines[0]
        if [f.lower() for f in fields] != [h.lower() for h in header]:
            shown = ",".join(fields)
            raise DatasetError(f"{path}: line {number}: expected the header {','.join(header)}, got "
                               f"{shown[:80]!r}{'...' if len(shown) > 80 else ''}")
        lines = lines[1:]
    elif optional_header and not any(is_number(f) for f in lines[0][1]):
        lines = lines[1:]
    table = parse_numeric_rows(lines, path, num_columns)
    check_finite(table, path, [number for number, _ in lines])
    return table


def check_finite(array: np.ndarray, path: str | os.PathLike, line_numbers: Sequence[int] | None = None) -> None:
    """Refuse NaN and Inf readings, naming the first one (by CSV line when ``line_numbers`` maps the table's rows)."""
    if array.dtype.kind not in "fc":
        return
    bad = ~np.isfinite(array)
    if bad.any():
        where = np.argwhere(bad)[0]
        value = array[tuple(where)]
        if line_numbers is not None and array.ndim == 2:
            loc = f"line {line_numbers[int(where[0])]}, column {int(where[1]) + 1}"
        else:
            loc = f"index {tuple(int(i) for i in where)}"
        raise DatasetError(f"{path}: {loc}: non-finite reading {float(value)!r} ({int(bad.sum())} non-finite "
                           f"value(s) in all); NaN/Inf readings are refused")


def load_npy(source: str | os.PathLike | bytes, name: str | os.PathLike | None = None) -> np.ndarray:
    """Load one ``.npy`` array from a path or from raw bytes, never unpickling anything.

    ``name`` is what error messages call the file (defaults to the path).
    """
    label = name if name is not None else source if not isinstance(source, bytes) else "<bytes>"
    try:
        blob = source if isinstance(source, bytes) else Path(source).read_bytes()
    except FileNotFoundError as exc:
        raise DatasetError(f"{label}: file not found") from exc
    except OSError as exc:
        raise DatasetError(f"{label}: cannot be read ({exc.strerror or exc})") from exc
    if not blob.startswith(_NPY_MAGIC):
        kind = "a zip/.npz archive" if blob.startswith(b"PK") else "a pickle" if blob[:1] == b"\x80" else "random data"
        raise DatasetError(f"{label}: not a .npy file (no NumPy magic string; looks like {kind})")
    try:
        fp = io.BytesIO(blob)
        version = np.lib.format.read_magic(fp)
        if version in ((1, 0), (2, 0)):
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(fp)
            if not dtype.hasobject:  # check the declared size first: a lying header must not allocate gigabytes
                need, have = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize, len(blob) - fp.tell()
                if have < need:
                    raise DatasetError(f"{label}: truncated .npy file: its header declares shape {tuple(shape)} "
                                       f"{dtype} ({need} bytes of data), the file holds {have}")
        array = np.lib.format.read_array(io.BytesIO(blob), allow_pickle=False)
    except ValueError as exc:
        if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
            raise DatasetError(f"{label}: holds pickled Python objects (dtype object); refused, .npy files are "
                               f"loaded with allow_pickle=False") from exc
        raise DatasetError(f"{label}: truncated or corrupt .npy file ({exc})") from exc
    except (EOFError, OSError, SyntaxError, TypeError, OverflowError, MemoryError) as exc:
        raise DatasetError(f"{label}: truncated or corrupt .npy file ({type(exc).__name__}: {exc})") from exc
    if array.dtype.kind not in "biuf" or array.dtype.fields is not None:
        raise DatasetError(f"{label}: dtype {array.dtype} is not a real number type (expected float32 or another "
                           f"integer/float type)")
    return array
