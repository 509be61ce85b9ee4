"""Output folders tactile-zoo owns: one rule for every command that writes a folder (``bench --out``,
``export --out``), so that no command overwrites a file it did not write.

- The tool marks a folder it writes with a *marker*, a file only it writes (``run.json`` of a bench folder,
  ``tactile-zoo-export.json`` of an export folder).
- A folder that exists and holds anything but carries no marker (nor the files an older version wrote before
  markers existed) belongs to someone else: it is refused before any work, naming the folder and the first entries
  it holds (:func:`check_folder`). A new or empty folder is taken and marked.
- In a folder it owns, each command replaces only its own files: bench resumes its cells, export replaces the files
  of one model as one set (:mod:`tactile_zoo.export.folder`).

This module sits just above :mod:`tactile_zoo.errors` and :mod:`tactile_zoo._files` in the import layers, so every
layer that writes a folder can use it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Container
from dataclasses import dataclass
from pathlib import Path

from ._files import open_temporary
from .errors import ConfigError

__all__ = ["FolderRule", "folder_entries", "check_folder", "make_writable"]


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
