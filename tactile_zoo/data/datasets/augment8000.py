"""Augment8000: 20 objects grasped by a Jaco three-finger gripper with three OptoForce 3-axis sensors.

Maus, Kim, Nocentini, Bashir, Cavallo; public repository https://github.com/philipmaus/Tactile_Object_Classification.
Two files, both read: ``000_training_data.csv`` (2000 samples) and ``000_real_life_data.csv`` (120 samples recorded
by 12 other experimenters: the test set the paper's D-CNN accuracy 0.7258 is measured on).

File format (every row 16 comma-separated fields)::

    row 0                      file header; field 6 (0-based) is the number of samples N
    then per sample, 52 rows:
      header,seq,<k>,stamp start,<ns>,stamp end,<ns>,nMeas,50,class label,<label>,0,0,0.0,0.0,0.0
      timestep,opto1_x,opto1_y,opto1_z,eucl force 1,opto2_x,...,eucl force 3,finger1_pos,finger2_pos,finger3_pos
      50 rows: timestep + 15 features [F1x F1y F1z |F1| F2x F2y F2z |F2| F3x F3y F3z |F3| pos1 pos2 pos3]

The sample length is the declared ``nMeas`` (50 in the release); every sample of a file must have the same length.

Preprocessing, as in the source:

1. object-weight compensation on sensors 2 and 3: if the largest of the sensor's first three z values exceeds 0.05,
   ``z -= w cos(theta)`` and ``y += w sin(theta)`` at every step, with ``w`` the mean of those three z values and
   ``theta = (finger2_pos - 20) / 360 * 2 pi`` (finger 2's position at that step, for both sensors, as the source
   does). The force norms ``|F|`` are left as recorded (the source does not recompute them).
2. a per-feature z-score (15 features) with training statistics: computed from the whole training file (every
   sample and step, population std) when it is present, else the source's published constants
   (:data:`SOURCE_MEAN`, :data:`SOURCE_STD`). The real-life test file never contributes statistics. Using the whole
   training file (not each fold's training part) follows the source; it lets the validation folds' statistics in,
   never the test set's.

Samples: ``x [T, 3, 4]`` (three sensor nodes x (Fx, Fy, Fz, |F|)), ``g [T, 3]`` (the finger positions).

Protocol (``num_folds`` folds, default 10): stratified k-fold over the training file's samples: fold ``f`` is
``val``, the other folds are ``train``, and ``test`` is the 120 real-life samples for every fold. Augmented copies
(``augment=``) are made from the ``train`` split only, so a sample's copies always stay in its fold (the source
augmented before splitting). Fallbacks, each with a warning: with only the real-life file, a stratified k-fold over
its 120 samples (fold ``f`` is ``test``, ``val`` is carved from the rest; with 6 samples per class and 10 folds,
each class is absent from the test part of some folds, see :func:`~tactile_zoo.data.splits.stratified_group_kfold`);
with only the training file, the same k-fold over the training samples.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...errors import ConfigError, DatasetError
from ...registry import register_dataset
from ..base import TactileDataset, TensorData, data_home
from ..sensors import OPTOFORCE3
from ..splits import stratified_group_kfold
from ._io import check_finite, parse_numeric_rows, read_csv_lines

__all__ = ["Augment8000", "CLASSES", "SOURCE_MEAN", "SOURCE_STD", "compensate_weight", "read_augment8000"]

REPOSITORY = "https://github.com/philipmaus/Tactile_Object_Classification"
TRAIN_FILE, REAL_FILE = "000_training_data.csv", "000_real_life_data.csv"
CLASSES = ("corn", "candle", "banana", "rubiks cube", "cotton pads", "knotted rope", "tissues", "etui",
           "green pepper", "stuffed animal", "pepper mill", "tennis ball", "tomato", "sponge", "grapes", "squash ball",
           "light bulb", "massage ball", "cucumber", "empty")
#: The source's training-set statistics per feature (F1x F1y F1z |F1| F2x ... |F3| pos1 pos2 pos3).
SOURCE_MEAN = np.array([-0.2332938, 0.43448809, -0.02102928, 0.565528053, 0.0387262300, 0.0398179976, 0.567078027,
                        0.716047705, -0.30245472, 0.286651377, 0.0750420239, 0.468298448, 33.11166, 33.593965,
                        33.577765])
SOURCE_STD = np.array([0.39165433, 0.57594662, 0.21116683, 0.6734428, 0.267279, 0.26111209, 0.67091961, 0.72118393,
                       0.28212706, 0.27444994, 0.19451229, 0.39772967, 6.77925638, 7.47350691, 7.58818243])
_FEATURES = 15
_COLUMNS = 1 + _FEATURES


def _trim(fields: list[str]) -> list[str]:
    while fields and fields[-1] == "":
        fields = fields[:-1]
    return fields


def _int_field(value: str, where: str, what: str) -> int:
    try:
        number = float(value)
    except ValueError:
        raise DatasetError(f"{where}: {what} {value!r} is not a number") from None
    if not math.isfinite(number) or number != int(number):
        raise DatasetError(f"{where}: {what} {value!r} is not an integer")
    return int(number)


def read_augment8000(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read one Augment8000 CSV: ``(features float64 [N, T, 15], labels int64 [N])``, raw (no preprocessing)."""
    lines = [(number, _trim(fields) if fields[-1] == "" else fields) for number, fields in read_csv_lines(path)]
    if not lines:
        raise DatasetError(f"{path}: empty file")
    number, head = lines[0]
    if len(head) < 7:
        raise DatasetError(f"{path}: line {number}: the file header has {len(head)} fields; field 7 must hold the "
                           f"number of samples")
    declared = _int_field(head[6], f"{path}: line {number}", "number of samples (field 7 of the file header)")
    if declared < 1:
        raise DatasetError(f"{path}: line {number}: the file header declares {declared} samples")
    samples, labels, pos, length = [], [], 1, None
    for k in range(declared):
        if pos >= len(lines):
            raise DatasetError(f"{path}: the file header declares {declared} samples, the file ends after {k} "
                               f"(truncated file)")
        number, fields = lines[pos]
        where = f"{path}: line {number}"
        if not fields or fields[0].lower() != "header" or len(fields) < 11 or fields[7].lower() != "nmeas":
            raise DatasetError(f"{where}: expected the header row of sample {k + 1} (header,seq,<k>,...,nMeas,<T>,"
                               f"class label,<label>,...), got {','.join(fields)[:80]!r}")
        steps = _int_field(fields[8], where, "nMeas")
        label = _int_field(fields[10], where, "class label")
        if not 0 <= label < len(CLASSES):
            raise DatasetError(f"{where}: class label {label} is outside the {len(CLASSES)} classes (0..19)")
        if steps < 1 or (length is not None and steps != length):
            raise DatasetError(f"{where}: sample {k + 1} declares nMeas {steps}; every sample must have the same "
                               f"positive length ({length if length is not None else 'first sample'})")
        length = steps
        if pos + 1 >= len(lines) or [f.lower() for f in lines[pos + 1][1][:1]] != ["timestep"]:
            got = ",".join(lines[pos + 1][1])[:60] if pos + 1 < len(lines) else "end of file"
            raise DatasetError(f"{path}: line {lines[pos + 1][0] if pos + 1 < len(lines) else number + 1}: expected "
                               f"the column-name row (timestep,opto1_x,...) of sample {k + 1}, got {got!r}")
        rows = lines[pos + 2: pos + 2 + steps]
        short = next((i for i, (_, f) in enumerate(rows) if f[:1] and f[0].lower() == "header"), len(rows))
        if short < steps:
            raise DatasetError(f"{where}: sample {k + 1} declares {steps} measurements (nMeas) but has only {short}")
        table = parse_numeric_rows(rows, path, _COLUMNS)
        check_finite(table, path, [n for n, _ in rows])
        samples.append(table[:, 1:])  # drop the timestep column
        labels.append(label)
        pos += 2 + steps
    if pos < len(lines):
        raise DatasetError(f"{path}: line {lines[pos][0]}: data after the {declared} samples the file header "
                           f"declares (wrong sample count in the header?)")
    return np.stack(samples), np.asarray(labels, dtype=np.int64)


