"""Where a weights file is: a path inside an installed distribution or on disk, or a URL downloaded into the cache.

Every file is checked against its entry's sha256 before it is read, wherever it comes from. A download goes through
:func:`tactile_zoo.data.download.fetch`: into a temporary file next to its destination, renamed into the cache
(``<cache home>/weights/``, see :func:`~tactile_zoo.data.base.cache_home`) only when the sha256 matches, deleted
otherwise. A cached file that no longer matches (corrupted on disk) is deleted and downloaded again. A local or
installed file that does not match is refused and left alone: it is the user's.
"""

from __future__ import annotations

import re
import urllib.parse
from pathlib import Path

from ..data.base import cache_home, file_sha256
from ..data.download import fetch
from ..errors import DatasetError
from .entry import WeightEntry

__all__ = ["weights_cache", "cached_path", "locate"]


def weights_cache() -> Path:
    """The folder downloaded weights are kept in: ``<cache home>/weights``."""
    return cache_home() / "weights"


def cached_path(entry: WeightEntry) -> Path:
    """Where the download of ``entry`` lives in the cache: ``<sha256 prefix>-<file name from the URL>``."""
    name = Path(urllib.parse.urlsplit(entry.url or "").path).name or f"{entry.tag}.safetensors"
    return weights_cache() / f"{entry.sha256[:16]}-{re.sub(r'[^A-Za-z0-9._-]', '_', name)}"


def locate(entry: WeightEntry, *, download: bool = True, timeout: float = 60.0) -> Path:
    """The verified ``.safetensors`` file of ``entry``: its local file, else its cached download, else a download.

    Raises:
        DatasetError: the file is missing (and there is no URL, or ``download`` is False), its sha256 does not match
            the entry's, or the download fails; the message names the entry, the file or URL, and what is wrong.
    """
    local = entry.local_path()
    if local is not None and local.is_file():
        got = file_sha256(local)
        if got != entry.sha256:
            raise DatasetError(f"weights {entry.tag!r} ({entry.origin}): {local} has sha256 {got}, the manifest says "
                               f"{entry.sha256}; the file is damaged or not the one the manifest describes")
        return local
    if not entry.url:
        raise DatasetError(f"weights {entry.tag!r} ({entry.origin}): file {local} not found, and the entry has no url")
    path = cached_path(entry)
    if path.is_file():
        if file_sha256(path) == entry.sha256:
            return path
        path.unlink()  # a damaged cache entry is never trusted: fetch it again
    if not download:
        raise DatasetError(f"weights {entry.tag!r} are not in the cache ({path}) and downloading is off")
    hint = f"(weights {entry.tag!r} from {entry.origin}; or download {entry.url} yourself and use it as a local file)"
    return fetch(entry.url, path, entry.sha256, timeout=timeout, hint=hint)
