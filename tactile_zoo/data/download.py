"""Fetching and unpacking raw dataset files without trusting them.

* :func:`fetch` streams a URL into a temporary file next to its destination, hashes it on the way, and renames it
  into place only when the sha256 matches; a mismatch deletes the temporary file and raises. A half-finished or
  forged download therefore never sits where a loader would find it. Transient failures (a dropped or reset
  connection, a timeout, HTTP 429 or 5xx) are retried a few times with exponential backoff, each attempt starting
  the file and its hash afresh; anything else (404, a refused connection, an unknown host) fails at once. A tqdm
  bar on stderr shows the bytes when stderr is a terminal.
* :func:`check_zip_member` refuses what a hostile archive uses to write outside its folder ("zip slip"): absolute
  paths, ``..`` components, symbolic links and other special files, plus encrypted members and members larger than
  a cap. :func:`safe_extract` checks every member before writing anything, then writes each one with an explicit
  path that is verified to stay inside the destination.
"""

from __future__ import annotations

import errno
import hashlib
import http.client
import logging
import os
import re
import stat
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
import zipfile
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from tqdm import tqdm

from .._files import open_temporary
from ..errors import DatasetError

__all__ = ["fetch", "verify_sha256", "check_zip_member", "check_zip", "open_zip", "safe_extract", "not_a_file",
           "MAX_DOWNLOAD_BYTES", "MAX_MEMBER_BYTES"]

MAX_DOWNLOAD_BYTES = 2 << 30  # 2 GiB: no release this zoo knows is larger; a server streaming forever is refused
MAX_MEMBER_BYTES = 512 << 20  # one archive member, uncompressed (the Ev releases' members are ~100 kB)
RETRIES = 3  # further attempts after a transient failure: a flaky mirror recovers, a dead one fails within ~7 s
BACKOFF_SECONDS = 1.0  # the first wait; each later one doubles
MAX_WAIT_SECONDS = 30.0  # cap on one wait, including a server's Retry-After

log = logging.getLogger(__name__)


