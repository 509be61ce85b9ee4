"""Predicting the class of recorded grasps with pretrained weights: :func:`predict` and :func:`read_recording`.

Input files are the bring-your-own recordings format (:mod:`tactile_zoo.data.datasets.recordings`): one row per time
step; the columns are the taxel readings in row-major taxel order, all channels of a taxel together (``[ch0 ..
chC-1]`` of taxel 0, then of taxel 1, ...), then the global features: ``N * C + G`` columns. A ``.csv`` (comma,
semicolon or tab between values, ``.`` as the decimal mark) may start with one row of column names; a ``.npy`` is a
2-D real array ``(T, N * C + G)``, or, for a dataset without globals, ``(T, N, C)``; it is memory-mapped and read
without unpickling. Only the rows used are read (``crop`` and ``pad`` read the first T; ``resample`` and a stream read
all); the others are counted. Files above the input size limit (``$TACTILE_ZOO_MAX_INPUT_MB``, default 2048) and
anything that is not a regular file (a device, a FIFO, a socket) are refused. The values are
what the weights' dataset feeds its models, in the same units: the entry's ``dataset_kwargs`` say which
preprocessing that is (BioTac-DoS, for instance, subtracts each recording's first readings and divides by 1000;
Augment8000 z-scores with the training statistics). A file of the dataset's own test sample, written row by row,
gives exactly :func:`tactile_zoo.evaluate`'s prediction for that sample.

Length: the weights were trained on ``num_steps`` (T) rows per sample.

* ``length="crop"`` (default): what the recordings loader does with ``num_steps`` set: a longer recording is cut to
  its first T rows, a shorter one is refused (as BioTac-DoS refuses a recording shorter than one window).
* ``"pad"``: a longer recording is cut the same way, a shorter one gets rows of zeros after its end (how prefix
  evaluation feeds a non-causal model a partial sequence).
* ``"resample"``: linear interpolation in time onto T evenly spaced rows spanning the whole recording (another frame
  rate). None of the zoo's loaders resample, so this is an approximation; binary event data become fractional.

No other preprocessing is applied. For a causal model's running decision frame by frame on a recording of any
length, use ``tactile-zoo stream MODEL --pretrained ... --file FILE``.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..data.datasets._io import check_finite, open_npy, read_csv_table
from ..errors import ConfigError, DatasetError
from .load import load_pretrained

__all__ = ["LENGTHS", "ON_ERROR", "Recording", "Prediction", "Refused", "read_recording", "predict"]

#: How a recording of another length is brought to the weights' number of steps (see the module docstring).
LENGTHS = ("crop", "pad", "resample")
#: What :func:`predict` does with an input it cannot read: raise its error, or report it in place of its prediction.
ON_ERROR = ("raise", "report")


@dataclass(frozen=True)
class Recording:
    """One recording brought to a spec: ``x (T, N, C)``, ``g (T, G)``, float32.

    Attributes:
        source: the file (or ``<array i>``).
        steps_read: rows in the file.
        length: ``"as recorded"``, ``"cropped"``, ``"padded"`` or ``"resampled"``.
    """

    source: str
    x: torch.Tensor
    g: torch.Tensor
    steps_read: int
    length: str


@dataclass(frozen=True)
class Refused:
    """An input :func:`predict` could not read (with ``on_error="report"``): ``source`` (the file, or ``<array i>``)
    and ``reason`` (the one-line error, which names the source)."""

    source: str
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.source, "error": self.reason}


@dataclass(frozen=True)
class Prediction:
    """The model's answer for one recording.

    Attributes:
        source: the file (or ``<array i>``).
        index, label, probability: the top class, its name and its probability.
        top_k: the ``k`` most probable ``(class name, probability)`` pairs, most probable first.
        probabilities: every class's probability, in class order.
        steps_read, length: the recording's rows and what was done to fit the weights' length.
    """

    source: str
    index: int
    label: str
    probability: float
    top_k: list[tuple[str, float]]
    probabilities: list[float] = field(repr=False)
    steps_read: int = 0
    length: str = "as recorded"

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.source, "class": self.label, "index": self.index, "probability": self.probability,
                "top_k": [{"class": c, "probability": p} for c, p in self.top_k], "steps_read": self.steps_read,
                "length": self.length, "probabilities": self.probabilities}


def _as_table(array: np.ndarray, spec: Any, where: str, max_rows: int | None = None) -> np.ndarray:
    """The first ``max_rows`` rows (all with ``None``) of an input array as a 2-D ``(T, N * C + G)`` table; a 3-D
    ``(T, N, C)`` array is accepted without globals. Any other layout is refused, saying the expected one and, when
    the axes are only in another order (the Ev-Touch zips keep ``(N, C, T)``), the transpose that fixes it. Rows are
    taken before any reshape, so a memory-mapped file is only read where it is used."""
    n, c, g = spec.num_nodes, spec.num_channels, spec.num_globals
    if array.ndim == 2:
        return array[:max_rows]
    if array.ndim == 3 and array.shape[1:] == (n, c) and g == 0:
        rows = array[:max_rows]
        return rows.reshape(rows.shape[0], n * c)
    expected = (f"expected 2-D (time steps, columns) = (T, {n * c + g}), {n} taxels x {c} channel(s) + {g} "
                f"global(s)" + (f", or 3-D (T, N, C) = (T, {n}, {c})" if g == 0 else ""))
    hint = ""
    if array.ndim == 3:
        # the order of the given axes that puts them as (T, N, C): the time axis is the one left over
        order = next((p for p in itertools.permutations(range(3)) if (array.shape[p[1]], array.shape[p[2]]) == (n, c)),
                     None)
        if order is not None:
            given = ", ".join("TNC"[order.index(axis)] for axis in range(3))
            fix = "x" if order == (0, 1, 2) else f"x.transpose{order}"
            if g == 0:
                hint = f"; its axes look like ({given}): save {fix} instead" if order != (0, 1, 2) else ""
            else:
                steps = f"x.shape[{order[0]}]"
                hint = (f"; its axes look like ({given}), without the {g} global(s): save "
                        f"np.concatenate([{fix}.reshape({steps}, {n * c}), globals], axis=1) with globals of shape "
                        f"(T, {g})")
    raise DatasetError(f"{where}: array of shape {tuple(array.shape)}; {expected}{hint}")


def _read_table(path: Path, spec: Any, max_rows: int | None) -> tuple[np.ndarray, int]:
    """``(the first max_rows rows as float64, the rows in the file)``; the rows not used are not read."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        table = read_csv_table(path, optional_header=True, max_rows=max_rows)
        return table.table, table.rows
    if suffix == ".npy":
        view = open_npy(path)  # memory-mapped: only the rows copied below are read
        array = np.array(_as_table(view, spec, str(path), max_rows), dtype=np.float64)
        check_finite(array, path)
        return array, int(view.shape[0])
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    raise DatasetError(f"{path}: not a recording file (expected .csv or .npy)")


