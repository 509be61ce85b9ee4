"""Ev-Objects and Ev-Containers: event-based NeuTouch grasps (TactileSGNet, Gu et al., IROS 2020).

The recordings come from Taunyazov et al., "Event-Driven Visual-Tactile Sensing and Learning for Robots" (RSS 2020);
Gu, Sng, Taunyazov and Soh released them, binned, with TactileSGNet as ``Ev-Objects.zip`` and ``Ev-Containers.zip``
at the root of https://github.com/clear-nus/TactileSGNet.

Release format (read as is, straight from the zip; nothing is extracted)::

    Ev-Objects/{train,test}/sample_{i}_label_{c}.npy    float32 (39, 2, T): taxel x polarity (ON, OFF) x time bin,
                                                        values 0/1; the label c is in the file name only

Samples become ``x [T, 39, 2]`` (time first), ``g [T, 0]``. The released train/test folders are the protocol
(``num_folds == 1``); ``val`` is carved from ``train`` by the base class, stratified and seeded. An already
extracted folder ``<root>/<name>/raw/Ev-Objects/{train,test}/`` is read when the zip is absent.

The zip's sha256 is checked before its content is used (``verify_checksum=False`` accepts a re-packed archive);
``download=True`` fetches it from the repository's raw URL (override the base URL with ``$TACTILE_ZOO_EV_URL`` or
the class attribute ``base_url``) through :func:`tactile_zoo.data.download.fetch`, which verifies it before renaming
it into place. Every member is checked against zip slip even though nothing is written, so a hostile archive is
refused the same way :func:`~tactile_zoo.data.download.safe_extract` refuses it.

Class names are not in the release. The VT-SNN preprocessing of the same recordings (clear-nus/VT_SNN) lists the
objects in the order used here, very likely the label order; that is unverified.
"""

from __future__ import annotations

import os
import re
from pathlib import Path, PurePosixPath
from typing import Any, ClassVar

import numpy as np
import torch

from ...errors import DatasetError
from ...registry import register_dataset
from ..base import TactileDataset, TensorData
from ..download import check_zip, fetch, not_a_file, open_zip, safe_extract, verify_sha256
from ..sensors import NEUTOUCH
from ._io import check_finite, load_npy

__all__ = ["EvTouchDataset", "EvObjects", "EvContainers", "EV_OBJECTS_CLASSES", "EV_CONTAINERS_CLASSES"]

REPOSITORY = "https://github.com/clear-nus/TactileSGNet"
_SAMPLE = re.compile(r"^sample_(\d+)_label_(\d+)\.npy$")
_PARTITIONS = ("train", "test")

EV_OBJECTS_CLASSES = (
    "003_cracker_box", "004_sugar_box", "006_mustard_bottle", "010_potted_meat_can", "040_large_marker",
    "041_small_marker", "046_plastic_bolt", "061_foam_brick", "065-a_cups", "065-b_cups", "065-c_cups", "065-d_cups",
    "065-e_cups", "071_nine_hole_peg_test", "072-d_toy_airplane", "072-f_toy_airplane", "072-i_toy_airplane",
    "072-j_toy_airplane", "073-a_lego_duplo", "073-d_lego_duplo", "073-h_lego_duplo", "073-n_lego_duplo",
    "073-o_lego_duplo", "073-p_lego_duplo", "077_rubiks_cube", "101_rope", "102-a_duck", "102-b_duck", "103-a_evian",
    "103-b_evian", "103-c_evian", "104_sponge", "106-a_vitasoy", "106-b_vitasoy", "107-a_pepsi_bottle",
    "107-b_pepsi_bottle",
)
EV_CONTAINERS_CLASSES = tuple(f"{obj.split('_', 1)[0]}-{level}_{obj.split('_', 1)[1]}"
                              for obj in ("107_pepsi_bottle", "108_tuna_fish_can", "109_soymilk", "110_coffee_can")
                              for level in "abcde")

