"""Bring-your-own recordings, and ALU-Textures (which is not public) on the same loader.

Folder format under the data home (one file per trial)::

    <root>/<name>/raw/<class_name>/<trial>.csv|.npy            k-fold protocol over the trials
    <root>/<name>/raw/{train,test}/<class_name>/<trial>.csv|.npy   fixed protocol: the user's own train/test split

A trial is a table with one row per time step; its columns are the taxel readings in row-major taxel order, all
channels of a taxel together (``[x, y, z]`` of taxel 0, then of taxel 1, ...), followed by the global features
(joint angles, ...): ``N * C + G`` columns for a sensor with ``N`` taxels, ``C`` channels per taxel and ``G``
globals. A ``.csv`` (comma, semicolon or tab between values, ``.`` as the decimal mark, quotes allowed) may start
with one row of column names (a row in which no field is or looks like a number); a ``.npy`` is a 2-D real array
``(T, N * C + G)``, read with ``allow_pickle=False``. A file above the input size limit (``$TACTILE_ZOO_MAX_INPUT_MB``,
default 2048) or not a regular file is an error. Hidden files are ignored; anything else in a class folder is an
error.

Classes are the sorted class-folder names, or the ``classes=`` list (label = position in the list; then a folder not
in the list is an error). All trials must have the same number of steps, unless ``num_steps`` is given: longer trials
are cropped to their first ``num_steps`` rows, shorter ones are an error.

Protocols: with ``train``/``test`` folders, the fixed split (``num_folds == 1``, ``val`` carved from ``train``);
otherwise a stratified ``num_folds``-fold over the trials (default 5; fold ``f`` is ``test``, ``val`` carved from the
rest). Every trial is its own group.

Using it for your own data (any registered sensor)::

    from tactile_zoo.data.datasets import define_recordings
    define_recordings("my_grasps", sensor="biotac_sp", num_channels=1)   # registers the dataset "my_grasps"
    ds = tactile_zoo.load_dataset("my_grasps", root="~/tactile", split="train")   # ~/tactile/my_grasps/raw/...

or without registering: ``RecordingsDataset(root, folder="my_grasps", sensor="biotac_sp", num_channels=1)``.

``alu_textures`` (the X-Tacformer paper's ALU-Textures: 10 fabrics x 20 trials, an Allegro hand with two uSkin
fingertips, 2 x 30 taxels x 3 axes + 8 joint angles, 50 steps) is this format with the ``uskin_allegro`` sensor.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from ...errors import ConfigError, DatasetError
from ...registry import get_sensor, register_dataset
from ..base import TactileDataset, TensorData, data_home
from ..sensors import USKIN_ALLEGRO, Sensor
from ._io import check_finite, load_npy, read_numeric_csv

__all__ = ["RecordingsDataset", "AluTextures", "define_recordings"]

_SUFFIXES = (".csv", ".npy")
_FIXED = ("train", "test")


def _visible_dirs(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


class RecordingsDataset(TactileDataset):
    """Trials recorded with any registered sensor (see the module docstring for the folder format).

    A subclass sets ``name``, ``sensor``, ``num_channels``, ``num_globals`` (and optionally ``num_steps``,
    ``class_names``) as class attributes; every one of them can also be given per instance.

    Args:
        folder: the dataset folder under ``root`` (default: the class's ``name``).
        sensor: a registered sensor name or a :class:`~tactile_zoo.data.sensors.Sensor`.
        num_channels: channels per taxel ``C`` (default: the sensor's channel count).
        num_globals: global features per step ``G`` (default 0).
        num_steps: crop every trial to this many steps (shorter trials are an error).
        classes: class names in label order; a class folder not listed is an error.
        num_folds: folds of the k-fold protocol (default 5; ignored with train/test folders).
        **kwargs: :class:`~tactile_zoo.data.base.TactileDataset`'s (``transform``, ``augment``, ...).
    """

    name = "recordings"
    num_channels: ClassVar[int | None] = None
    num_globals: ClassVar[int] = 0
    num_steps: ClassVar[int | None] = None

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, folder: str | None = None, sensor: str | Sensor | None = None,
                 num_channels: int | None = None, num_globals: int | None = None, num_steps: int | None = None,
                 classes: list[str] | tuple[str, ...] | None = None, num_folds: int = 5, **kwargs: Any) -> None:
        if folder is not None:
            if not folder or Path(folder).name != folder or folder in (".", ".."):
                raise ConfigError(f"recordings: folder must be a plain folder name, got {folder!r}")
            self.name = folder
        if sensor is not None:
            self.sensor = get_sensor(sensor) if isinstance(sensor, str) else sensor
        if not isinstance(getattr(self, "sensor", None), Sensor):
            raise ConfigError(f"{self.name}: pass sensor= (one of the registered sensors, e.g. 'biotac_sp')")
        channels = num_channels if num_channels is not None else self.num_channels
        self.num_channels = int(channels if channels is not None else max(1, len(self.sensor.channels)))
        self.num_globals = int(num_globals if num_globals is not None else self.num_globals)
        steps = num_steps if num_steps is not None else self.num_steps
        self.num_steps = None if steps is None else int(steps)
        if self.num_channels < 1 or self.num_globals < 0 or (self.num_steps is not None and self.num_steps < 1):
            raise ConfigError(f"{self.name}: need num_channels >= 1, num_globals >= 0, num_steps >= 1 (or None); got "
                              f"{self.num_channels}, {self.num_globals}, {self.num_steps}")
        if int(num_folds) < 2:
            raise ConfigError(f"{self.name}: num_folds must be >= 2, got {num_folds}")
        self.k = int(num_folds)
        self.root = data_home(root)  # the base class sets it too; the class list is read from the folder first
        self.fixed = (self.raw_dir / "train").is_dir() and (self.raw_dir / "test").is_dir()
        self.class_names = self._classes(classes)
        super().__init__(root, split, fold, download, **kwargs)

    # ------------------------------------------------------------------------------------------- layout
    @property
    def raw_dir(self) -> Path:
        return self.root / self.name / "raw"  # per instance: `folder=` renames the folder without a subclass

    def _class_roots(self) -> list[Path]:
        """The folders holding class folders: ``raw/`` or ``raw/train`` and ``raw/test``."""
        return [self.raw_dir / p for p in _FIXED] if self.fixed else [self.raw_dir]

    def _classes(self, classes: list[str] | tuple[str, ...] | None) -> tuple[str, ...]:
        if not self.raw_dir.is_dir():
            return tuple(classes or self.class_names)  # the base class reports the missing folder
        found = sorted({d.name for r in self._class_roots() if r.is_dir() for d in _visible_dirs(r)})
        listed = tuple(classes) if classes is not None else tuple(self.class_names)
        if not listed:
            if not found:
                raise DatasetError(f"{self.name}: no class folders in {self.raw_dir} (expected <class_name>/<trial>"
                                   f".csv|.npy, or train/ and test/ holding such folders)")
            return tuple(found)
        if len(set(listed)) != len(listed):
            raise ConfigError(f"{self.name}: classes= lists a class twice: {list(listed)}")
        unknown = [c for c in found if c not in listed]
        if unknown:
            where = " or ".join(str(r) for r in self._class_roots())
            raise DatasetError(f"{self.name}: class folder(s) {unknown} in {where} are not in the class list "
                               f"{list(listed)}")
        absent = [c for c in listed if c not in found]
        if absent:
            raise DatasetError(f"{self.name}: no folder for class(es) {absent} under {self.raw_dir}")
        return listed

    @classmethod
    def availability(cls, root: str | os.PathLike | None = None) -> tuple[bool, str]:
        raw = cls.raw_dir_for(root)
        if raw.is_dir() and _visible_dirs(raw):
            return True, str(raw)
        return False, (f"no recordings at {raw}: expected {raw}/<class_name>/<trial>.csv|.npy (or train/ and test/ "
                       f"folders holding such class folders). {cls.obtain}").strip()

    def raw_present(self) -> bool:
        return self.raw_dir.is_dir()

    def missing_message(self) -> str:
        return (f"{self.name}: recordings folder {self.raw_dir} not found; expected {self.raw_dir}/<class_name>/"
                f"<trial>.csv|.npy. {self.obtain}").strip()

    def _trials(self) -> list[tuple[str, int, Path]]:
        """``(partition, label, file)`` of every trial, sorted."""
        out = []
        for root_dir in self._class_roots():
            part = root_dir.name if self.fixed else "train"
            for label, cls_name in enumerate(self.class_names):
                class_dir = root_dir / cls_name
                if not class_dir.is_dir():
                    continue
                files = [p for p in sorted(class_dir.iterdir()) if not p.name.startswith(".")]
                for p in files:
                    if p.suffix.lower() not in _SUFFIXES or not p.is_file():
                        raise DatasetError(f"{p}: not a trial file (expected <trial>.csv or <trial>.npy)")
                if not files:
                    raise DatasetError(f"{class_dir}: empty class folder (no .csv/.npy trials)")
                out += [(part, label, p) for p in files]
        return out

    def raw_files(self) -> list[Path]:
        return [p for _, _, p in self._trials()] if self.raw_dir.is_dir() else []

    def process_options(self) -> dict[str, Any]:
        return {"sensor": self.sensor.name, "nodes": self.sensor.num_nodes, "channels": self.num_channels,
                "globals": self.num_globals, "steps": self.num_steps, "classes": list(self.class_names),
                "fixed": self.fixed}

    # ------------------------------------------------------------------------------------------- reading
    def _read_trial(self, path: Path) -> np.ndarray:
        n, c, g = self.sensor.num_nodes, self.num_channels, self.num_globals
        width = n * c + g
        if path.suffix.lower() == ".npy":
            table = load_npy(path)
            if table.ndim != 2 or table.shape[1] != width:
                raise DatasetError(f"{path}: shape {table.shape}, expected (T, {width}) = (time steps, {n} taxels x "
                                   f"{c} channels + {g} globals)")
            table = table.astype(np.float64)
            check_finite(table, path)
        else:
            table = read_numeric_csv(path, optional_header=True)
            if table.shape[1] != width:
                raise DatasetError(f"{path}: {table.shape[1]} columns, expected {width} ({n} taxels x {c} channels "
                                   f"+ {g} globals, taxels row-major)")
        return table

    def process(self) -> TensorData:
        trials = self._trials()
        if self.fixed:
            for part in _FIXED:
                if not any(t[0] == part for t in trials):
                    raise DatasetError(f"{self.raw_dir / part}: no trials")
        if not trials:
            raise DatasetError(f"{self.raw_dir}: no trials")
        tables, first = [], None
        for _, _, path in trials:
            table = self._read_trial(path)
            if self.num_steps is not None:
                if table.shape[0] < self.num_steps:
                    raise DatasetError(f"{path}: {table.shape[0]} time steps, shorter than the declared length "
                                       f"num_steps={self.num_steps}")
                table = table[: self.num_steps]
            elif first is not None and table.shape[0] != first[1]:
                raise DatasetError(f"{path}: {table.shape[0]} time steps, but {first[0]} has {first[1]}; trials must "
                                   f"have equal length (pass num_steps= to crop them to a common length)")
            first = first or (path, table.shape[0])
            tables.append(table)
        data = np.stack(tables).astype(np.float32)  # (S, T, N*C + G)
        s, t = data.shape[:2]
        n, c = self.sensor.num_nodes, self.num_channels
        x = torch.from_numpy(np.ascontiguousarray(data[:, :, : n * c])).reshape(s, t, n, c)  # (S, T, N, C)
        g = torch.from_numpy(np.ascontiguousarray(data[:, :, n * c:]))  # (S, T, G)
        y = torch.tensor([label for _, label, _ in trials], dtype=torch.long)
        return TensorData(x, g, y, torch.arange(s), tuple(part for part, _, _ in trials))

    # ------------------------------------------------------------------------------------------- protocol
    def count_folds(self, data: TensorData) -> int:
        return 1 if self.fixed else self.k

    def split_indices(self, data: TensorData, fold: int) -> dict[str, np.ndarray]:
        return super().split_indices(data, fold) if self.fixed else self.kfold_indices(data, fold, self.k)


def define_recordings(name: str, sensor: str | Sensor, num_channels: int | None = None, num_globals: int = 0,
                      num_steps: int | None = None, class_names: tuple[str, ...] = (), register: bool = True,
                      **meta: Any) -> type[RecordingsDataset]:
    """A :class:`RecordingsDataset` subclass for ``<root>/<name>/raw/``, registered under ``name`` by default.

    ``meta`` is the registry metadata (``description``, ``citation``, ``revision``, ...), passed through as given (a
    missing ``revision`` is the registry's default); sensor, shapes and classes are filled in.
    """
    sensor_obj = get_sensor(sensor) if isinstance(sensor, str) else sensor
    attrs = {"name": name, "sensor": sensor_obj, "num_channels": num_channels, "num_globals": num_globals,
             "num_steps": num_steps, "class_names": tuple(class_names), "__module__": __name__,
             "__doc__": f"Recordings of {name!r} ({sensor_obj.name}); see :mod:`{__name__}`."}
    cls = type(f"Recordings_{name}", (RecordingsDataset,), attrs)
    if register:
        base = {"sensor": sensor_obj.name, "num_nodes": sensor_obj.num_nodes,
                "num_channels": num_channels or max(1, len(sensor_obj.channels)), "num_globals": num_globals,
                "protocol": "stratified k-fold over trials, or the train/test folders when present",
                "obtain": f"place trials at DIR/{name}/raw/<class_name>/<trial>.csv|.npy"}
        if num_steps is not None:
            base["num_steps"] = num_steps
        if class_names:
            base.update(class_names=tuple(class_names), num_classes=len(class_names))
        register_dataset(name, **{**base, **meta})(cls)
    return cls


@register_dataset(
    "alu_textures", sensor="uskin_allegro", num_classes=10, num_steps=50, num_nodes=60, num_channels=3,
    num_globals=8, num_samples=200, folds=5, revision=1,
    protocol="stratified 5-fold over trials (or the user's train/test folders)", splits=("train", "val", "test"),
    source_url="not public (the X-Tacformer paper's private dataset)",
    citation="\"X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition\" (ALU-Textures)",
    licence="not public",
    description="10 fabrics rubbed by an Allegro hand with two uSkin fingertips (2 x 30 taxels x 3 axes) + 8 joint "
                "angles, 50 steps; classes = the fabric folder names, sorted",
    obtain="not public: place your recorded trials at DIR/alu_textures/raw/<fabric>/<trial>.csv|.npy, 50 rows of "
           "188 columns (60 taxels x [x, y, z] row-major, fingertip 1 first, then 8 joint angles)")
class AluTextures(RecordingsDataset):
    """ALU-Textures in the bring-your-own format (see the module docstring)."""

    name = "alu_textures"
    sensor = USKIN_ALLEGRO
    num_channels = 3
    num_globals = 8
    num_steps = 50
    obtain = ("ALU-Textures is not public: place recorded trials at <root>/alu_textures/raw/<fabric>/<trial>.csv|.npy "
              "(50 rows x 188 columns).")