def compensate_weight(features: np.ndarray, threshold: float = 0.05) -> np.ndarray:
    """The source's object-weight compensation on sensors 2 and 3 (see the module docstring); a copy."""
    out = np.array(features, dtype=np.float64, copy=True)  # (N, T, 15)
    theta = (out[:, :, 13] - 20.0) / 360.0 * 2.0 * np.pi  # finger 2's position, per step
    for y_col, z_col in ((5, 6), (9, 10)):  # sensor 2, sensor 3
        first = out[:, :3, z_col]  # (N, 3)
        apply = first.max(axis=1) > threshold
        w = first.mean(axis=1, keepdims=True)  # (N, 1)
        out[:, :, z_col] -= np.where(apply[:, None], w * np.cos(theta), 0.0)
        out[:, :, y_col] += np.where(apply[:, None], w * np.sin(theta), 0.0)
    return out


@register_dataset(
    "augment8000", sensor="optoforce3", num_classes=20, class_names=CLASSES, num_steps=50, num_nodes=3,
    num_channels=4, num_globals=3, num_samples=2120, folds=10, revision=1,
    protocol="stratified 10-fold over the training file (fold f = val), test = the 120 real-life samples for every "
             "fold; real-life-only fallback: stratified 10-fold over those 120",
    splits=("train", "val", "test"), source_url=REPOSITORY,
    citation="P. Maus, J. Kim, O. Nocentini, M. Z. Bashir, F. Cavallo, \"The Impact of Data Augmentation on "
             "Tactile-Based Object Classification Using Deep Learning Approach\" (Augment8000; see the repository)",
    licence=f"not verified here; check {REPOSITORY} before redistributing",
    description="Jaco gripper, 3 OptoForce sensors x (Fx, Fy, Fz, |F|) + 3 finger positions, 20 objects, 50 steps; "
                "2000 training + 120 real-life samples",
    obtain=f"download {TRAIN_FILE} and {REAL_FILE} from {REPOSITORY} into DIR/augment8000/raw/; no automatic "
           "download")