_CITATION = ("F. Gu, W. Sng, T. Taunyazov, H. Soh, \"TactileSGNet: A Spiking Graph Neural Network for Event-based "
             "Tactile Object Recognition\", IROS 2020; recordings: T. Taunyazov, W. Sng, H. H. See, B. Lim, J. Kuan, "
             "A. F. Ansari, B. C. K. Tee, H. Soh, \"Event-Driven Visual-Tactile Sensing and Learning for Robots\", "
             "RSS 2020")
_LICENCE = ("not stated in the released zips (no licence file inside); check the repository "
            f"{REPOSITORY} before redistributing")


class EvTouchDataset(TactileDataset):
    """A TactileSGNet event dataset: the released zip (or its extracted folder) under ``<root>/<name>/raw/``.

    Args:
        verify_checksum: refuse a zip whose sha256 differs from the release's (default). ``False`` accepts a
            re-packed archive with the same layout.
        **kwargs: :class:`~tactile_zoo.data.base.TactileDataset`'s (``transform``, ``augment``, ...).
    """

    sensor = NEUTOUCH
    binary = True
    downloadable = True
    protocol = "fixed"
    archive: ClassVar[str]  # e.g. "Ev-Objects.zip"
    folder: ClassVar[str]  # the zip's top folder, e.g. "Ev-Objects"
    sha256: ClassVar[str]
    num_steps: ClassVar[int]  # time bins every sample of the release has
    base_url: ClassVar[str] = f"{REPOSITORY}/raw/master"
    url_env: ClassVar[str] = "TACTILE_ZOO_EV_URL"

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, verify_checksum: bool = True, **kwargs: Any) -> None:
        self.verify_checksum = bool(verify_checksum)
        super().__init__(root, split, fold, download, **kwargs)

    # ------------------------------------------------------------------------------------------- where the raw data is
    @classmethod
    def locate(cls, root: str | os.PathLike | None = None) -> tuple[str, Path] | None:
        """``("zip", path)``, ``("folder", path)`` or None: the zip wins over an extracted folder."""
        raw = cls.raw_dir_for(root)
        if (raw / cls.archive).is_file():
            return "zip", raw / cls.archive
        if (raw / cls.folder).is_dir():
            return "folder", raw / cls.folder
        return None

    @classmethod
    def availability(cls, root: str | os.PathLike | None = None) -> tuple[bool, str]:
        found = cls.locate(root)
        return (True, str(found[1])) if found else (False, cls.place_hint(root))

    @classmethod
    def place_hint(cls, root: str | os.PathLike | None = None) -> str:
        raw = cls.raw_dir_for(root)
        what = f"{cls.archive} (sha256 {cls.sha256}, from the root of {REPOSITORY})"
        if (wrong := not_a_file(raw / cls.archive)) is not None:  # a folder or a link loop of the zip's name
            where = f"{raw / cls.archive} is {wrong}, not the zip file: move it out of the way and place {what} there"
        else:
            where = f"Place {what} at {raw / cls.archive}"
        return f"{where}, or its extracted folder at {raw / cls.folder}/{{train,test}}/."

    def raw_present(self) -> bool:
        return self.locate(self.root) is not None

    def missing_message(self) -> str:
        return (f"{self.name}: raw data not found. {self.place_hint(self.root)} Or run `tactile-zoo download "
                f"{self.name} --root {self.root}` (or pass download=True) to fetch and verify it.")

    def raw_files(self) -> list[Path]:
        kind, path = self.locate(self.root) or ("", Path())
        if kind == "zip":
            return [path]
        return sorted(p for part in _PARTITIONS for p in (path / part).glob("*.npy")) if kind else []

    def process_options(self) -> dict[str, Any]:
        return {"verify_checksum": self.verify_checksum}

    # ------------------------------------------------------------------------------------------- download
    @classmethod
    def url(cls) -> str:
        base = os.environ.get(cls.url_env) or cls.base_url
        return f"{base.rstrip('/')}/{cls.archive}"

    @classmethod
    def fetch(cls, root: str | os.PathLike | None = None, timeout: float = 60.0) -> Path:
        """Download the zip into ``<root>/<name>/raw/`` (sha256-verified before it is renamed into place)."""
        return fetch(cls.url(), cls.raw_dir_for(root) / cls.archive, cls.sha256, timeout=timeout,
                     hint=cls.place_hint(root))

    def download(self) -> None:
        self.fetch(self.root)

    @classmethod
    def extract(cls, root: str | os.PathLike | None = None) -> Path:
        """Unpack the (verified) zip next to itself, refusing unsafe members; returns the extracted folder."""
        found = cls.locate(root)
        if found is None or found[0] != "zip":
            raise DatasetError(f"{cls.name}: no zip to extract. {cls.place_hint(root)}")
        cls._verify(found[1], root)
        safe_extract(found[1], found[1].parent)
        return found[1].parent / cls.folder

    @classmethod
    def _verify(cls, path: Path, root: str | os.PathLike | None) -> None:
        try:
            verify_sha256(path, cls.sha256)
        except DatasetError as exc:
            raise DatasetError(f"{cls.name}: {exc}: not the released {cls.archive}. Replace it with the released "
                               f"file (or delete it and use download=True), or pass verify_checksum=False to accept "
                               f"a re-packed archive. {cls.place_hint(root)}") from None

    # ------------------------------------------------------------------------------------------- reading
    def process(self) -> TensorData:
        kind, path = self.locate(self.root) or ("", Path())
        if kind == "zip":
            if self.verify_checksum:
                self._verify(path, self.root)
            records = self._read_zip(path)
        else:
            records = self._read_folder(path)
        for part in _PARTITIONS:
            if not any(r[0] == part for r in records):
                where = f"{path}:{self.folder}/{part}/" if kind == "zip" else f"{path / part}/"
                raise DatasetError(f"{self.name}: no samples in {where} (expected sample_<i>_label_<c>.npy files)")
        records.sort(key=lambda r: (_PARTITIONS.index(r[0]), r[1]))
        # (S, 39, 2, T) -> (S, T, 39, 2): time first, as the data contract wants
        x = torch.from_numpy(np.ascontiguousarray(np.stack([r[3] for r in records]).transpose(0, 3, 1, 2)))
        y = torch.tensor([r[2] for r in records], dtype=torch.long)
        n = len(records)
        return TensorData(x, torch.zeros(n, self.num_steps, 0), y, torch.arange(n), tuple(r[0] for r in records))

    def _read_zip(self, path: Path) -> list[tuple[str, int, int, np.ndarray]]:
        records = []
        with open_zip(path) as zf:
            for info, rel in check_zip(zf, path):
                if info.is_dir():
                    continue
                parsed = self._member(rel, f"{path}:{info.filename}")
                if parsed is not None:
                    try:
                        blob = zf.read(info)
                    except Exception as exc:  # zipfile raises BadZipFile, zlib.error, EOFError, ... on damage
                        raise DatasetError(f"{path}:{info.filename}: cannot be read from the archive ({exc})") from exc
                    records.append((*parsed, self._check(load_npy(blob, f"{path}:{info.filename}"),
                                                         f"{path}:{info.filename}", parsed[2])))
        return records

    def _read_folder(self, folder: Path) -> list[tuple[str, int, int, np.ndarray]]:
        records = []
        for part in _PARTITIONS:
            if not (folder / part).is_dir():
                raise DatasetError(f"{self.name}: folder {folder / part} is missing (expected {folder}/{{train,test}}/"
                                   f"sample_<i>_label_<c>.npy)")
            for file in sorted((folder / part).iterdir()):
                parsed = self._member(PurePosixPath(self.folder, part, file.name), str(file))
                if parsed is not None:
                    records.append((*parsed, self._check(load_npy(file), str(file), parsed[2])))
        return records

    def _member(self, rel: PurePosixPath, where: str) -> tuple[str, int, int] | None:
        """``(partition, sample index, label)`` of a sample file; None for anything outside ``<folder>/{train,test}``
        and for hidden files (``.DS_Store``)."""
        parts = rel.parts
        if len(parts) != 3 or parts[0] != self.folder or parts[1] not in _PARTITIONS or parts[2].startswith("."):
            return None
        match = _SAMPLE.match(parts[2])
        if match is None:
            raise DatasetError(f"{where}: unexpected file name; samples are named sample_<i>_label_<c>.npy")
        label = int(match.group(2))
        if label >= len(self.class_names):
            raise DatasetError(f"{where}: label {label} is outside the {len(self.class_names)} classes of "
                               f"{self.name} (0..{len(self.class_names) - 1})")
        return parts[1], int(match.group(1)), label

    def _check(self, array: np.ndarray, where: str, label: int) -> np.ndarray:
        if array.ndim != 3 or array.shape[:2] != (NEUTOUCH.num_nodes, 2):
            raise DatasetError(f"{where}: shape {array.shape}, expected (39, 2, T) = (taxel, polarity, time bin)")
        if array.shape[2] != self.num_steps:
            raise DatasetError(f"{where}: {array.shape[2]} time bins, but every {self.name} sample has "
                               f"{self.num_steps}")
        check_finite(array, where)
        if not np.isin(array, (0, 1)).all():
            bad = array[~np.isin(array, (0, 1))].flat[0]
            raise DatasetError(f"{where}: value {bad!r} in an event array; the release holds only 0/1 events")
        return array.astype(np.float32, copy=False)


