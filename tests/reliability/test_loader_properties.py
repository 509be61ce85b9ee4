"""Property-based tests (hypothesis) of the loaders and augmentations, beyond those in tests/data/.

tests/data/ already fuzzes the ``.npy`` reader with random bytes and truncations, the numeric CSV reader with random
text, and the four augmentations on random shapes. Here: ``.npy`` files of random real and non-real dtypes and
shapes, headers that lie about their shape, whole Ev archives and recordings folders of random shapes and contents
(each checked against an independent oracle: it loads exactly the written numbers, or raises one DatasetError that
names the file), mutated Augment8000 files, and the augmented expansion of a training split.
"""

from __future__ import annotations

import io
import itertools
import string
import struct
import zipfile
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_zoo.data.augment import AUGMENTATIONS
from tactile_zoo.data.base import TactileDataset, TensorData
from tactile_zoo.data.datasets import EvObjects, RecordingsDataset
from tactile_zoo.data.datasets._io import load_npy
from tactile_zoo.data.datasets.augment8000 import CLASSES as A8K_CLASSES
from tactile_zoo.data.datasets.augment8000 import read_augment8000
from tactile_zoo.errors import DatasetError
from tactile_zoo.registry import get_sensor

_counter = itertools.count()


def _fresh(factory: pytest.TempPathFactory) -> Path:
    return factory.getbasetemp() / f"prop_{next(_counter)}"


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------- .npy
REAL_DTYPES = (hnp.boolean_dtypes() | hnp.integer_dtypes(endianness="?") | hnp.unsigned_integer_dtypes(endianness="?")
               | hnp.floating_dtypes(endianness="?"))
OTHER_DTYPES = (hnp.complex_number_dtypes(endianness="?") | hnp.datetime64_dtypes() | hnp.timedelta64_dtypes()
                | hnp.unicode_string_dtypes() | hnp.byte_string_dtypes()
                | st.just(np.dtype([("a", "<f4"), ("b", "<i2")])))
SHAPES = hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=5)


@settings(max_examples=80, deadline=None)
@given(array=hnp.arrays(REAL_DTYPES, SHAPES), fortran=st.booleans())
def test_npy_of_any_real_dtype_and_shape_round_trips(array: np.ndarray, fortran: bool) -> None:
    array = np.asfortranarray(array) if fortran else array
    got = load_npy(_npy(array), "prop.npy")
    assert got.dtype == array.dtype and got.shape == array.shape
    assert np.array_equal(got, array, equal_nan=got.dtype.kind == "f")


@settings(max_examples=40, deadline=None)
@given(array=hnp.arrays(OTHER_DTYPES, SHAPES))
def test_npy_of_a_non_real_dtype_is_refused(array: np.ndarray) -> None:
    with pytest.raises(DatasetError, match=r"^prop\.npy: dtype .* is not a real number type"):
        load_npy(_npy(array), "prop.npy")


