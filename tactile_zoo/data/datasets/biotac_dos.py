"""BioTac-DoS: direction of slip on a BioTac SP (Zapata-Impata, Gil, Torres, Sensors 2019).

Public repository https://github.com/yayaneath/BioTacSP-DoS. Release layout, read as is::

    csvs/{n,s,e,w,cw,aw,t}/<object><id>.csv    header ff_e1,...,ff_e24, then one row of 24 integer electrode
                                               values per reading (100 Hz; raw, about 1900-3750, dropping under
                                               contact); the folder is the class

Classes in label order: ``n, s, e, w`` (translational slip north/south/east/west), ``cw, aw`` (rotation clockwise,
anti-clockwise), ``t`` (stable touch). The object is the file name without its trailing digits (the release's
misspelled ``strippes`` is read as ``striped``); 11 objects in four sets: basic (pen, case, sponge, hd), solids
(bottle, cardboard), small (brush, screw), textures (plate, bubbles, striped).

Samples are windows of ``window`` consecutive readings cut inside one recording, never across files (the source
concatenated the recordings first, so some of its windows straddle two files), every ``stride`` readings (default 10
and 10: non-overlapping): ``x [window, 24, 1]``, ``g [window, 0]``. A recording shorter than one window is an error.

Normalisation (``normalize="baseline"``, the default): per electrode, ``x = (b - E) / scale`` with ``b`` the mean of
the recording's first ``baseline`` readings (10) and ``scale`` 1000 raw units: 0 at the start, positive under added
pressure; it removes the per-recording electrode offsets (which drift with temperature) without statistics from other
recordings, so no split leaks into another. ``normalize="minmax"`` scales every reading by its own range over the 24
electrodes, ``x = (max E - E) / (max E - min E)`` (0 where all are equal): 1 at the most pressed electrode, 0 at the
least, the pattern kept and the overall pressure level removed, as the ConvLSTM source scales each of its sensor
images (sign as for the baseline: pressure is positive). ``normalize="none"`` keeps the raw values.

Protocols:

``objects`` (default; the source's generalisation protocol)
    ``train`` and ``val`` come from the basic set; ``test`` holds every window of the seven unseen objects, also
    available per set as ``test_solids``, ``test_small``, ``test_textures``. How ``val`` is carved:

    - ``validation="recordings"`` (default, one fold): 20 % of the basic recordings, whole recordings, stratified,
      seeded. It measures how well the model knows recordings of objects it has seen, not how it generalises.
    - ``validation="object"`` (four folds): fold ``f`` holds out every recording of the ``f``-th basic object
      (pen, case, sponge, hd) and trains on the other three, so validation asks the question the test asks: an
      object never touched in training. Epochs and window lengths chosen on it are chosen for generalisation.
``kfold`` (``num_folds`` folds, default 5)
    stratified k-fold over the recordings of all objects (a recording's windows never split across folds); fold
    ``f`` is ``test``, ``val`` is carved from the rest; ``test_<set>`` are the test windows of that set.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...errors import ConfigError, DatasetError
from ...registry import register_dataset
from ..base import TactileDataset, TensorData, data_home
from ..preprocess import RecordingPreprocessing
from ..sensors import BIOTAC_SP
from ..splits import carve_holdout
from ._io import read_numeric_csv

__all__ = ["BioTacDoS", "OBJECT_SETS", "CLASSES", "normalize_recording"]

REPOSITORY = "https://github.com/yayaneath/BioTacSP-DoS"
CLASSES = ("n", "s", "e", "w", "cw", "aw", "t")
OBJECT_SETS = {"basic": ("pen", "case", "sponge", "hd"), "solids": ("bottle", "cardboard"),
               "small": ("brush", "screw"), "textures": ("plate", "bubbles", "striped")}
_SET_OF = {obj: name for name, objs in OBJECT_SETS.items() for obj in objs}
_ALIASES = {"strippes": "striped"}  # the release's spelling
_HEADER = tuple(f"ff_e{i}" for i in range(1, 25))
_FILE = re.compile(r"^([A-Za-z]+?)[_-]?(\d+)\.csv$")
_UNSEEN = ("solids", "small", "textures")
VALIDATIONS = ("recordings", "object")
NORMALIZATIONS = ("baseline", "minmax", "none")


def normalize_recording(readings: np.ndarray, normalize: str, baseline: int, scale: float, where: str
                        ) -> np.ndarray:
    """One recording ``(R, 24)`` in raw electrode units, normalised as the module docstring says (``"baseline"``,
    ``"minmax"`` or ``"none"``); float64. The loader and pretrained weights' predictions both use it."""
    if normalize == "baseline":
        if readings.shape[0] < baseline:
            raise DatasetError(f"{where}: {readings.shape[0]} readings, fewer than the {baseline} baseline readings")
        return (readings[:baseline].mean(0, keepdims=True) - readings) / scale
    if normalize == "minmax":  # each reading (R, 24) by its own range: the pattern, not the level
        high, low = readings.max(1, keepdims=True), readings.min(1, keepdims=True)
        span = high - low
        return np.divide(high - readings, span, out=np.zeros(readings.shape), where=span > 0)
    return readings