def _meta(name: str, archive: str, classes: tuple[str, ...], steps: int, train: int, test: int, what: str
          ) -> dict[str, Any]:
    return dict(
        sensor="neutouch", num_classes=len(classes), class_names=classes, num_steps=steps, num_nodes=39,
        num_channels=2, num_globals=0, num_samples=train + test, folds=1, revision=1,
        protocol=f"the released fixed stratified split ({train} train / {test} test); val carved from train "
                 "(20 % of each class, seeded by fold)",
        splits=("train", "val", "test"), source_url=f"{REPOSITORY} ({archive})", citation=_CITATION,
        licence=_LICENCE,
        description=f"{what}; NeuTouch ON/OFF events binned to {steps} steps (class names from clear-nus/VT_SNN, "
                    "label order unverified)",
        obtain=f"`tactile-zoo download {name} --root DIR` (or download=True) fetches {archive} from {REPOSITORY} "
               f"and verifies its sha256; offline, place the zip at DIR/{name}/raw/{archive}")


@register_dataset("ev_objects", **_meta("ev_objects", "Ev-Objects.zip", EV_OBJECTS_CLASSES, 250, 576, 144,
                                        "36 household objects grasped and lifted"))
class EvObjects(EvTouchDataset):
    name = "ev_objects"
    class_names = EV_OBJECTS_CLASSES
    archive, folder, num_steps = "Ev-Objects.zip", "Ev-Objects", 250
    sha256 = "bd8e828064a85c4fc6567789283198ff0b92384ef58aeb2366fa36a963ded867"
    obtain = "Run `tactile-zoo download ev_objects --root DIR`, or place Ev-Objects.zip from the TactileSGNet " \
             "repository."


@register_dataset("ev_containers", **_meta("ev_containers", "Ev-Containers.zip", EV_CONTAINERS_CLASSES, 325, 240, 60,
                                           "4 containers x 5 fill levels"))
class EvContainers(EvTouchDataset):
    name = "ev_containers"
    class_names = EV_CONTAINERS_CLASSES
    archive, folder, num_steps = "Ev-Containers.zip", "Ev-Containers", 325
    sha256 = "dc965e9425ca0060e0628ce8efe717c92a0b2e8f11163f4239569fc5434ab8e2"
    obtain = "Run `tactile-zoo download ev_containers --root DIR`, or place Ev-Containers.zip from the TactileSGNet " \
             "repository."