def _lying_npy(shape: tuple[int, ...], descr: str, body: bytes) -> bytes:
    """A version 1.0 .npy whose header declares ``shape``, followed by ``body`` (whatever its length)."""
    text = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape!r}, }}"
    pad = (64 - (10 + len(text) + 1) % 64) % 64
    header = (text + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + body


@settings(max_examples=80, deadline=None)
@given(shape=st.lists(st.one_of(st.integers(0, 6), st.integers(2**20, 2**40)), max_size=4).map(tuple),
       descr=st.sampled_from(["<f4", ">f8", "<i2", "|u1", "|b1"]), body=st.binary(max_size=200))
def test_npy_header_that_lies_about_its_shape(shape: tuple[int, ...], descr: str, body: bytes) -> None:
    """A header declaring terabytes over a few bytes of data is refused before anything is allocated."""
    need = int(np.prod(shape, dtype=np.float64)) * np.dtype(descr).itemsize
    if need <= len(body):  # enough data; numpy may still refuse a shape whose size overflows (with a 0 side)
        try:
            assert load_npy(_lying_npy(shape, descr, body), "lie.npy").shape == shape
        except DatasetError as exc:
            assert str(exc).startswith("lie.npy: truncated or corrupt .npy file")
    else:
        with pytest.raises(DatasetError, match=r"^lie\.npy: truncated \.npy file"):
            load_npy(_lying_npy(shape, descr, body), "lie.npy")


# ----------------------------------------------------------------------------------------------- Ev archives
EV_SHAPES = st.one_of(st.just((39, 2, 250)),
                      st.tuples(st.sampled_from([38, 39, 40]), st.sampled_from([1, 2, 3]), st.sampled_from([249, 250])),
                      SHAPES)
EV_DTYPES = st.sampled_from(["float32", "float64", "float16", "int8", "uint8", "bool", "complex64"])


def _events(shape: tuple[int, ...], dtype: str, kind: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = (rng.random(shape) < 0.1).astype(np.float64)
    if values.size and kind == "spike":
        values.flat[values.size // 2] = 2.0
    if values.size and kind == "nan":
        values.flat[0] = np.nan
    with np.errstate(invalid="ignore"):
        return values.astype(dtype)


@settings(max_examples=30, deadline=None)
@given(shape=EV_SHAPES, dtype=EV_DTYPES, kind=st.sampled_from(["events", "spike", "nan"]), label=st.integers(0, 40),
       seed=st.integers(0, 2**16))
def test_ev_archive_member_of_random_shape_dtype_and_values(tmp_path_factory: pytest.TempPathFactory,
                                                            shape: tuple[int, ...], dtype: str, kind: str,
                                                            label: int, seed: int) -> None:
    home = _fresh(tmp_path_factory)
    raw = home / "ev_objects" / "raw"
    raw.mkdir(parents=True)
    member = f"Ev-Objects/train/sample_1_label_{label}.npy"
    array = _events(shape, dtype, kind, seed)
    with zipfile.ZipFile(raw / "Ev-Objects.zip", "w") as zf:
        zf.writestr("Ev-Objects/train/sample_0_label_0.npy", _npy(_events((39, 2, 250), "float32", "events", 1)))
        zf.writestr(member, _npy(array))
        zf.writestr("Ev-Objects/test/sample_0_label_1.npy", _npy(_events((39, 2, 250), "float32", "events", 2)))
    valid = (array.shape == (39, 2, 250) and array.dtype.kind in "biuf" and label < 36
             and bool(np.isin(array, (0, 1)).all()))
    if valid:
        ds = EvObjects(root=home, verify_checksum=False)
        assert ds.x.shape == (3, 250, 39, 2) and ds.x.dtype == torch.float32 and ds.y.tolist() == [0, label, 1]
        assert np.array_equal(ds.x[1].numpy(), array.astype(np.float32).transpose(2, 0, 1))
    else:
        with pytest.raises(DatasetError) as err:
            EvObjects(root=home, verify_checksum=False)
        assert f"Ev-Objects.zip:{member}: " in str(err.value)


# ----------------------------------------------------------------------------------------------- recordings
@st.composite
def recordings(draw: st.DrawFn) -> dict[str, Any]:
    """A recordings folder: 2 classes x 1-2 trials of random length and width, CSV or .npy, maybe one defect."""
    channels, globals_ = draw(st.integers(1, 3)), draw(st.integers(0, 2))
    width = 3 * channels + globals_  # OptoForce: 3 taxels
    trials = []
    for cls in ("a", "b"):
        for k in range(draw(st.integers(1, 2))):
            steps = draw(st.integers(1, 7))
            cols = draw(st.sampled_from([width, width, width, width - 1, width + 1]))
            table = np.round(np.random.default_rng(draw(st.integers(0, 99))).normal(size=(steps, cols)), 3)
            fmt = draw(st.sampled_from(["csv", "csv", "npy"]))
            trials.append({"cls": cls, "file": f"t{k}.{fmt}", "table": table, "header": fmt == "csv" and
                           draw(st.booleans()), "defect": None})
    defect = draw(st.sampled_from([None, None, "nan", "inf", "word", "empty", "ragged"]))
    if defect is not None:
        target = draw(st.sampled_from(trials))
        target["defect"] = "nan" if target["file"].endswith(".npy") else defect
    return {"channels": channels, "globals": globals_, "width": width, "trials": trials,
            "num_steps": draw(st.none() | st.integers(1, 7))}


def _write_trial(path: Path, trial: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    table, defect = trial["table"].copy(), trial["defect"]
    if path.suffix == ".npy":
        if defect == "nan":
            table.flat[-1] = np.nan
        np.save(path, table.astype(np.float32))
        return
    rows = [[repr(float(v)) for v in row] for row in table]
    if defect in ("nan", "inf", "word", "empty"):
        rows[-1][-1] = {"nan": "nan", "inf": "-inf", "word": "n/a", "empty": ""}[defect]
    if defect == "ragged":
        rows[-1] = rows[-1] + ["1.0"]
    lines = ([",".join(f"col{j}" for j in range(table.shape[1]))] if trial["header"] else []) + \
        [",".join(r) for r in rows]
    path.write_text("\n".join(lines) + "\n")


@settings(max_examples=50, deadline=None)
@given(spec=recordings())
def test_recordings_folder_of_random_shapes_and_defects(tmp_path_factory: pytest.TempPathFactory,
                                                        spec: dict[str, Any]) -> None:
    home = _fresh(tmp_path_factory)
    raw = home / "fuzz" / "raw"
    for trial in spec["trials"]:
        _write_trial(raw / trial["cls"] / trial["file"], trial)
    steps = [t["table"].shape[0] for t in spec["trials"]]
    n = spec["num_steps"]
    valid = (all(t["defect"] is None and t["table"].shape[1] == spec["width"] for t in spec["trials"])
             and (min(steps) >= n if n is not None else len(set(steps)) == 1))
    kwargs = {"folder": "fuzz", "sensor": "optoforce3", "num_channels": spec["channels"],
              "num_globals": spec["globals"], "num_steps": n}
    if not valid:
        with pytest.raises(DatasetError) as err:
            RecordingsDataset(root=home, **kwargs)
        assert str(raw) in str(err.value)
        return
    ds = RecordingsDataset(root=home, **kwargs)
    t = n if n is not None else steps[0]
    ordered = sorted(spec["trials"], key=lambda tr: (tr["cls"], tr["file"]))
    expected = np.stack([tr["table"][:t] for tr in ordered]).astype(np.float32)  # (S, T, width)
    c = spec["channels"]
    assert ds.x.shape == (len(ordered), t, 3, c) and ds.g.shape == (len(ordered), t, spec["globals"])
    assert np.array_equal(ds.x.numpy().reshape(len(ordered), t, 3 * c), expected[:, :, : 3 * c])
    assert np.array_equal(ds.g.numpy(), expected[:, :, 3 * c:])
    assert ds.y.tolist() == [0 if tr["cls"] == "a" else 1 for tr in ordered]


# ----------------------------------------------------------------------------------------------- Augment8000
_A8K_COLUMNS = "timestep," + ",".join(f"f{i}" for i in range(15))


def _augment8000_text(samples: int = 2, steps: int = 4) -> str:
    rng = np.random.default_rng(0)
    lines = [f"file header,dataset,0,stamp,0,nSamples,{samples},0,0,0,0,0,0,0.0,0.0,0.0"]
    for k in range(samples):
        lines.append(f"header,seq,{k},stamp start,0,stamp end,1,nMeas,{steps},class label,{k % 20},0,0,0.0,0.0,0.0")
        lines.append(_A8K_COLUMNS)
        lines += [",".join([str(t)] + [f"{v:.3f}" for v in rng.normal(size=15)]) for t in range(steps)]
    return "\n".join(lines) + "\n"


@settings(max_examples=120, deadline=None)
@given(data=st.data())
def test_augment8000_file_mutated_anywhere(tmp_path_factory: pytest.TempPathFactory, data: st.DataObject) -> None:
    """Truncated at any byte, a line dropped or duplicated, any field replaced: a result or one DatasetError."""
    text = _augment8000_text()
    how = data.draw(st.sampled_from(["truncate", "drop", "duplicate", "field"]), label="how")
    lines = text.splitlines()
    if how == "truncate":
        text = text[: data.draw(st.integers(0, len(text)), label="at")]
    elif how in ("drop", "duplicate"):
        i = data.draw(st.integers(0, len(lines) - 1), label="line")
        lines = lines[:i] + lines[i + 1:] if how == "drop" else lines[: i + 1] + lines[i:]
        text = "\n".join(lines) + "\n"
    else:
        i = data.draw(st.integers(0, len(lines) - 1), label="line")
        fields = lines[i].split(",")
        j = data.draw(st.integers(0, len(fields) - 1), label="field")
        fields[j] = data.draw(st.text(string.digits + "-.eE naif", max_size=6), label="value")
        lines[i] = ",".join(fields)
        text = "\n".join(lines) + "\n"
    path = _fresh(tmp_path_factory).with_suffix(".csv")
    path.write_text(text)
    try:
        features, labels = read_augment8000(path)
    except DatasetError as exc:
        assert str(exc).startswith(str(path))
    else:
        assert features.ndim == 3 and features.shape[0] == labels.shape[0] >= 1 and features.shape[2] == 15
        assert np.isfinite(features).all() and ((0 <= labels) & (labels < len(A8K_CLASSES))).all()


# ----------------------------------------------------------------------------------------------- augmented splits
class _Random(TactileDataset):
    """Random readings of a shape chosen per example (``DATA`` is set before each instantiation)."""

    name = "prop_random"
    sensor = get_sensor("optoforce3")
    class_names: ClassVar[tuple[str, ...]] = ("a", "b")
    simulated = True
    DATA: ClassVar[TensorData | None] = None

    def process(self) -> TensorData:
        assert self.DATA is not None
        return self.DATA


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 6), t=st.integers(1, 12), sensor=st.sampled_from(["optoforce3", "biotac_sp"]),
       c=st.integers(1, 3), g=st.integers(0, 3),
       scale=st.floats(1e-3, 1e3), binary=st.booleans(), factor=st.integers(2, 3), seed=st.integers(0, 2**16),
       names=st.lists(st.sampled_from(sorted(AUGMENTATIONS)), min_size=1, max_size=3))
def test_augmented_training_split_keeps_shape_dtype_labels_and_finiteness(
        n: int, t: int, sensor: str, c: int, g: int, scale: float, binary: bool, factor: int, seed: int,
        names: list[str]) -> None:
    gen = torch.Generator().manual_seed(seed)
    nodes = get_sensor(sensor).num_nodes
    x = torch.rand(n + 2, t, nodes, c, generator=gen)
    x = (x < 0.3).float() if binary else (x * 2 - 1) * scale
    gl = torch.randn(n + 2, t, g, generator=gen)
    y = torch.arange(n + 2) % 2
    _Random.DATA = TensorData(x, gl, y, torch.arange(n + 2), ("train",) * n + ("test",) * 2)
    _Random.binary, _Random.sensor = binary, get_sensor(sensor)
    try:
        plain = _Random(split=None)
        train_plain = _Random(split="train")
        with pytest.warns(UserWarning) if binary and "time_warp" not in names else _no_warning():
            train = _Random(split="train", augment=names, augment_factor=factor, augment_seed=seed)
        test = _Random(split="test", augment=names, augment_factor=factor)
    finally:
        _Random.DATA, _Random.binary = None, False
    k = len(train_plain)
    assert len(plain) == n + 2 and len(test) == 2 and torch.equal(test.x, x[n:])  # only train grows
    assert len(train) == factor * k and train.x.shape[1:] == (t, nodes, c) and train.g.shape[1:] == (t, g)
    assert train.x.dtype == torch.float32 and train.g.dtype == torch.float32
    assert torch.isfinite(train.x).all() and torch.isfinite(train.g).all()
    assert torch.equal(train.x[:k], train_plain.x) and torch.equal(train.g[:k], train_plain.g)
    assert torch.equal(train.y, train_plain.y.repeat(factor))
    assert torch.equal(train.groups, train_plain.groups.repeat(factor))
    if binary:
        assert set(train.x.unique().tolist()) <= {0.0, 1.0}
    if "time_warp" not in names:  # only a time warp moves the global features
        assert torch.equal(train.g[k:], train_plain.g.repeat(factor - 1, 1, 1))


class _no_warning:  # noqa: N801 - a context manager used like pytest.warns
    def __enter__(self) -> None:
        import warnings

        self._ctx = warnings.catch_warnings()
        self._ctx.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc: object) -> None:
        self._ctx.__exit__(*exc)
