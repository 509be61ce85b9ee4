"""The dataset base class every built-in dataset derives from, and where data and caches live.

Conventions follow PyTorch Geometric's datasets: raw files live in ``<root>/<name>/raw/``, a subclass says how to
``download()`` them and how to ``process()`` them into tensors, and an optional ``transform`` is applied per sample.
Two departures, both deliberate:

* processed tensors never go under ``root`` but into the cache directory (``$TACTILE_ZOO_CACHE``, else
  ``~/.cache/tactile_zoo``), keyed by the checksums of the raw files and the processing options, so a shared or
  read-only data home is never written to (the only write under ``root`` is a download into ``raw/``);
* a dataset object is one *split* of one *fold*; the dataset itself carves ``val`` out of its training data,
  deterministically per fold, so every consumer sees the same validation samples.

A subclass sets the class attributes (``name``, ``sensor``, ``class_names``) and implements :meth:`process`; it
overrides :meth:`split_indices` for a protocol other than the released fixed train/test split.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from .._files import atomic_path
from ..errors import ConfigError, DatasetError
from .augment import apply_augmentation, resolve_augmentations
from .guard import check_readable
from .preprocess import RecordingPreprocessing
from .sensors import Sensor
from .spec import DatasetSpec, TactileSample
from .splits import carve_holdout, stratified_group_kfold

#: the errors of a write that found no room: no space, a file size limit, a disk quota
_FULL_DISK = frozenset({errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)})

__all__ = ["TactileDataset", "TensorData", "data_home", "cache_home", "file_sha256", "Augmentation"]

#: ``f(x [T, N, C], generator) -> x'``: a training-only augmentation (see :mod:`tactile_zoo.data.augment`).
Augmentation = Callable[[torch.Tensor, torch.Generator], torch.Tensor]

CACHE_FORMAT = 1  # bump when the processed layout changes


def data_home(root: str | os.PathLike | None = None) -> Path:
    """The data home: ``root``, else ``$TACTILE_ZOO_DATA``, else ``~/.cache/tactile_zoo/data``.

    Raises:
        ConfigError: the data home, or the nearest of its parents that exists, is a file: every dataset's files would
            be looked for (and a download written) under a path that cannot exist.
    """
    if root is not None:
        home, origin = Path(root).expanduser(), "the data root"
    else:
        env = os.environ.get("TACTILE_ZOO_DATA")
        home, origin = ((Path(env).expanduser(), "the data home (from $TACTILE_ZOO_DATA)") if env else
                        (Path.home() / ".cache" / "tactile_zoo" / "data", "the default data home"))
    _check_not_a_file(home, origin)
    return home


def _check_not_a_file(home: Path, origin: str) -> None:
    """Refuse a data home that is a file, or lies under one (``/etc/passwd/data``). A home that does not exist yet is
    fine (a download creates it); one that cannot be inspected is left to the reader that opens it."""
    for path in (home, *home.parents):
        try:
            if not path.exists():  # also False under a file (ENOTDIR): the next parent says which
                continue
        except OSError:
            return
        if path.is_dir():
            return
        inside = f"{home} is a file" if path == home else f"{path}, a parent of {home}, is a file"
        raise ConfigError(f"{origin}: {inside}, not a folder; give a folder that holds one folder per "
                          f"dataset (<root>/<dataset>/raw/)")


def cache_home() -> Path:
    """Where processed tensors go: ``$TACTILE_ZOO_CACHE``, else ``~/.cache/tactile_zoo``."""
    env = os.environ.get("TACTILE_ZOO_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "tactile_zoo"


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


@dataclass
class TensorData:
    """Every sample of a dataset, before splitting.

    ``groups`` marks samples that must stay together (windows of one recording); ``partition`` is the release's own
    assignment per sample (``"train"``, ``"test"``, or the name of an extra test split such as ``"test_solids"``).
    """

    x: torch.Tensor  # (S, T, N, C) float32
    g: torch.Tensor  # (S, T, G) float32
    y: torch.Tensor  # (S,) int64
    groups: torch.Tensor  # (S,) int64
    partition: tuple[str, ...]

    def __post_init__(self) -> None:
        s = self.x.shape[0]
        if not (self.g.shape[0] == self.y.shape[0] == self.groups.shape[0] == len(self.partition) == s):
            raise DatasetError(f"inconsistent sample counts: x {s}, g {self.g.shape[0]}, y {self.y.shape[0]}, "
                               f"groups {self.groups.shape[0]}, partition {len(self.partition)}")
        if self.x.dim() != 4 or self.g.dim() != 3:
            raise DatasetError(f"x must be (S, T, N, C) and g (S, T, G); got {tuple(self.x.shape)} and "
                               f"{tuple(self.g.shape)}")


class TactileDataset(torch.utils.data.Dataset):
    """One split of one fold of a tactile dataset, held as tensors.

    Args:
        root: the data home (one folder per dataset); see :func:`data_home`.
        split: ``"train"``, ``"val"``, ``"test"``, an extra test split in :attr:`extra_splits`, or ``None`` for all.
        fold: the fold of a k-fold protocol, ``0 <= fold < num_folds``.
        download: fetch missing raw files into ``<root>/<name>/raw/`` first.
        transform: PyG-style ``f(TactileSample) -> TactileSample`` applied when a sample is read.
        pre_transform: PyG-style ``f(TactileSample) -> TactileSample`` applied once per sample of the split when the
            dataset is loaded, before augmentation and before ``transform``; its results are what the dataset holds
            (``x``, ``g``, ``y``, the spec's shapes). Not part of the processed cache's key (a function has no
            stable hash), so it runs at every load, never on a cached copy of another transform's output.
        augment: a training-only augmentation ``f(x, generator) -> x``, a name from :mod:`.augment` (``"jitter"``,
            ``"scaling"``, ``"magnitude_warp"``, ``"time_warp"``), or a sequence of them (applied in order); only
            the ``train`` split is expanded.
        augment_factor: the ``train`` split grows to ``augment_factor`` times its size: the originals plus
            ``augment_factor - 1`` augmented copies of each.
        augment_seed: seed of the augmentation generator.

    Attributes:
        x, g, y, groups: the split's tensors ``(S, T, N, C)``, ``(S, T, G)``, ``(S,)``, ``(S,)``.
        spec: the :class:`DatasetSpec`.
        num_folds: how many folds the protocol defines (1 for a fixed split).
    """

    name: ClassVar[str] = ""
    sensor: ClassVar[Sensor]
    class_names: ClassVar[tuple[str, ...]] = ()
    extra_splits: ClassVar[tuple[str, ...]] = ()
    protocol: ClassVar[str] = "fixed"
    val_fraction: ClassVar[float] = 0.2
    binary: ClassVar[bool] = False  # event data: augmented copies are re-binarised (threshold 0.5)
    simulated: ClassVar[bool] = False
    obtain: ClassVar[str] = ""  # how a user gets the raw files (shown when they are missing)
    downloadable: ClassVar[bool] = False  # download=True can fetch the raw files (the harness needs --download)
    frame_period: ClassVar[float | None] = None  # seconds between time steps, when known (`tactile-zoo stream`)

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, transform: Callable[[TactileSample], TactileSample] | None = None,
                 pre_transform: Callable[[TactileSample], TactileSample] | None = None,
                 augment: str | Augmentation | Sequence[str | Augmentation] | None = None, augment_factor: int = 1,
                 augment_seed: int = 0) -> None:
        super().__init__()
        self.root = data_home(root)
        self.split, self.fold, self.transform = split, int(fold), transform
        allowed = ("train", "val", "test", *self.extra_splits)
        if split is not None and split not in allowed:
            raise ConfigError(f"{self.name}: unknown split {split!r}; choose one of {', '.join(allowed)} or None")
        check_readable(self.name, split)
        if download and not self.raw_present():
            self.download()
        if not self.raw_present():
            raise DatasetError(self.missing_message())
        data = self._load_processed()
        self.num_folds = self.count_folds(data)
        if not 0 <= self.fold < self.num_folds:
            raise ConfigError(f"{self.name}: fold={fold} is out of range; this protocol has {self.num_folds} "
                              f"fold(s) (0..{self.num_folds - 1})")
        if split is None:
            idx = np.arange(len(data.y))
        else:
            idx = self.split_indices(data, self.fold)[split]
        idx_t = torch.as_tensor(idx, dtype=torch.long)
        self.x, self.g, self.y, self.groups = data.x[idx_t], data.g[idx_t], data.y[idx_t], data.groups[idx_t]
        if pre_transform is not None:
            self._pre_transform(pre_transform)
        if augment is not None and augment_factor > 1 and split == "train":
            self._expand(resolve_augmentations(augment, self.binary, self.name), augment_factor, augment_seed)
        elif augment_factor < 1:
            raise ConfigError(f"augment_factor must be >= 1, got {augment_factor}")
        # the shapes of what the dataset holds (a pre_transform may change them; an empty split keeps the data's)
        shape_x, shape_g = (self.x, self.g) if len(self.y) else (data.x, data.g)
        self.spec = DatasetSpec(self.name, len(self.class_names), tuple(self.class_names), int(shape_x.shape[1]),
                                int(shape_x.shape[2]), int(shape_x.shape[3]), int(shape_g.shape[2]), self.sensor)

    # ------------------------------------------------------------------------------------------- subclass hooks
    @classmethod
    def raw_dir_for(cls, root: str | os.PathLike | None = None) -> Path:
        return data_home(root) / cls.name / "raw"

    @property
    def raw_dir(self) -> Path:
        return self.raw_dir_for(self.root)

    @property
    def processed_dir(self) -> Path:
        return cache_home() / self.name / "processed"

    def raw_files(self) -> list[Path]:
        """The raw files whose checksums key the processed cache (empty: never cache)."""
        return []

    def raw_present(self) -> bool:
        """Whether the raw data is in place (simulators: always)."""
        return self.simulated or self.raw_dir.exists()

    @classmethod
    def availability(cls, root: str | os.PathLike | None = None) -> tuple[bool, str]:
        """``(present, reason)`` without loading anything; the harness uses it to skip absent datasets."""
        if cls.simulated:
            return True, "simulated"
        raw = cls.raw_dir_for(root)
        return (True, str(raw)) if raw.exists() else (False, f"no raw data at {raw}. {cls.obtain}".strip())

    def missing_message(self) -> str:
        return f"{self.name}: raw data not found at {self.raw_dir}. {self.obtain}".strip()

    @classmethod
    def recording_preprocessing(cls, options: dict[str, Any]) -> RecordingPreprocessing | None:
        """What loading with ``options`` (the constructor's keyword options, defaults filled in) does to one raw
        recording before the models read it, for pretrained weights to apply to a user's file; ``None`` (the default):
        recordings are fed as they are. A subclass that transforms recordings overrides it with the function its own
        :meth:`process` applies."""
        return None

    def download(self) -> None:
        raise DatasetError(f"{self.name} cannot be downloaded automatically. {self.obtain}".strip())

    def process(self) -> TensorData:
        """Read (or generate) every sample."""
        raise NotImplementedError

    def process_options(self) -> dict[str, Any]:
        """Options that change :meth:`process`'s output; they key the cache with the raw checksums."""
        return {}

    def count_folds(self, data: TensorData) -> int:
        return 1

    def split_indices(self, data: TensorData, fold: int) -> dict[str, np.ndarray]:
        """Index arrays per split name. Default: the release's fixed split, ``val`` carved from ``train``."""
        part = np.asarray(data.partition)
        y, groups = data.y.numpy(), data.groups.numpy()
        train, val = carve_holdout(np.flatnonzero(part == "train"), y, groups, self.val_fraction, seed=fold)
        out = {"train": train, "val": val, "test": np.flatnonzero(part == "test")}
        out.update({name: np.flatnonzero(part == name) for name in self.extra_splits})
        return out

    def kfold_indices(self, data: TensorData, fold: int, k: int, pool: np.ndarray | None = None, seed: int = 0
                      ) -> dict[str, np.ndarray]:
        """Stratified group k-fold over ``pool`` (default: all): fold ``fold`` is ``test``, ``val`` is carved from
        the rest, the remainder is ``train``."""
        y, groups = data.y.numpy(), data.groups.numpy()
        pool = np.arange(len(y)) if pool is None else pool
        folds = stratified_group_kfold(pool, y, groups, k, seed)
        rest = np.sort(np.concatenate([f for i, f in enumerate(folds) if i != fold]))
        train, val = carve_holdout(rest, y, groups, self.val_fraction, seed=seed * 1000 + fold)
        return {"train": train, "val": val, "test": folds[fold]}

    # ------------------------------------------------------------------------------------------- caching
    def _cache_key(self) -> str | None:
        files = self.raw_files()
        if not files:
            return None
        parts = {"format": CACHE_FORMAT, "name": self.name, "options": self.process_options(),
                 "raw": sorted((str(p.relative_to(self.raw_dir)) if p.is_relative_to(self.raw_dir) else p.name,
                                file_sha256(p)) for p in files)}
        return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]

    def _load_processed(self) -> TensorData:
        key = self._cache_key()
        path = self.processed_dir / f"{key}.pt" if key else None
        if path is not None and path.exists():
            if not path.is_file():
                # not a file this cache wrote (a folder, a FIFO): it is the user's, never deleted or read over
                raise DatasetError(f"{self.name}: the processed cache file {path} is a "
                                   f"{'folder' if path.is_dir() else 'special file'}, not a cache file; move it away "
                                   f"(it is rebuilt from the raw data), or set TACTILE_ZOO_CACHE to another folder")
            try:
                blob = torch.load(path, weights_only=True)
                return TensorData(blob["x"], blob["g"], blob["y"], blob["groups"], tuple(blob["partition"]))
            except Exception:  # a corrupt cache is rebuilt, never trusted
                path.unlink(missing_ok=True)
        data = self.process()
        if path is not None:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                with atomic_path(path) as tmp:
                    torch.save({"x": data.x, "g": data.g, "y": data.y, "groups": data.groups,
                                "partition": list(data.partition)}, tmp)
            except (OSError, RuntimeError) as exc:  # torch's file writer raises RuntimeError on a full disk
                # an unwritable cache costs time, never correctness, and its temporary file is gone (atomic_path);
                # a full disk is said once, in one line (a folder the user cannot write stays silent, as before)
                if isinstance(exc, RuntimeError) or exc.errno in _FULL_DISK:
                    why = exc.strerror if isinstance(exc, OSError) else "the disk is full or a file size limit was hit"
                    warnings.warn(f"{self.name}: could not write the processed cache {path} ({why}); continuing "
                                  f"without it (the next load processes the raw data again)", stacklevel=2)
        return data

    def _pre_transform(self, fn: Callable[[TactileSample], TactileSample]) -> None:
        """Apply ``pre_transform`` to every sample of the split, once."""
        if not len(self.y):
            return
        out = [fn(TactileSample(x, g, int(y))) for x, g, y in zip(self.x, self.g, self.y)]
        try:
            self.x = torch.stack([torch.as_tensor(s.x) for s in out])
            self.g = torch.stack([torch.as_tensor(s.g) for s in out])
            self.y = torch.as_tensor([int(s.y) for s in out], dtype=torch.long)
        except (AttributeError, TypeError, RuntimeError) as exc:
            raise ConfigError(f"{self.name}: pre_transform must return TactileSample(x [T, N, C], g [T, G], y) of "
                              f"one shape for every sample ({type(exc).__name__}: {exc})") from None

    # ------------------------------------------------------------------------------------------- augmentation
    def _expand(self, augment: Augmentation | Sequence[Augmentation], factor: int, seed: int) -> None:
        fns = list(augment) if isinstance(augment, Sequence) else [augment]
        gen = torch.Generator().manual_seed(seed)
        copies, g_copies = [], []
        for _ in range(factor - 1):
            for xi, gi in zip(self.x, self.g):
                for fn in fns:
                    xi, gi = apply_augmentation(fn, xi, gi, gen)  # a time warp moves g along with x
                copies.append((xi > 0.5).to(xi.dtype) if self.binary else xi)
                g_copies.append(gi)
        n = len(self.y)
        self.x = torch.cat([self.x, torch.stack(copies)])
        self.g = torch.cat([self.g, torch.stack(g_copies)])
        self.y = self.y.repeat(factor)
        self.groups = self.groups.repeat(factor)  # a copy stays in its original's group
        assert self.x.shape[0] == n * factor

    # ------------------------------------------------------------------------------------------- Dataset API
    def __len__(self) -> int:
        return int(self.y.shape[0])

    def __getitem__(self, i: int) -> TactileSample:
        sample = TactileSample(self.x[i], self.g[i], int(self.y[i]))
        return self.transform(sample) if self.transform is not None else sample

    def tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(x, g, y)`` of the whole split at once (the fast path for training), transform applied."""
        if self.transform is None:
            return self.x, self.g, self.y
        samples = [self[i] for i in range(len(self))]
        return (torch.stack([s.x for s in samples]), torch.stack([s.g for s in samples]),
                torch.as_tensor([s.y for s in samples], dtype=torch.long))

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(split={self.split!r}, fold={self.fold}, samples={len(self)}, "
                f"x={tuple(self.x.shape[1:])}, classes={len(self.class_names)})")