def _check_width(table: np.ndarray, rows: int, spec: Any, where: str) -> None:
    """``rows``: the rows in the file (``table`` may hold only the first of them)."""
    n, c, g = spec.num_nodes, spec.num_channels, spec.num_globals
    width, cols = n * c + g, table.shape[1]
    if cols == width:
        return
    message = (f"{where}: {cols} columns, expected {width} = {n} taxels x {c} channel(s) + {g} global(s) (sensor "
               f"{spec.sensor.name!r}; one row per time step, taxels row-major, then globals)")
    if rows == width:
        message += f"; it has {rows} rows: transposed? (write one row per time step)"
    elif cols > g and (cols - g) % c == 0:
        message += f"; that would be {(cols - g) // c} taxels: wrong taxel count (another sensor?)"
    raise DatasetError(message)


def _fit_length(table: np.ndarray, rows: int, steps: int, length: str, where: str, dataset: str
                ) -> tuple[np.ndarray, str]:
    """``table`` (its first ``steps`` rows, or all ``rows`` for resample) brought to ``steps`` rows."""
    if rows == 0:
        raise DatasetError(f"{where}: no rows (no time steps)")
    if length == "resample":
        if rows == steps:
            return table, "as recorded"
        pos = np.linspace(0.0, rows - 1, steps)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, rows - 1)
        w = (pos - lo)[:, None]
        return table[lo] * (1.0 - w) + table[hi] * w, "resampled"
    if rows >= steps:
        return table[:steps], "as recorded" if rows == steps else "cropped"
    if length == "pad":
        return np.concatenate([table, np.zeros((steps - rows, table.shape[1]))]), "padded"
    raise DatasetError(f"{where}: {rows} time steps, fewer than the {steps} the weights were trained on "
                       f"(dataset {dataset!r}); record at least {steps}, or use length 'pad' (zeros after the end) or "
                       f"'resample' (stretch it)")


