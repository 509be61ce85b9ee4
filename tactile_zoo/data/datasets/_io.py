"""Strict readers shared by the dataset plugins and ``predict``/``stream``: CSV tables and ``.npy`` arrays.

Every reader turns whatever is wrong with a file into one :class:`~tactile_zoo.errors.DatasetError` that names the
file, the line or column when there is one, and what is wrong. Nothing here unpickles: ``.npy`` files are parsed with
``allow_pickle=False`` after checking the magic string, so a pickle, an ``.npz`` archive or random bytes are refused
rather than executed or half-read.

Bounded input. A file is only opened when ``os.stat`` (which follows symlinks) says it is a regular file no larger
than :func:`max_input_bytes` (``$TACTILE_ZOO_MAX_INPUT_MB``, default :data:`DEFAULT_MAX_INPUT_MB`): a device, a FIFO
or a socket is refused before ``open()``, which blocks on a FIFO and never ends on ``/dev/zero``. A ``.npy`` file is
memory-mapped and only the rows a caller asks for are copied; a CSV is parsed line by line, up to the rows asked for
(the rest are counted, not parsed).

CSV dialect. The delimiter is detected among comma, semicolon and tab (quoted fields allowed); numbers are ASCII
decimal literals with ``.`` as the decimal mark (``1_0``, which Python's ``float()`` reads as 10, and decimal commas
are refused with a hint). A first row is a header only when none of its fields is or looks like a number.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import math
import os
import re
import stat
from collections.abc import Iterator, Sequence
from typing import BinaryIO, NamedTuple

import numpy as np

from ...errors import ConfigError, DatasetError

__all__ = ["read_csv_lines", "parse_numeric_rows", "read_numeric_csv", "read_csv_table", "load_npy", "open_npy",
           "open_input", "max_input_bytes", "check_finite", "is_number", "Table", "MAX_INPUT_ENV", "FLOAT32_OVERFLOW",
           "DEFAULT_MAX_INPUT_MB"]

_NPY_MAGIC = b"\x93NUMPY"

#: The environment variable that sets the largest input file read, in MiB.
MAX_INPUT_ENV = "TACTILE_ZOO_MAX_INPUT_MB"
#: Its default: far above any recording the zoo's datasets hold (kilobytes to megabytes), low enough that a file read
#: whole (a CSV streamed by ``stream``) fits in a workstation's memory.
DEFAULT_MAX_INPUT_MB = 2048

#: The delimiters a CSV may use, and how messages name them.
_DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}
#: What ``float()`` accepts minus underscores and non-ASCII digits (NaN and Inf are read, then refused by
#: check_finite with their own message).
_NUMBER = re.compile(r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)", re.IGNORECASE | re.ASCII)
#: A field that is not a number but looks like one (a decimal comma, digit separators, values that were not split):
#: such a first row is data with a problem, not column names.
_NUMERIC_LOOKING = re.compile(r"[+-]?[\d.,_';\t ]*\d[\d.,_';\t ]*(?:[eE][+-]?\d+)?", re.ASCII)
_DECIMAL_COMMA = re.compile(r"[+-]?\d*,\d+(?:[eE][+-]?\d+)?", re.ASCII)
_CHUNK_ROWS = 4096  # CSV rows converted to float64 at a time


def max_input_bytes() -> int:
    """The largest input file the readers open, in bytes: ``$TACTILE_ZOO_MAX_INPUT_MB`` MiB, default
    :data:`DEFAULT_MAX_INPUT_MB`."""
    text = os.environ.get(MAX_INPUT_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_INPUT_MB * 2**20
    value = float(text) if _NUMBER.fullmatch(text) else -1.0  # the CSV grammar: no "1_0", no non-ASCII digits
    if not value > 0 or value == float("inf"):
        raise ConfigError(f"${MAX_INPUT_ENV}={text!r}: expected a positive number of MiB (default "
                          f"{DEFAULT_MAX_INPUT_MB})")
    return int(value * 2**20)


def _mib(size: int) -> str:
    return f"{size / 2**20:.1f} MiB" if size >= 2**20 else f"{size} bytes"


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def _not_regular(mode: int) -> str | None:
    return None if stat.S_ISREG(mode) else next((kind for test, kind in _KINDS if test(mode)), "not a regular file")


class _Capped(io.RawIOBase):
    """Reads at most ``limit`` bytes of ``raw``; a file that grew past the limit since it was checked is refused."""

    def __init__(self, raw: BinaryIO, limit: int, label: str) -> None:
        super().__init__()
        self._raw, self._left, self._limit, self._label = raw, limit, limit, label

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:  # type: ignore[override]
        view = memoryview(buffer).cast("B")
        if self._left <= 0:
            if self._raw.read(1):
                raise DatasetError(f"{self._label}: grew above the input size limit of {_mib(self._limit)} while "
                                   f"being read (set {MAX_INPUT_ENV} to raise the limit)")
            return 0
        n = self._raw.readinto(view[: self._left]) or 0
        self._left -= n
        return n


@contextlib.contextmanager
def _open_checked(path: str | os.PathLike, label: str | os.PathLike) -> Iterator[tuple[io.FileIO, int]]:
    """The opened regular file (unbuffered) and the size limit; see :func:`open_input`."""
    limit = max_input_bytes()
    try:
        info = os.stat(path)
    except FileNotFoundError as exc:
        raise DatasetError(f"{label}: file not found") from exc
    except OSError as exc:
        raise DatasetError(f"{label}: cannot be read ({exc.strerror or exc})") from exc
    kind = _not_regular(info.st_mode)
    if kind is not None:
        raise DatasetError(f"{label}: {kind}, not a regular file; only regular files are read")
    if info.st_size > limit:
        raise DatasetError(f"{label}: {_mib(info.st_size)}, above the input size limit of {_mib(limit)} (set "
                           f"{MAX_INPUT_ENV} to raise the limit)")
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise DatasetError(f"{label}: cannot be read ({exc.strerror or exc})") from exc
    with os.fdopen(fd, "rb", buffering=0) as raw:
        kind = _not_regular(os.fstat(fd).st_mode)
        if kind is not None:
            raise DatasetError(f"{label}: {kind}, not a regular file; only regular files are read")
        yield raw, limit  # type: ignore[misc]


@contextlib.contextmanager
def open_input(path: str | os.PathLike, label: str | os.PathLike | None = None) -> Iterator[BinaryIO]:
    """Open an input file for reading, binary, after checking that it is a regular file within the size limit.

    ``os.stat`` follows symlinks, so a link to ``/dev/zero`` is refused like the device itself; the check comes
    before ``open()`` because opening a FIFO blocks until a writer appears. The file is then opened non-blocking and
    checked again through its descriptor, so a file swapped for a FIFO in between cannot hang the open either. The
    stream reads at most the limit.
    """
    label = path if label is None else label
    with _open_checked(path, label) as (raw, limit):
        yield io.BufferedReader(_Capped(raw, limit, str(label)))  # type: ignore[arg-type]


def read_csv_lines(path: str | os.PathLike) -> list[tuple[int, list[str]]]:
    """``(line number, stripped fields)`` for every non-blank line of a comma-separated text file."""
    with open_input(path) as f:
        try:
            text = f.read().decode("utf-8-sig")
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
    """Whether ``field`` (surrounding spaces allowed) is a number literal: ``float()``'s syntax without underscores and
    with ASCII digits only (``float("1_0")`` is 10, which no recording means)."""
    return _NUMBER.fullmatch(field.strip()) is not None


def _looks_numeric(field: str) -> bool:
    return is_number(field) or _NUMERIC_LOOKING.fullmatch(field.strip()) is not None


def _hint(field: str, delimiter: str = ",") -> str:
    """Why a field that is not a number probably is not: what to change in the file."""
    if _DECIMAL_COMMA.fullmatch(field):
        return "; a decimal comma? write numbers with '.' as the decimal mark"
    if "_" in field and _NUMBER.fullmatch(field.replace("_", "")):
        return "; underscores are not allowed in numbers"
    if other := _other_delimiter([field], delimiter):
        return (f"; it holds a {other}: values separated by a {other} and by a {_DELIMITERS[delimiter]} in other "
                f"rows? use one delimiter throughout")
    if " " in field.strip():
        return "; values separated by spaces? separate them with commas"
    return ""


def _other_delimiter(fields: Sequence[str], delimiter: str) -> str | None:
    """The name of a delimiter other than ``delimiter`` found in ``fields`` (a decimal comma is not one), if any."""
    return next((name for sep, name in _DELIMITERS.items() if sep != delimiter and any(
        sep in f and not (sep == "," and _DECIMAL_COMMA.fullmatch(f)) for f in fields)), None)


def _not_a_number(path: str | os.PathLike, number: int, col: int, field: str, delimiter: str = ",") -> DatasetError:
    shown = field if len(field) <= 40 else field[:37] + "..."
    return DatasetError(f"{path}: line {number}, column {col}: {shown!r} is not a number{_hint(field, delimiter)}")


def parse_numeric_rows(rows: Sequence[tuple[int, list[str]]], path: str | os.PathLike, num_columns: int | None,
                       delimiter: str = ",") -> np.ndarray:
    """Convert ``(line, fields)`` rows into a ``float64 [rows, columns]`` array.

    Raises a DatasetError naming the first ragged row (a truncated line, or one separated by another delimiter: the
    mixed separators are named) or non-numeric cell. ``num_columns`` ``None`` means "whatever the first row has".
    """
    if not rows:
        raise DatasetError(f"{path}: no data rows")
    width = len(rows[0][1]) if num_columns is None else num_columns
    try:  # the fast path; the slow one below only runs to say precisely what is wrong
        # numpy reads what float() reads, underscores and non-ASCII digits included: rows with either go the slow way
        if all(len(fields) == width and _plain(fields) for _, fields in rows):
            return np.array([fields for _, fields in rows], dtype=np.float64)
    except ValueError:
        pass
    for number, fields in rows:
        if len(fields) != width:
            other = _other_delimiter(fields, delimiter)
            why = (f"it separates values with a {other} where the file uses a {_DELIMITERS[delimiter]}: mixed "
                   f"separators, use one delimiter throughout" if other else "ragged or truncated row")
            raise DatasetError(f"{path}: line {number} has {len(fields)} values, expected {width} ({why})")
        for col, field in enumerate(fields, start=1):
            if not is_number(field):
                raise _not_a_number(path, number, col, field, delimiter)
    raise DatasetError(f"{path}: could not be parsed as a numeric table")  # pragma: no cover (numpy-only quirks)


def _plain(fields: list[str]) -> bool:
    return "_" not in (joined := "".join(fields)) and joined.isascii()


class Table(NamedTuple):
    """A numeric table read from a file: ``table`` (``float64 [rows read, columns]``), ``rows`` (the data rows in
    the file, read or not) and ``line_numbers`` (the file line of each row read; ``None`` for a ``.npy``)."""

    table: np.ndarray
    rows: int
    line_numbers: list[int] | None = None


def _detect_delimiter(sample: list[str]) -> str:
    """The delimiter of a CSV from its first lines: among comma, semicolon and tab, the one that splits every line
    into the same number (> 1) of fields. Semicolon and tab win over comma, which they leave inside fields as a
    decimal comma (``1,5;2,5``): the numbers are then refused with that hint. None does (mixed separators): the one
    that splits the most lines, so that a line separated otherwise is named. One column: comma."""
    widths = {sep: [len(row) for row in csv.reader(sample, delimiter=sep) if row] for sep in _DELIMITERS}
    consistent = [sep for sep, found in widths.items() if len(set(found)) == 1 and found[0] > 1]
    if not consistent:
        most = max(sum(n > 1 for n in found) for found in widths.values())
        consistent = [sep for sep, found in widths.items() if most and sum(n > 1 for n in found) == most]
    return next((sep for sep in (";", "\t") if sep in consistent), ",")


def _csv_rows(text: io.TextIOBase) -> tuple[str, Iterator[tuple[int, list[str]]]]:
    """The delimiter and ``(line number, stripped fields)`` of every non-blank line, lazily."""
    head: list[str] = []  # the lines read to tell the delimiter, given to the parser again (the stream cannot seek)
    size = 0
    while len(head) < 50 and size < 2**16:
        line = text.readline()
        if not line:
            break
        size += len(line)
        head.append(line)
    delimiter = _detect_delimiter([line for line in head if line.strip()])

    def rows() -> Iterator[tuple[int, list[str]]]:
        reader = csv.reader(itertools.chain(head, text), delimiter=delimiter)
        for fields in reader:
            if "".join(fields).strip():
                yield reader.line_num, [f.strip() for f in fields]

    return delimiter, rows()


def read_csv_table(path: str | os.PathLike, *, max_rows: int | None = None, num_columns: int | None = None,
                   header: Sequence[str] | None = None, optional_header: bool = False) -> Table:
    """Read a numeric CSV table (delimiter detected, quoted fields allowed) into ``float64 [rows, columns]``.

    Args:
        max_rows: parse at most this many data rows; the rest are counted (``Table.rows``), not parsed.
        num_columns: the number of columns every row must have (default: the first data row's).
        header: the exact header row the file must start with (compared after stripping spaces, any case).
        optional_header: skip a first row in which no field is or looks like a number (column names).

    Raises:
        DatasetError: naming the file, the line and column, and what is wrong (with a hint for a decimal comma, an
            underscore in a number or a mixed delimiter).
    """
    with open_input(path) as raw:
        text = io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
        try:
            return _parse_csv(text, path, max_rows, num_columns, header, optional_header)
        except UnicodeDecodeError as exc:
            raise DatasetError(f"{path}: not a UTF-8 text file (a byte cannot be decoded: {exc.reason})") from exc
        except csv.Error as exc:
            raise DatasetError(f"{path}: not a readable CSV file ({exc})") from exc
        except OSError as exc:
            raise DatasetError(f"{path}: cannot be read ({exc.strerror or exc})") from exc


def _parse_csv(text: io.TextIOWrapper, path: str | os.PathLike, max_rows: int | None, num_columns: int | None,
               header: Sequence[str] | None, optional_header: bool) -> Table:
    delimiter, rows = _csv_rows(text)
    first = next(rows, None)
    if first is None:
        raise DatasetError(f"{path}: empty file")
    number, fields = first
    if header is not None:
        if [f.lower() for f in fields] != [h.lower() for h in header]:
            shown = delimiter.join(fields)
            raise DatasetError(f"{path}: line {number}: expected the header {','.join(header)}, got "
                               f"{shown[:80]!r}{'...' if len(shown) > 80 else ''}")
    elif not (optional_header and not any(_looks_numeric(f) for f in fields)):
        rows = itertools.chain([first], rows)  # data, not column names
    chunks: list[np.ndarray] = []
    line_numbers: list[int] = []
    pending: list[tuple[int, list[str]]] = []
    count = 0
    for row in rows:
        count += 1
        if max_rows is not None and count > max_rows:
            continue  # counted, not parsed
        pending.append(row)
        if len(pending) == _CHUNK_ROWS:  # bounded strings in memory; numpy's speed per chunk
            chunks.append(parse_numeric_rows(pending, path, num_columns, delimiter))
            num_columns = chunks[-1].shape[1]
            line_numbers += [n for n, _ in pending]
            pending.clear()
    if pending:
        chunks.append(parse_numeric_rows(pending, path, num_columns, delimiter))
        line_numbers += [n for n, _ in pending]
    if count == 0:
        raise DatasetError(f"{path}: no data rows")
    table = np.concatenate(chunks) if len(chunks) > 1 else chunks[0] if chunks else np.zeros((0, num_columns or 0))
    check_finite(table, path, line_numbers)
    return Table(table, count, line_numbers)


def read_numeric_csv(path: str | os.PathLike, num_columns: int | None = None, header: Sequence[str] | None = None,
                     optional_header: bool = False) -> np.ndarray:
    """Read a whole numeric CSV table into ``float64 [rows, columns]`` (see :func:`read_csv_table`).

    Args:
        header: the exact header row the file must start with (compared after stripping spaces).
        optional_header: skip a first row in which no field is or looks like a number (column names); any other
            non-numeric cell is an error.
    """
    return read_csv_table(path, num_columns=num_columns, header=header, optional_header=optional_header).table


#: The smallest magnitude that float32 rounds to infinity (half an ulp above its largest finite value): every model
#: computes in float32, so a reading at or beyond it is infinite by the time a model sees it.
FLOAT32_OVERFLOW = 2.0**128 - 2.0**103


def check_finite(array: np.ndarray, path: str | os.PathLike, line_numbers: Sequence[int] | None = None) -> None:
    """Refuse readings that are not finite once cast to float32: NaN, Inf, and finite float64 values beyond float32's
    range (``1e300``), which the cast would turn into Inf and the model into NaN scores. The first one is named (by CSV
    line and column when ``line_numbers`` maps the table's rows, else by index)."""
    if array.dtype.kind not in "fc":
        return
    with np.errstate(invalid="ignore", over="ignore"):  # float16/32: the bound becomes inf, finite values stay below
        bad = ~(np.abs(array) < FLOAT32_OVERFLOW)  # NaN compares False: caught with Inf and the too large
    if bad.any():
        where = np.argwhere(bad)[0]
        value = array[tuple(where)]
        if line_numbers is not None and array.ndim == 2:
            loc = f"line {line_numbers[int(where[0])]}, column {int(where[1]) + 1}"
        else:
            loc = f"index {tuple(int(i) for i in where)}"
        what = (f"non-finite reading {float(value)!r}" if not np.isfinite(value) else
                f"reading {float(value)!r} is beyond float32's range (largest {float(np.finfo(np.float32).max):.7g}), "
                f"where models compute")
        raise DatasetError(f"{path}: {loc}: {what} ({int(bad.sum())} non-finite value(s) in all, as float32); NaN/Inf "
                           f"readings and values beyond float32 are refused")


def _npy_header(fp: BinaryIO, size: int, label: str | os.PathLike) -> tuple[tuple[int, ...], bool, np.dtype, int]:
    """``(shape, fortran order, dtype, data offset)`` of a ``.npy`` stream of ``size`` bytes, checked: a real number
    dtype, and as many data bytes as the header declares (a lying header must not map or allocate gigabytes)."""
    head = fp.read(len(_NPY_MAGIC))
    if head != _NPY_MAGIC:
        kind = "a zip/.npz archive" if head.startswith(b"PK") else "a pickle" if head[:1] == b"\x80" else "random data"
        raise DatasetError(f"{label}: not a .npy file (no NumPy magic string; looks like {kind})")
    fp.seek(0)
    try:
        version = np.lib.format.read_magic(fp)
        if version not in ((1, 0), (2, 0)):  # 3.0 only exists for structured dtypes with non-ASCII field names
            raise DatasetError(f"{label}: .npy format version {version[0]}.{version[1]} is not read (expected 1.0 "
                               f"or 2.0)")
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read_header(fp)
    except ValueError as exc:
        raise DatasetError(f"{label}: truncated or corrupt .npy file ({exc})") from exc
    except (EOFError, OSError, SyntaxError, TypeError, OverflowError, MemoryError) as exc:
        raise DatasetError(f"{label}: truncated or corrupt .npy file ({type(exc).__name__}: {exc})") from exc
    if dtype.hasobject:
        raise DatasetError(f"{label}: holds pickled Python objects (dtype object); refused, .npy files are "
                           f"loaded with allow_pickle=False")
    if dtype.kind not in "biuf" or dtype.fields is not None:
        raise DatasetError(f"{label}: dtype {dtype} is not a real number type (expected float32 or another "
                           f"integer/float type)")
    offset = fp.tell()
    need = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if size - offset < need:
        raise DatasetError(f"{label}: truncated .npy file: its header declares shape {tuple(shape)} {dtype} "
                           f"({need} bytes of data), the file holds {size - offset}")
    if math.prod(max(int(d), 1) for d in shape) * dtype.itemsize >= 2**63:  # zero-size, yet overflowing numpy's sizes
        raise DatasetError(f"{label}: truncated or corrupt .npy file (shape {tuple(shape)} is too large)")
    return tuple(shape), bool(fortran), dtype, offset


def open_npy(path: str | os.PathLike, name: str | os.PathLike | None = None) -> np.ndarray:
    """A ``.npy`` file as a read-only memory map: only the rows a caller touches are read from disk.

    Checked like :func:`load_npy` (regular file within the size limit, magic string, header, real dtype, enough
    bytes), never unpickled. ``name`` is what error messages call the file (defaults to the path).
    """
    label = name if name is not None else path
    with _open_checked(path, label) as (f, _):
        size = os.fstat(f.fileno()).st_size
        shape, fortran, dtype, offset = _npy_header(f, size, label)
        if int(np.prod(shape, dtype=np.float64)) == 0:  # mmap cannot map zero bytes
            return np.zeros(shape, dtype=dtype)
        try:
            # the descriptor checked above, not the path again: a file swapped since cannot be mapped instead
            return np.memmap(f, dtype=dtype, mode="r", shape=shape, order="F" if fortran else "C", offset=offset)
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{label}: cannot be memory-mapped ({exc})") from exc


def load_npy(source: str | os.PathLike | bytes, name: str | os.PathLike | None = None,
             max_rows: int | None = None) -> np.ndarray:
    """Load one ``.npy`` array from a path or from raw bytes, never unpickling anything.

    ``name`` is what error messages call the file (defaults to the path). ``max_rows``: only the first rows (along
    the first axis) are read, from a path through a memory map (:func:`open_npy`).
    """
    label = name if name is not None else source if not isinstance(source, bytes) else "<bytes>"
    if not isinstance(source, bytes):
        view = open_npy(source, label)
        return np.array(view[:max_rows] if view.ndim and max_rows is not None else view)
    fp = io.BytesIO(source)
    shape, fortran, dtype, offset = _npy_header(fp, len(source), label)
    count = int(np.prod(shape, dtype=np.int64))
    array = np.frombuffer(source, dtype=dtype, count=count, offset=offset).reshape(shape, order="F" if fortran else "C")
    array = array[:max_rows] if array.ndim and max_rows is not None else array
    return array.copy()
