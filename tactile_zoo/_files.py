"""Atomic file writes: the one way tactile-zoo writes a file it may later read or share.

Every write goes to a temporary file in the target's folder and is renamed over the target (``os.replace``), so a
reader, or a rerun after SIGKILL, sees either the old complete file or the new complete one, never a torn one.

The temporary file is created with ``os.open(..., 0o666)`` rather than :func:`tempfile.mkstemp`, so the kernel
applies the process umask (and any default ACL of the folder) exactly as it does for a plain ``open(path, "w")``:
under umask 022 the file ends up 0o644. ``mkstemp`` creates 0o600 files, which made results folders and data homes
shared between colleagues unreadable to everyone but their writer. Reading the umask instead (``os.umask`` sets it
to read it) would briefly change it for every thread of the process.

Temporary names are ``.<name>.<random>.tmp`` (hidden, next to the target); :func:`torn_temporaries` finds those a
killed writer left behind.

Generated pages (:func:`replace_block`, :func:`stale_files`, :func:`update_pages`): a hand-written page holds
generated text between two marker lines, ``<!-- NAME: begin (COMMAND) -->`` and ``<!-- NAME: end -->``; a generator
rewrites what lies between them and writes the page, or with ``--check`` names each page that is out of date. The
model pages, the fidelity ledger, the CLI reference, the weights table and the published result tables all do it
here, once.

This module sits at the bottom of the import layers (beside :mod:`tactile_zoo.errors`) so every layer can use it.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import stat
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "create_exclusive", "open_temporary",
           "torn_temporaries", "replace_block", "stale_files", "out_of_date", "update_pages"]


def create_exclusive(path: str | os.PathLike, mode: int = 0o666) -> int:
    """Create ``path`` (it must not exist) for writing and return its descriptor; the umask applies to ``mode``."""
    return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), mode)


def open_temporary(path: str | os.PathLike, suffix: str = ".tmp") -> tuple[int, Path]:
    """Create a new hidden temporary file ``.<name>.<random><suffix>`` next to ``path``, with the permissions the
    umask allows; returns its descriptor and path. For writers that stream into it and rename it themselves."""
    target = Path(path)
    for _ in range(100):  # a clash needs 2**48 bad luck or a leftover of the same name: try another name
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}{suffix}")
        try:
            return create_exclusive(tmp), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file next to {target}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, fsync: bool = True) -> Iterator[Path]:
    """A temporary path for a writer that wants a file name (``torch.save``, ``safetensors``, ``savefig``); when
    the block ends without an exception the file is flushed to disk (``fsync``) and renamed over ``path``,
    otherwise it is deleted and ``path`` is left as it was.

    The temporary file already exists (empty, with the umask's permissions) when the block starts. A writer that
    replaces it instead of rewriting it (safetensors creates its files 0o600) gets those permissions back.
    """
    target = Path(path)
    fd, tmp = open_temporary(target)
    try:
        wanted = stat.S_IMODE(os.fstat(fd).st_mode)  # what the kernel made of 0o666 under the umask
    finally:
        os.close(fd)
    try:
        yield tmp
        if stat.S_IMODE(os.stat(tmp).st_mode) != wanted:
            os.chmod(tmp, wanted)
        if fsync:
            _fsync(tmp)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (module docstring)."""
    with atomic_path(path, fsync=fsync) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike, text: str, *, fsync: bool = True) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (module docstring)."""
    atomic_write_bytes(path, text.encode("utf-8"), fsync=fsync)


def torn_temporaries(folder: str | os.PathLike, name: str) -> list[Path]:
    """The temporary files of writes to ``folder/name`` that never finished (their writer was killed)."""
    return sorted(Path(folder).glob(f".{name}.*.tmp"))


def replace_block(text: str, begin: str, end: str, body: str, where: str | os.PathLike, *, find: str | None = None,
                  error: Callable[[str], BaseException] = ValueError) -> str:
    """``text`` with what lies between the marker lines ``begin`` and ``end`` replaced by ``body`` (module
    docstring). ``find``: a regular expression the begin marker matches (default: ``begin`` itself), for a marker
    rewritten to ``begin``. Markers missing, repeated or out of order raise ``error`` naming ``where`` and both."""
    starts = list(re.finditer(find or re.escape(begin), text))
    if len(starts) != 1 or text.count(end) != 1 or end not in text[starts[0].end():]:
        raise error(f"{where} must hold the markers {begin!r} ... {end!r} once each, in that order")
    rest = text[starts[0].end():].split(end, 1)[1]
    return f"{text[:starts[0].start()]}{begin}\n{body}\n{end}{rest}"


def stale_files(texts: Mapping[Path, str], *, write: bool = False) -> list[Path]:
    """The files of ``texts`` whose content is not ``texts[path]`` (a missing file included), in order; with
    ``write``, each is rewritten (atomically, UTF-8)."""
    stale = [path for path, text in texts.items()
             if not path.is_file() or path.read_text(encoding="utf-8") != text]
    for path in stale if write else ():
        atomic_write_text(path, texts[path])
    return stale


def out_of_date(path: str | os.PathLike, command: str) -> str:
    """The line naming a stale generated page and the command that regenerates it."""
    return f"{path} is out of date: run {command}"


def update_pages(texts: Mapping[Path, str], check: bool, command: str, root: Path | None = None) -> int:
    """A generator's ``main``: write each stale page of ``texts`` (printing ``wrote PATH``), or with ``check`` write
    nothing and name each on stderr (:func:`out_of_date`); the exit status, 1 when ``check`` found a stale page.
    ``root``: print paths relative to it."""
    stale = stale_files(texts, write=not check)
    for path in stale:
        shown = path.relative_to(root) if root is not None else path
        print(out_of_date(shown, command) if check else f"wrote {shown}", file=sys.stderr if check else sys.stdout)
    return int(check and bool(stale))