def read_recording(source: str | os.PathLike | np.ndarray, spec: Any, *, length: str | None = "crop",
                   name: str | None = None) -> Recording:
    """Read one recording (a ``.csv``/``.npy`` file or a 2-D array) in the documented format and bring it to
    ``spec``'s number of steps.

    Args:
        source: the file, or an array ``(T, N * C + G)`` (``(T, N, C)`` without globals).
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` the model expects.
        length: ``"crop"``, ``"pad"`` or ``"resample"`` (see the module docstring); ``None`` keeps every row (a
            stream, which has no fixed length).
        name: what errors call an array (default ``<array>``).

    Shapes:
        file or array ``(T_file, N * C + G)`` (or ``(T_file, N, C)`` when ``G = 0``) -> ``x (T, N, C)``, ``g (T, G)``
        with ``T = spec.num_steps`` (``T = T_file`` with ``length=None``).

    Raises:
        DatasetError: naming the file and what is wrong: not numeric, NaN/Inf, wrong shape or taxel count, too short.
    """
    if length is not None and length not in LENGTHS:
        raise ConfigError(f"length must be one of {', '.join(LENGTHS)}, got {length!r}")
    # crop and pad use the first T rows only: the rest of a file is not read
    max_rows = spec.num_steps if length in ("crop", "pad") else None
    if isinstance(source, np.ndarray | torch.Tensor):
        where = name or "<array>"
        table = np.asarray(source.detach().cpu() if isinstance(source, torch.Tensor) else source)
        if table.ndim not in (2, 3) or table.dtype.kind not in "biuf":
            raise DatasetError(f"{where}: expected a 2-D real array (time steps, columns), got shape {table.shape} "
                               f"dtype {table.dtype}")
        table = _as_table(table, spec, where).astype(np.float64)
        check_finite(table, where)
        steps_read = int(table.shape[0])
    else:
        path = Path(source).expanduser()
        where = str(path)
        table, steps_read = _read_table(path, spec, max_rows)
    _check_width(table, steps_read, spec, where)
    if length is None:
        if steps_read == 0:
            raise DatasetError(f"{where}: no rows (no time steps)")
        action = "as recorded"
    else:
        table, action = _fit_length(table, steps_read, spec.num_steps, length, where, spec.name)
    data = torch.from_numpy(np.ascontiguousarray(table, dtype=np.float32))  # (T, N*C + G)
    n, c = spec.num_nodes, spec.num_channels
    return Recording(where, data[:, : n * c].reshape(-1, n, c), data[:, n * c:], steps_read, action)


def _as_list(inputs: Any) -> list[Any]:
    if isinstance(inputs, str | os.PathLike | np.ndarray | torch.Tensor):
        return [inputs]
    if isinstance(inputs, Sequence):
        return list(inputs)
    raise ConfigError(f"inputs must be a file, an array, or a list of them, got {type(inputs).__name__}")


def _spec_of(model: nn.Module, spec: Any) -> Any:
    if spec is not None:
        return spec
    entry = getattr(model, "zoo_pretrained", None)
    if entry is not None:
        return entry.dataset_spec()
    if getattr(model, "spec", None) is not None:
        return model.spec
    raise ConfigError(f"predict: pass spec= (the {type(model).__name__} model does not say which data it was built "
                      f"for)")