@register_dataset(
    "biotac_dos", sensor="biotac_sp", num_classes=7, class_names=CLASSES, num_steps=10, num_nodes=24,
    num_channels=1, num_globals=0, folds=1, revision=1,
    protocol="objects (default): train/val from the basic objects (val carved by recording), test = unseen objects "
             "(+ test_solids/test_small/test_textures); or protocol='kfold': stratified k-fold over recordings",
    splits=("train", "val", "test", "test_solids", "test_small", "test_textures"),
    source_url=REPOSITORY,
    citation="B. S. Zapata-Impata, P. Gil, F. Torres, \"Learning Spatio Temporal Tactile Features with a ConvLSTM "
             "for the Direction Of Slip Detection\", Sensors 19(3):523, 2019",
    licence=f"not verified here; check {REPOSITORY} before redistributing",
    description="BioTac SP direction of slip (n, s, e, w, cw, aw, stable), 11 objects, about 306 recordings cut "
                "into windows of W readings (default 10)",
    obtain=f"clone {REPOSITORY} and copy its csvs/ folder to DIR/biotac_dos/raw/csvs/ (so that "
           "DIR/biotac_dos/raw/csvs/n/<object><id>.csv exists); no automatic download")
class BioTacDoS(TactileDataset):
    """BioTac-DoS windows (see the module docstring).

    Args:
        protocol: ``"objects"`` (default) or ``"kfold"``.
        validation: how the ``objects`` protocol carves ``val``: ``"recordings"`` (default) or ``"object"`` (leave
            one basic object out; four folds).
        num_folds: folds of the ``kfold`` protocol (default 5).
        window: readings per sample (W, default 10).
        stride: readings between window starts (default ``window``: non-overlapping).
        normalize: ``"baseline"`` (default), ``"minmax"`` (each reading by its own range) or ``"none"``.
        baseline: readings at the start of a recording that define its baseline (default 10).
        scale: raw units per normalised unit (default 1000).
        **kwargs: :class:`~tactile_zoo.data.base.TactileDataset`'s (``transform``, ``augment``, ...).
    """

    name = "biotac_dos"
    sensor = BIOTAC_SP
    class_names = CLASSES
    extra_splits = ("test_solids", "test_small", "test_textures")
    frame_period = 0.01  # the release's 100 Hz readings
    obtain = f"Copy the csvs/ folder of {REPOSITORY} to <root>/biotac_dos/raw/csvs/."

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, protocol: str = "objects", validation: str = "recordings",
                 num_folds: int = 5, window: int = 10,
                 stride: int | None = None, normalize: str = "baseline", baseline: int = 10, scale: float = 1000.0,
                 **kwargs: Any) -> None:
        if protocol not in ("objects", "kfold"):
            raise ConfigError(f"biotac_dos: protocol must be 'objects' or 'kfold', got {protocol!r}")
        if validation not in VALIDATIONS:
            raise ConfigError(f"biotac_dos: validation must be one of {', '.join(map(repr, VALIDATIONS))}, "
                              f"got {validation!r}")
        if validation == "object" and protocol != "objects":
            raise ConfigError("biotac_dos: validation='object' belongs to the 'objects' protocol (the kfold "
                              "protocol mixes every object into every fold)")
        if normalize not in NORMALIZATIONS:
            raise ConfigError(f"biotac_dos: normalize must be one of {', '.join(map(repr, NORMALIZATIONS))}, "
                              f"got {normalize!r}")
        stride = window if stride is None else stride
        for arg, value in (("window", window), ("stride", stride), ("baseline", baseline)):
            if int(value) < 1:
                raise ConfigError(f"biotac_dos: {arg} must be >= 1, got {value}")
        if protocol == "kfold" and int(num_folds) < 2:
            raise ConfigError(f"biotac_dos: the kfold protocol needs num_folds >= 2, got {num_folds}")
        if not scale > 0:
            raise ConfigError(f"biotac_dos: scale must be positive, got {scale}")
        self.protocol, self.validation = protocol, validation
        self.k = int(num_folds)
        self.window, self.stride, self.normalize = int(window), int(stride), normalize
        self.baseline, self.scale = int(baseline), float(scale)
        super().__init__(root, split, fold, download, **kwargs)

    # ------------------------------------------------------------------------------------------- raw files
    @classmethod
    def csv_dir(cls, root: str | os.PathLike | None = None) -> Path:
        return cls.raw_dir_for(root) / "csvs"

    @classmethod
    def availability(cls, root: str | os.PathLike | None = None) -> tuple[bool, str]:
        csvs = cls.csv_dir(root)
        if any((csvs / c).is_dir() for c in CLASSES):
            return True, str(csvs)
        return False, cls._hint(root)

    @classmethod
    def _hint(cls, root: str | os.PathLike | None) -> str:
        return (f"Expected the release's csvs/ folder at {cls.csv_dir(root)} (csvs/{{n,s,e,w,cw,aw,t}}/"
                f"<object><id>.csv): clone {REPOSITORY} and copy its csvs/ folder there (root {data_home(root)}); "
                f"biotac_dos is not downloaded automatically.")

    def raw_present(self) -> bool:
        return self.availability(self.root)[0]

    def missing_message(self) -> str:
        return f"{self.name}: raw data not found. {self._hint(self.root)}"

    def raw_files(self) -> list[Path]:
        csvs = self.csv_dir(self.root)
        return sorted(p for c in CLASSES for p in (csvs / c).glob("*.csv"))

    def process_options(self) -> dict[str, Any]:
        return {"window": self.window, "stride": self.stride, "normalize": self.normalize,
                "baseline": self.baseline, "scale": self.scale}

    @staticmethod
    def object_of(path: Path) -> str:
        """The object a recording shows, from its file name (``strippes12.csv`` -> ``striped``)."""
        match = _FILE.match(path.name)
        if match is None:
            raise DatasetError(f"{path}: file name is not <object><id>.csv")
        obj = _ALIASES.get(match.group(1).lower(), match.group(1).lower())
        if obj not in _SET_OF:
            raise DatasetError(f"{path}: unknown object {match.group(1)!r}; known objects: "
                               f"{', '.join(sorted(_SET_OF))} (and 'strippes' for striped)")
        return obj

    # ------------------------------------------------------------------------------------------- reading
    def process(self) -> TensorData:
        csvs = self.csv_dir(self.root)
        unknown = sorted(p.name for p in csvs.iterdir() if p.is_dir() and p.name not in CLASSES
                         and not p.name.startswith("."))
        if unknown:
            raise DatasetError(f"{csvs}: unknown class folder(s) {unknown}; the classes are {', '.join(CLASSES)}")
        for c in CLASSES:
            if not (csvs / c).is_dir() or not any(p.suffix == ".csv" for p in (csvs / c).iterdir()):
                raise DatasetError(f"{csvs / c}: class folder missing or without .csv recordings")
        xs, ys, groups, parts = [], [], [], []
        for rec, (label, path) in enumerate(self._recordings()):
            if path.suffix != ".csv" or not path.is_file():
                raise DatasetError(f"{path}: unexpected entry in a class folder (expected <object><id>.csv files)")
            obj = self.object_of(path)
            windows = self._windows(read_numeric_csv(path, 24, header=_HEADER), path)  # (K, W, 24)
            xs.append(windows)
            ys += [label] * len(windows)
            groups += [rec] * len(windows)
            set_name = _SET_OF[obj]
            parts += ["train" if set_name == "basic" else f"test_{set_name}"] * len(windows)
        x = torch.from_numpy(np.concatenate(xs)).unsqueeze(-1)  # (S, W, 24, 1)
        return TensorData(x, torch.zeros(x.shape[0], self.window, 0), torch.tensor(ys, dtype=torch.long),
                          torch.tensor(groups, dtype=torch.long), tuple(parts))

    def _recordings(self) -> list[tuple[int, Path]]:
        """``(label, path)`` of every recording, in the order that numbers the groups (a sample's ``groups`` value is
        its recording's index here)."""
        csvs = self.csv_dir(self.root)
        return [(label, path) for label, c in enumerate(CLASSES) for path in sorted((csvs / c).iterdir())
                if not path.name.startswith(".")]

    def _windows(self, readings: np.ndarray, path: Path) -> np.ndarray:
        """``(K, W, 24)`` float32 windows of one recording ``(R, 24)``, normalised."""
        r = readings.shape[0]
        if r < self.window:
            raise DatasetError(f"{path}: {r} readings, fewer than one window of {self.window}")
        readings = normalize_recording(readings, self.normalize, self.baseline, self.scale, str(path))
        starts = np.arange(0, r - self.window + 1, self.stride)
        return np.stack([readings[s: s + self.window] for s in starts]).astype(np.float32)  # (K, W, 24)

    @classmethod
    def recording_preprocessing(cls, options: dict[str, Any]) -> RecordingPreprocessing | None:
        """The normalisation ``options`` name (``normalize``, ``baseline``, ``scale``), applied to one raw recording
        by the function :meth:`process` uses; ``None`` for ``normalize="none"``."""
        normalize = options.get("normalize", "baseline")
        baseline, scale = int(options.get("baseline", 10)), float(options.get("scale", 1000.0))
        if normalize not in NORMALIZATIONS:
            raise ConfigError(f"biotac_dos: normalize must be one of {', '.join(map(repr, NORMALIZATIONS))}, got "
                              f"{normalize!r}")
        if normalize == "none":
            return None
        if normalize == "minmax":
            text = "each reading scaled by its own range over the 24 electrodes, (max E - E) / (max E - min E)"
            head = 1
        else:
            text = (f"each electrode as (b - E) / {scale:g}, b its mean over the recording's first {baseline} "
                    f"readings")
            head = baseline
        return RecordingPreprocessing(f"biotac_dos normalize={normalize!r}", text, head,
                                      lambda table, where: normalize_recording(table, normalize, baseline, scale,
                                                                               where))

    # ------------------------------------------------------------------------------------------- protocols
    def count_folds(self, data: TensorData) -> int:
        if self.protocol == "kfold":
            return self.k
        return len(OBJECT_SETS["basic"]) if self.validation == "object" else 1

    def validation_object(self) -> str | None:
        """The basic object this fold validates on (``validation="object"``), else ``None``."""
        return OBJECT_SETS["basic"][self.fold] if self.validation == "object" else None

    def split_indices(self, data: TensorData, fold: int) -> dict[str, np.ndarray]:
        part = np.asarray(data.partition)
        if self.protocol == "kfold":
            out = self.kfold_indices(data, fold, self.k)
            test = out["test"]
            out.update({f"test_{s}": test[part[test] == f"test_{s}"] for s in _UNSEEN})
            return out
        y, groups = data.y.numpy(), data.groups.numpy()
        basic = np.flatnonzero(part == "train")
        if self.validation == "object":
            objects = np.array([self.object_of(path) for _, path in self._recordings()])  # per recording
            if objects.size != int(data.groups.max()) + 1:
                raise DatasetError(f"{self.csv_dir(self.root)}: the recordings changed since they were read")
            held_out = objects[groups[basic]] == OBJECT_SETS["basic"][fold]
            train, val = basic[~held_out], basic[held_out]
        else:
            train, val = carve_holdout(basic, y, groups, self.val_fraction, seed=fold)
        extra = {f"test_{s}": np.flatnonzero(part == f"test_{s}") for s in _UNSEEN}
        test = np.sort(np.concatenate(list(extra.values())))
        return {"train": train, "val": val, "test": test, **extra}