class Augment8000(TactileDataset):
    """Augment8000 (see the module docstring).

    Args:
        num_folds: folds of the cross-validation (default 10).
        stats: ``"auto"`` (training-file statistics when the file is present, else the source's) or ``"source"``
            (always the source's published constants).
        **kwargs: :class:`~tactile_zoo.data.base.TactileDataset`'s (``transform``, ``augment``, ...).
    """

    name = "augment8000"
    sensor = OPTOFORCE3
    class_names = CLASSES
    protocol = "kfold"
    obtain = f"Download {TRAIN_FILE} and {REAL_FILE} from {REPOSITORY} into <root>/augment8000/raw/."

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, num_folds: int = 10, stats: str = "auto", **kwargs: Any) -> None:
        if int(num_folds) < 2:
            raise ConfigError(f"augment8000: num_folds must be >= 2, got {num_folds}")
        if stats not in ("auto", "source"):
            raise ConfigError(f"augment8000: stats must be 'auto' or 'source', got {stats!r}")
        self.k, self.stats = int(num_folds), stats
        super().__init__(root, split, fold, download, **kwargs)
        present = {p.name for p in self.raw_files()}
        if present != {TRAIN_FILE, REAL_FILE}:
            missing = REAL_FILE if TRAIN_FILE in present else TRAIN_FILE
            warnings.warn(f"augment8000: {self.raw_dir / missing} is missing, so the paper's protocol (train on the "
                          f"training file, test on the real-life file) is not possible; using a stratified "
                          f"{self.k}-fold cross-validation over {', '.join(sorted(present))} instead", UserWarning,
                          stacklevel=2)

    @classmethod
    def availability(cls, root: str | os.PathLike | None = None) -> tuple[bool, str]:
        raw = cls.raw_dir_for(root)
        found = [raw / f for f in (TRAIN_FILE, REAL_FILE) if (raw / f).is_file()]
        return (True, ", ".join(map(str, found))) if found else (False, cls._hint(root))

    @classmethod
    def _hint(cls, root: str | os.PathLike | None) -> str:
        raw = cls.raw_dir_for(root)
        return (f"Expected {raw / TRAIN_FILE} and/or {raw / REAL_FILE} (root {data_home(root)}): download them from "
                f"{REPOSITORY}; augment8000 is not downloaded automatically.")

    def raw_present(self) -> bool:
        return self.availability(self.root)[0]

    def missing_message(self) -> str:
        return f"{self.name}: raw data not found. {self._hint(self.root)}"

    def raw_files(self) -> list[Path]:
        return [self.raw_dir / f for f in (TRAIN_FILE, REAL_FILE) if (self.raw_dir / f).is_file()]

    def process_options(self) -> dict[str, Any]:
        return {"stats": self.stats}

    def process(self) -> TensorData:
        parts: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for part, file in (("train", TRAIN_FILE), ("test", REAL_FILE)):
            if (self.raw_dir / file).is_file():
                feats, labels = read_augment8000(self.raw_dir / file)
                parts[part] = (compensate_weight(feats), labels)
        lengths = {p: f.shape[1] for p, (f, _) in parts.items()}
        if len(set(lengths.values())) > 1:
            raise DatasetError(f"{self.raw_dir}: the two files' samples differ in length {lengths}")
        if "train" in parts and self.stats == "auto":
            flat = parts["train"][0].reshape(-1, _FEATURES)
            mean, std = flat.mean(0), flat.std(0)
            std = np.where(std > 0, std, 1.0)  # a constant feature stays 0 instead of dividing by zero
        else:
            mean, std = SOURCE_MEAN, SOURCE_STD
        feats = np.concatenate([f for f, _ in parts.values()])
        labels = np.concatenate([y for _, y in parts.values()])
        z = ((feats - mean) / std).astype(np.float32)  # (S, T, 15)
        s, t = z.shape[:2]
        x = torch.from_numpy(np.ascontiguousarray(z[:, :, :12])).reshape(s, t, 3, 4)  # (S, T, 3 sensors, 4)
        g = torch.from_numpy(np.ascontiguousarray(z[:, :, 12:]))  # (S, T, 3 finger positions)
        partition = tuple(p for p, (_, y) in parts.items() for _ in range(len(y)))
        return TensorData(x, g, torch.from_numpy(labels), torch.arange(s), partition)

    def count_folds(self, data: TensorData) -> int:
        return self.k

    def split_indices(self, data: TensorData, fold: int) -> dict[str, np.ndarray]:
        part = np.asarray(data.partition)
        train_pool, test_pool = np.flatnonzero(part == "train"), np.flatnonzero(part == "test")
        if len(train_pool) and len(test_pool):
            folds = stratified_group_kfold(train_pool, data.y.numpy(), data.groups.numpy(), self.k, seed=0)
            rest = np.sort(np.concatenate([f for i, f in enumerate(folds) if i != fold]))
            return {"train": rest, "val": folds[fold], "test": test_pool}
        return self.kfold_indices(data, fold, self.k, pool=train_pool if len(train_pool) else test_pool)
