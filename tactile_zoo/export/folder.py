"""The export folder: ``--out`` of ``tactile-zoo export`` (``export_model(model, out)``) under the output-folder rule
every command shares (:mod:`tactile_zoo._owned`).

- Marker: ``tactile-zoo-export.json``, written by export only, listing each model's files in the folder::

      {"format": "tactile-zoo-export-folder/1",
       "exports": {"sgnet": ["sgnet.forward.onnx", "sgnet.forward.pt", ..., "sgnet.export.json"]}}

- A folder that holds anything but has no marker is refused before any work, naming it and what it holds; a folder
  an older version exported into (every entry a ``MODEL.export.json`` or a file one of them lists) is adopted.
- A file the export would write that the marker does not list (your own ``sgnet.forward.pt`` put into an export
  folder) is refused by name: an export never overwrites a file it did not write.
- One model's files are one set. The new files are written into a hidden staging folder inside ``--out``; only once
  all of them are written and checked are the model's previous files (as the marker lists them) removed and the new
  ones moved in, the description last, so no file of an earlier export of that model (a format or a graph not
  exported this time) is left beside a description that does not mention it. A failed export leaves the folder as
  it was (a folder it created is removed again). Other models' sets in the same folder are left alone.
- One export at a time per folder: an export holds an exclusive lock on the folder (``flock`` on the folder itself,
  released by the kernel when its process dies, however) from its checks to its commit; a second one waits for it,
  saying so. A staging folder found while holding the lock is therefore a killed export's (SIGKILL, a power cut):
  it is removed before the new export stages its own. SIGTERM and Ctrl-C remove the export's own staging folder.
- A file that cannot be written (a full disk, a file size limit) stops the export with one error naming the file and
  the folder, and leaves the folder as it was. TorchScript files are serialised in memory and written by Python:
  torch writing straight to a full disk aborts the process from C++ instead of raising.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from .._files import atomic_write_text
from .._owned import FolderRule, check_folder, folder_entries, make_writable
from ..errors import ConfigError, ExportError

try:
    import fcntl
except ImportError:  # Windows: no flock; exports into one folder are then not serialised
    fcntl = None  # type: ignore[assignment]

__all__ = ["MARKER", "FOLDER_FORMAT", "EXPORT_FOLDER", "ExportFolder", "export_targets", "write_file"]

logger = logging.getLogger(__name__)

MARKER = "tactile-zoo-export.json"
FOLDER_FORMAT = "tactile-zoo-export-folder/1"
#: the ``format`` of a model's description starts so (``tactile-zoo-export/1``): an older version's export
_DESCRIPTION_PREFIX = "tactile-zoo-export/"
_STAGING_PREFIX = ".tactile-zoo-export."
#: the file suffix of each format
_SUFFIX = {"torchscript": "pt", "onnx": "onnx"}
EXPORT_FOLDER = FolderRule("--out", "export", MARKER, "an export folder to replace a model's files in",
                           ignored_prefixes=(_STAGING_PREFIX, f".{MARKER}."))


def export_targets(name: str, formats: Sequence[str], forward: bool, step: bool) -> list[str]:
    """The files an export of ``name`` writes, the description last."""
    graphs = [g for g, wanted in (("forward", forward), ("step", step)) if wanted]
    return [*(f"{name}.{g}.{_SUFFIX[f]}" for g in graphs for f in formats), f"{name}.export.json"]


class ExportFolder:
    """The ``--out`` folder of an export (module docstring)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.created = False
        self.staging: Path | None = None

    # ------------------------------------------------------------------------------------------- what is ours
    def _marker(self) -> dict[str, list[str]] | None:
        try:
            data = json.loads((self.path / MARKER).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(data, dict) or data.get("format") != FOLDER_FORMAT or not isinstance(data.get("exports"),
                                                                                               dict):
            return None
        return {str(k): [str(f) for f in v] for k, v in data["exports"].items() if isinstance(v, list)}

    def _legacy(self) -> dict[str, list[str]] | None:
        """The sets of a folder an older version exported into (no marker), else ``None``."""
        sets: dict[str, list[str]] = {}
        for path in sorted(self.path.glob("*.export.json")):
            try:
                desc = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                return None
            if not isinstance(desc, dict) or not str(desc.get("format", "")).startswith(_DESCRIPTION_PREFIX):
                return None
            files = [f for graph in ("forward", "step") for f in ((desc.get(graph) or {}).get("files") or {}).values()]
            sets[path.name[:-len(".export.json")]] = [*map(str, files), path.name]
        listed = {f for files in sets.values() for f in files}
        return sets if sets and set(folder_entries(self.path, EXPORT_FOLDER)) <= listed else None

    def sets(self) -> dict[str, list[str]]:
        """Each model's files, as the marker (or an older version's descriptions) lists them."""
        return self._marker() or self._legacy() or {}

    def owned(self) -> bool:
        return self._marker() is not None or self._legacy() is not None

    # ------------------------------------------------------------------------------------------- writing
    def check_owner(self) -> list[str]:
        """Refuse a folder that holds anything but is not an export folder; its entries otherwise."""
        return check_folder(self.path, EXPORT_FOLDER, self.owned)

    def check(self, targets: Iterable[str]) -> None:
        """Before any work: refuse a folder that is not an export folder, and a file among ``targets`` (the names
        this export writes) that is there but no export wrote; then create the folder and prove it writable."""
        entries = self.check_owner()
        ours = {f for files in self.sets().values() for f in files} | {MARKER}
        clash = [t for t in targets if t in entries and t not in ours]
        if clash:
            raise ConfigError(f"--out {self.path}: {', '.join(clash)} {'is' if len(clash) == 1 else 'are'} not from "
                              f"an export ({MARKER} does not list {'it' if len(clash) == 1 else 'them'}) and would be "
                              f"overwritten; move {'it' if len(clash) == 1 else 'them'} away or choose another folder")
        self.created = self.created or not self.path.exists()  # checked again under the lock: keep the first answer
        make_writable(self.path, EXPORT_FOLDER)

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the folder's export lock (module docstring), waiting for another export that holds it; the folder
        must exist (:meth:`check` creates it). A folder removed and made again while we waited is locked anew."""
        if fcntl is None:
            yield
            return
        while True:
            fd = os.open(self.path, os.O_RDONLY)
            try:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    logger.info("another tactile-zoo export is writing into %s; waiting for it to finish", self.path)
                    fcntl.flock(fd, fcntl.LOCK_EX)
                except OSError as exc:  # a file system without locks (some network mounts): go on unserialised
                    logger.debug("cannot lock %s (%s): exports into it are not serialised", self.path, exc)
                    yield
                    return
                here = os.fstat(fd)
                try:
                    now = os.stat(self.path)
                except FileNotFoundError:
                    now = None
                if now is None or (now.st_dev, now.st_ino) != (here.st_dev, here.st_ino):
                    make_writable(self.path, EXPORT_FOLDER)  # the other export removed the folder it had made
                    continue
                yield
                return
            finally:
                os.close(fd)  # releases the lock

    def remove_stale(self) -> list[str]:
        """Remove what killed exports left (their staging folders and torn marker files); call it holding the lock,
        so none of them is a live export's. Returns the names removed."""
        stale = [p for p in self.path.glob(f"{_STAGING_PREFIX}*.tmp") if p.is_dir()] + \
            [p for p in self.path.glob(f".{MARKER}.*.tmp") if p.is_file()]
        for path in stale:
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    path.unlink()
        if stale:
            logger.info("removed what a killed export left in %s: %s", self.path, ", ".join(p.name for p in stale))
        return [p.name for p in stale]

    def write_error(self, exc: OSError, file: str | os.PathLike | None = None) -> ExportError:
        """One line for a file the export could not write (a full disk): the file, the folder and why."""
        name = Path(file or exc.filename or "").name
        what = f"cannot write {name} into {self.path}" if name else f"cannot write into {self.path}"
        return ExportError(f"{what}: {exc.strerror or exc}; the export stopped and left the folder as it was")

    def stage(self) -> Path:
        """A new hidden folder inside ``--out`` for this export's files (:attr:`staging`)."""
        self.staging = Path(tempfile.mkdtemp(prefix=_STAGING_PREFIX, suffix=".tmp", dir=self.path))
        return self.staging

    def _write_marker(self, sets: dict[str, list[str]]) -> None:
        atomic_write_text(self.path / MARKER, json.dumps({"format": FOLDER_FORMAT, "exports": sets}, indent=2) + "\n")

    def commit(self, name: str, files: list[str]) -> None:
        """Replace model ``name``'s set by ``files`` (in :attr:`staging`; moved in in this order: the description
        last). The marker first lists both sets, so an export killed half-way leaves only files the next one
        removes."""
        staging = self.staging
        assert staging is not None, "stage() first"
        sets = self.sets()
        old = sets.get(name, [])
        self._write_marker({**sets, name: sorted({*old, *files})})
        for stale in old:
            if stale not in files:
                with contextlib.suppress(FileNotFoundError):
                    (self.path / stale).unlink()
        for file in files:
            os.replace(staging / file, self.path / file)
        self._write_marker({**sets, name: list(files)})
        shutil.rmtree(staging, ignore_errors=True)
        self.staging, self.created = None, False

    def abort(self) -> None:
        """An export failed: drop its staging folder, and the folder itself when this export created it."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
        if self.created:
            with contextlib.suppress(OSError):
                self.path.rmdir()  # only when empty


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to the new file ``path``; an :class:`OSError` (a full disk) names ``path``."""
    try:
        with open(path, "xb") as fh:
            fh.write(data)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(path)) from exc