def predict(model: str | nn.Module, inputs: Any, *, pretrained: Any = None, spec: Any = None, top_k: int = 5,
            length: str = "crop", device: str | torch.device | None = None, batch_size: int = 256,
            on_error: str = "raise", **hparams: Any) -> list[Any]:
    """The most probable classes of recorded grasps.

    Args:
        model: a model name (then ``pretrained`` is required) or a built model (a pretrained one knows its spec).
        inputs: a ``.csv``/``.npy`` file, a 2-D array ``(T, N * C + G)``, or a list of them.
        pretrained: with a model name: a dataset name, a tag, a local manifest or ``.safetensors`` file, or a
            WeightEntry (see :func:`tactile_zoo.create_model`).
        spec: the spec the inputs follow (default: the weights').
        top_k: how many classes to report per recording.
        length: ``"crop"``, ``"pad"`` or ``"resample"`` (see the module docstring).
        device: where to run (default: where the model is; ``"auto"`` = CUDA when available).
        batch_size: recordings per forward pass.
        on_error: an input that cannot be read (missing, not numeric, NaN, wrong shape, ...): ``"raise"`` (default)
            raises its :class:`~tactile_zoo.errors.DatasetError` before any prediction; ``"report"`` answers every
            other input and puts a :class:`Refused` in its place.
        **hparams: constructor overrides, with a model name.

    Returns:
        one :class:`Prediction` (or, with ``on_error="report"``, :class:`Refused`) per input, in order.
        Probabilities are the softmax of the logits, or the output spike rates normalised to sum 1 for a model
        trained with ``mse_rate`` (SGnet), as :func:`tactile_zoo.evaluate` does.
    """
    from ..engine.evaluate import model_loss, predict_scores
    from ..engine.metrics import scores_to_probabilities
    from ..engine.runtime import flush_denormals, resolve_device

    if isinstance(model, str):
        if pretrained is None:
            raise ConfigError(f"predict({model!r}): pass pretrained= (a dataset name, a tag or a local weights file)")
        model = load_pretrained(model, pretrained, spec, **hparams)
    elif pretrained is not None or hparams:
        raise ConfigError("predict: pretrained= and hyper-parameters go with a model name, not a built model")
    spec = _spec_of(model, spec)
    if isinstance(top_k, bool) or not isinstance(top_k, int) or top_k < 1:
        raise ConfigError(f"top_k must be a positive integer, got {top_k!r}")
    if on_error not in ON_ERROR:
        raise ConfigError(f"on_error must be one of {', '.join(ON_ERROR)}, got {on_error!r}")
    items = _as_list(inputs)
    if not items:
        raise ConfigError("predict: no inputs")
    read: list[Recording | Refused] = []
    for i, item in enumerate(items):
        try:
            read.append(read_recording(item, spec, length=length, name=f"<array {i}>"))
        except DatasetError as exc:  # what is wrong with this input only; anything else stops the whole call
            if on_error == "raise":
                raise
            source = str(Path(item).expanduser()) if isinstance(item, str | os.PathLike) else f"<array {i}>"
            read.append(Refused(source, str(exc)))
    recordings = [r for r in read if isinstance(r, Recording)]
    if not recordings:
        return read
    x = torch.stack([r.x for r in recordings])  # (S, T, N, C)
    g = torch.stack([r.g for r in recordings])  # (S, T, G)
    dev = None
    if device is not None:
        dev = resolve_device(device)
        model.to(dev)
    with flush_denormals():  # as evaluate() runs, so the numbers are the same
        scores = predict_scores(model, x, g, batch_size, dev)  # (S, K)
    probs = scores_to_probabilities(scores, model_loss(model))
    names = spec.class_names
    k = min(top_k, probs.shape[1])
    answers = iter(zip(recordings, scores, probs))
    out: list[Prediction | Refused] = []
    for item in read:
        if isinstance(item, Refused):
            out.append(item)
            continue
        rec, score_row, prob_row = next(answers)
        best = int(score_row.argmax())
        order = torch.argsort(prob_row, descending=True, stable=True)[:k].tolist()
        out.append(Prediction(rec.source, best, names[best], float(prob_row[best]),
                              [(names[j], float(prob_row[j])) for j in order], prob_row.tolist(), rec.steps_read,
                              rec.length))
    return out
