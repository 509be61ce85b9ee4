"""Output folders and files tactile-zoo owns: one rule for every command that writes a folder (``bench --out``,
``export --out``) or a file (``train --save``), so that no command overwrites a file it did not write.

- The tool marks a folder it writes with a *marker*, a file only it writes (``run.json`` of a bench folder,
  ``tactile-zoo-export.json`` of an export folder).
- A folder that exists and holds anything but carries no marker (nor the files an older version wrote before
  markers existed) belongs to someone else: it is refused before any work, naming the folder and the first entries
  it holds (:func:`check_folder`). A new or empty folder is taken and marked.
- In a folder it owns, each command replaces only its own files: bench resumes its cells, export replaces the files
  of one model as one set (:mod:`tactile_zoo.export.folder`).
- A single output file (:func:`check_file`) follows the same rule, its marker inside the file (a checkpoint's
  ``format`` key): a path that is free, or a regular file the tool wrote, is taken; an empty path, a symbolic link, a
  folder, anything that is not a regular file (``/dev/null``, a FIFO) and a regular file without the marker are
  refused before any work, naming the flag and the path. The file is then replaced atomically
  (:mod:`tactile_zoo._files`), never written in place.

This module sits just above :mod:`tactile_zoo.errors` and :mod:`tactile_zoo._files` in the import layers, so every
layer that writes a folder can use it.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable, Container
from dataclasses import dataclass
from pathlib import Path

from ._files import open_temporary
from .errors import ConfigError

__all__ = ["FolderRule", "folder_entries", "check_folder", "make_writable", "FileRule", "check_file"]


@dataclass(frozen=True)
class FolderRule:
    """What a command's output folder is, for its messages.

    Attributes:
        flag: the argument naming the folder (``"--out"``).
        kind: the folder's kind, as in "a tactile-zoo {kind} folder" (``"bench"``, ``"export"``).
        marker: the marker file's name (``"run.json"``).
        reuse: what an owned folder is good for, as in "or {reuse}" (``"a bench folder to resume"``).
        ignored: names the tool itself creates before its marker (a lock, the marker's temporary file prefix) or
            that a user may put in a new folder first (plan documents): they do not make a folder someone else's.
        ignored_prefixes: name prefixes of the same (hidden temporary files and folders).
    """

    flag: str
    kind: str
    marker: str
    reuse: str
    ignored: Container[str] = frozenset()
    ignored_prefixes: tuple[str, ...] = ()

    def ignores(self, name: str) -> bool:
        return name in self.ignored or name.startswith(self.ignored_prefixes)


def folder_entries(folder: str | os.PathLike, rule: FolderRule) -> list[str]:
    """The entries of ``folder`` that ``rule`` does not ignore, sorted; none for a folder that is not there."""
    try:
        names = sorted(os.listdir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    return [n for n in names if not rule.ignores(n)]


def check_folder(folder: str | os.PathLike, rule: FolderRule, owned: Callable[[], bool]) -> list[str]:
    """Refuse ``folder`` unless it is new, empty (bar what ``rule`` ignores) or ``owned()`` (it carries the marker,
    or an older version's files). Returns the entries it holds.

    Raises:
        ConfigError: the folder holds other files and is not owned (a path at a file: :func:`make_writable`).
    """
    path = Path(folder)
    try:
        entries = folder_entries(path, rule)
    except OSError:  # unreadable: make_writable says why
        return []
    if entries and not owned():
        raise ConfigError(f"{rule.flag} {path}: the folder holds other files ({', '.join(entries[:3])}"
                          f"{', ...' if len(entries) > 3 else ''}) and is not a tactile-zoo {rule.kind} folder (no "
                          f"{rule.marker} marker); choose a new or empty folder, or {rule.reuse}")
    return entries


def make_writable(folder: str | os.PathLike, rule: FolderRule) -> None:
    """Create ``folder`` (and its parents) and prove a file can be created there.

    Raises:
        ConfigError: it cannot be created or written (naming the folder and why).
    """
    path = Path(folder)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{rule.flag} {path}: cannot write there (it is a file, not a folder); choose a new or "
                          f"empty folder, or {rule.reuse}")
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = open_temporary(path / "probe")
        os.close(fd)
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"{rule.flag} {path}: cannot write there ({exc.strerror or exc}); choose a writable "
                          f"folder") from None


@dataclass(frozen=True)
class FileRule:
    """What a command's output file is, for its messages.

    Attributes:
        flag: the argument naming the file (``"--save"``).
        kind: what the tool writes there, as in "not a {kind}" (``"tactile-zoo checkpoint"``).
        reuse: what an owned file is good for, as in "or {reuse}" (``"a checkpoint `train --save` wrote"``).
        example: a file name to suggest for an empty path (``"MODEL.pt"``).
    """

    flag: str
    kind: str
    reuse: str
    example: str


def _what(mode: int) -> str:
    """A non-regular file's kind, in words."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "not a regular file"


def check_file(path: str | os.PathLike, rule: FileRule, owned: Callable[[Path], bool]) -> Path:
    """Refuse the output file ``path`` unless it is free (nothing there) or a regular file ``owned(path)`` says the
    tool wrote (it carries the marker); then create its folder and prove a file can be created there. Nothing is
    written at ``path`` itself.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ConfigError: an empty path; a symbolic link, folder, device, FIFO or socket; a regular file without the
            marker; a folder that cannot be created or written (each naming ``rule.flag`` and the path).
    """
    if not os.fspath(path).strip():
        raise ConfigError(f"{rule.flag}: an empty path names no file; give a file name such as {rule.example}")
    target = Path(path)
    try:
        mode = os.lstat(target).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:  # a parent that is a file (ENOTDIR), a name too long, no permission to look
        raise ConfigError(f"{rule.flag} {target}: cannot write there ({exc.strerror or exc}); choose another "
                          f"file") from None
    if mode is not None and not stat.S_ISREG(mode):
        raise ConfigError(f"{rule.flag} {target}: it is {_what(mode)}, not a file tactile-zoo wrote; it is left "
                          f"alone: choose a new file name, or {rule.reuse}")
    if mode is not None and not owned(target):
        raise ConfigError(f"{rule.flag} {target}: the file exists and is not a {rule.kind} (no marker), so it is not "
                          f"overwritten; choose a new file name, or {rule.reuse}")
    folder = target.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = open_temporary(target)
        os.close(fd)
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"{rule.flag} {target}: cannot write in folder {folder} ({exc.strerror or exc}); choose a "
                          f"writable folder") from None
    return target