def verify_sha256(path: str | os.PathLike, expected: str) -> str:
    """Return the file's sha256; raise a DatasetError when it is not ``expected``."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(1 << 20):
            digest.update(block)
    got = digest.hexdigest()
    if got != expected.lower():
        raise DatasetError(f"{path}: sha256 {got} does not match the expected {expected}")
    return got


def not_a_file(path: str | os.PathLike) -> str | None:
    """What stands at ``path`` when it is neither absent nor a regular file (a symbolic link to one counts as one):
    "a folder", "a symbolic link loop", "a broken symbolic link (to ...)" or another kind of file; None otherwise.

    A loader that looks for a file and finds a folder of that name should say so, not ask for the file to be placed
    where something already is."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        if not path.is_symlink():
            return None
        return f"a broken symbolic link (to {os.readlink(path)}, which does not exist)"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop"
        return f"unreadable ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "a folder"
    kinds = ((stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"))
    return next((name for test, name in kinds if test(mode)), "not a regular file")


def fetch(url: str, dest: str | os.PathLike, sha256: str, *, timeout: float = 60.0,
          max_bytes: int = MAX_DOWNLOAD_BYTES, hint: str = "", retries: int | None = None,
          backoff: float | None = None, progress: bool | None = None) -> Path:
    """Download ``url`` to ``dest`` if and only if its sha256 is ``sha256``.

    The bytes go to a temporary file in ``dest``'s folder and are renamed into place after the checksum matched, so
    ``dest`` is either absent or complete and verified. Network failures, a wrong checksum and oversized responses
    raise a DatasetError that ends with ``hint`` (what to place where by hand); a ``dest`` that exists but is not a
    regular file (a folder, a symbolic link loop; see :func:`not_a_file`) is refused before anything is downloaded.

    A transient failure (connection reset or dropped, timeout, HTTP 429 or 5xx) is retried up to ``retries`` more
    times (default :data:`RETRIES`), waiting ``backoff`` seconds (default :data:`BACKOFF_SECONDS`), then twice as
    long each time (or the server's ``Retry-After``, capped at 30 s); every
    attempt rewrites the temporary file from its first byte. Other failures raise at once. ``progress``: a tqdm bar
    on stderr; None shows it when stderr is a terminal and the ``tactile_zoo`` logger is not silenced to warnings
    (``tactile-zoo -q``).

    Returns:
        ``dest`` as a Path.
    """
    dest = Path(dest)
    suffix = f" {hint}" if hint else ""
    scheme = urllib.parse.urlsplit(url).scheme.lower()
    if scheme not in ("http", "https"):
        raise DatasetError(f"refusing to download {url!r}: only http(s) URLs are fetched.{suffix}")
    if (what := not_a_file(dest)) is not None:  # checked before the download, not at the rename after it
        raise DatasetError(f"{dest} is {what}, not a file: move it out of the way, then download again")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = open_temporary(dest, suffix=".part")  # the umask's permissions, not mkstemp's 0o600
    except OSError as exc:
        raise DatasetError(f"cannot write the download into {dest.parent} ({exc.strerror or exc}).{suffix}") from exc
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as out:
            digest = _download_with_retries(url, out, timeout=timeout, max_bytes=max_bytes, suffix=suffix,
                                            retries=RETRIES if retries is None else retries,
                                            backoff=BACKOFF_SECONDS if backoff is None else backoff,
                                            progress=_show_progress() if progress is None else progress)
        got = digest.hexdigest()
        if got != sha256.lower():
            raise DatasetError(f"download of {url} has sha256 {got}, expected {sha256}; the file was refused and "
                               f"deleted.{suffix}")
        os.replace(tmp, dest)
    except urllib.error.HTTPError as exc:
        raise DatasetError(f"could not download {url}: HTTP {exc.code} {exc.reason}.{suffix}") from exc
    except urllib.error.URLError as exc:
        raise DatasetError(f"could not download {url} (offline? {exc.reason}).{suffix}") from exc
    except (OSError, TimeoutError, http.client.HTTPException) as exc:
        raise DatasetError(f"could not download {url} ({_describe(exc)}).{suffix}") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return dest


def _show_progress() -> bool:
    quiet = not logging.getLogger("tactile_zoo").isEnabledFor(logging.INFO)
    return not quiet and sys.stderr.isatty()


def _transient(exc: BaseException) -> bool:
    """Whether another attempt may succeed: the server or the path to it hiccuped, not the request being wrong."""
    if isinstance(exc, urllib.error.HTTPError):
        return exc.code == 429 or 500 <= exc.code <= 599
    if isinstance(exc, urllib.error.URLError):
        exc = exc.reason if isinstance(exc.reason, BaseException) else exc
    # a refused connection or an unknown host is an offline machine or a wrong URL: retrying only delays the error
    if isinstance(exc, ConnectionRefusedError):
        return False
    # reset/aborted/dropped (RemoteDisconnected is a ConnectionResetError), a body cut short, a timeout
    return isinstance(exc, (ConnectionError, http.client.IncompleteRead, TimeoutError))


def _wait_before_retry(exc: BaseException, attempt: int, backoff: float) -> float:
    wait = backoff * 2 ** attempt
    retry_after = exc.headers.get("Retry-After") if isinstance(exc, urllib.error.HTTPError) and exc.headers else None
    if retry_after is not None and retry_after.strip().isdigit():  # the seconds form; an HTTP date is ignored
        wait = max(wait, float(retry_after))
    return min(wait, MAX_WAIT_SECONDS)


def _download_with_retries(url: str, out: BinaryIO, *, timeout: float, max_bytes: int, suffix: str, retries: int,
                           backoff: float, progress: bool) -> hashlib._Hash:
    """Stream ``url`` into ``out`` (from its start) and return the sha256 of what was written."""
    attempt = 0
    while True:
        out.seek(0)
        out.truncate()  # a retry must not append to a partial body: the hash covers exactly the file's bytes
        try:
            return _download_once(url, out, timeout=timeout, max_bytes=max_bytes, suffix=suffix, progress=progress)
        except (OSError, http.client.HTTPException) as exc:
            if attempt >= retries or not _transient(exc):
                raise
            wait = _wait_before_retry(exc, attempt, backoff)
            attempt += 1
            log.warning("download of %s failed (%s); retry %d of %d in %.1f s", url, _describe(exc), attempt,
                        retries, wait)
            time.sleep(wait)


def _download_once(url: str, out: BinaryIO, *, timeout: float, max_bytes: int, suffix: str,
                   progress: bool) -> hashlib._Hash:
    digest, size = hashlib.sha256(), 0
    with urllib.request.urlopen(url, timeout=timeout) as response:
        length = response.headers.get("Content-Length")
        total = int(length) if length and length.isdigit() else None
        name = Path(urllib.parse.urlsplit(url).path).name or url
        with tqdm(total=total, desc=name, unit="B", unit_scale=True, unit_divisor=1024, leave=False,
                  file=sys.stderr, disable=not progress) as bar:
            while block := response.read(1 << 20):
                size += len(block)
                if size > max_bytes:
                    raise DatasetError(f"download of {url} exceeds {max_bytes} bytes; refused and deleted.{suffix}")
                digest.update(block)
                out.write(block)
                bar.update(len(block))
        if total is not None and size < total:  # urllib returns a short body silently when the server drops it
            raise http.client.IncompleteRead(b"", total - size)
    return digest


def _describe(exc: BaseException) -> str:
    if isinstance(exc, urllib.error.HTTPError):
        return f"HTTP {exc.code} {exc.reason}"
    if isinstance(exc, urllib.error.URLError):
        return str(exc.reason)
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


_DRIVE = re.compile(r"^[A-Za-z]:")


def check_zip_member(info: zipfile.ZipInfo, archive: str | os.PathLike = "<zip>",
                     max_bytes: int = MAX_MEMBER_BYTES) -> PurePosixPath:
    """The member's safe relative path, or a DatasetError saying why the member (and so the archive) is refused."""
    name = info.filename
    where = f"{archive}: member {name!r}"
    if "\x00" in name:
        raise DatasetError(f"{where}: NUL byte in the name; archive refused")
    if name.startswith(("/", "\\")) or _DRIVE.match(name):
        raise DatasetError(f"{where}: absolute path; archive refused (zip slip)")
    parts = re.split(r"[/\\]+", name)
    if ".." in parts:
        raise DatasetError(f"{where}: '..' path component; archive refused (zip slip)")
    mode = info.external_attr >> 16
    kind = stat.S_IFMT(mode)
    if stat.S_ISLNK(mode):
        raise DatasetError(f"{where}: symbolic link; archive refused (zip slip)")
    if kind not in (0, stat.S_IFREG, stat.S_IFDIR):
        raise DatasetError(f"{where}: special file (mode {oct(mode)}); archive refused")
    if info.flag_bits & 0x1:
        raise DatasetError(f"{where}: encrypted member; archive refused")
    if info.file_size > max_bytes:
        raise DatasetError(f"{where}: {info.file_size} bytes uncompressed exceeds the {max_bytes}-byte cap; "
                           f"archive refused")
    clean = [p for p in parts if p not in ("", ".")]
    return PurePosixPath(*clean) if clean else PurePosixPath(".")


def check_zip(zf: zipfile.ZipFile, archive: str | os.PathLike = "<zip>") -> list[tuple[zipfile.ZipInfo, PurePosixPath]]:
    """Check every member (see :func:`check_zip_member`); returns ``(info, safe relative path)`` pairs."""
    return [(info, check_zip_member(info, archive)) for info in zf.infolist()]


def open_zip(path: str | os.PathLike) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(path)
    except FileNotFoundError as exc:
        raise DatasetError(f"{path}: file not found") from exc
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable zip archive ({exc})") from exc


def safe_extract(archive: str | os.PathLike, dest: str | os.PathLike) -> list[Path]:
    """Extract ``archive`` into ``dest`` after checking every member; returns the files written.

    Nothing is written when any member is refused. Each file is written through an explicit path that must resolve
    inside ``dest``, and no more bytes than the member declares are copied.
    """
    dest = Path(dest)
    with open_zip(archive) as zf:
        members = check_zip(zf, archive)
        dest.mkdir(parents=True, exist_ok=True)
        top = dest.resolve()
        written: list[Path] = []
        for info, rel in members:
            target = (dest / rel).resolve()
            if target != top and top not in target.parents:
                raise DatasetError(f"{archive}: member {info.filename!r} would land outside {dest}; refused")
            if info.is_dir():
                target.mkdir(parents=True, exist_ok=True)
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with zf.open(info) as src, open(target, "wb") as out:
                    copied = _copy_capped(src, out, info.file_size)
            except (zipfile.BadZipFile, OSError, EOFError) as exc:
                raise DatasetError(f"{archive}: member {info.filename!r} cannot be extracted ({exc})") from exc
            if copied != info.file_size:
                raise DatasetError(f"{archive}: member {info.filename!r} holds {copied} bytes, its header says "
                                   f"{info.file_size}")
            written.append(target)
    return written


def _copy_capped(src: BinaryIO, out: BinaryIO, declared: int) -> int:
    """Copy at most ``declared + 1`` bytes (one more reveals a member larger than its header says)."""
    copied = 0
    while block := src.read(min(1 << 20, declared - copied + 1)):
        copied += len(block)
        if copied > declared:
            return copied
        out.write(block)
    return copied

