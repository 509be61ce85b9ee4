"""Predicting the class of recorded grasps with pretrained weights: :func:`predict` and :func:`read_recording`.

Input files are the bring-your-own recordings format (:mod:`tactile_zoo.data.datasets.recordings`): one row per time
step; the columns are the taxel readings in row-major taxel order, all channels of a taxel together (``[ch0 ..
chC-1]`` of taxel 0, then of taxel 1, ...), then the global features: ``N * C + G`` columns. A ``.csv`` (comma,
semicolon or tab between values, ``.`` as the decimal mark) may start with one row of column names; a ``.npy`` is a
2-D real array ``(T, N * C + G)``, or, for a dataset without globals, ``(T, N, C)``; it is memory-mapped and read
without unpickling. Only the rows used are read (``crop`` and ``pad`` read the first T; ``resample`` and a stream read
all); the others are counted. Files above the input size limit (``$TACTILE_ZOO_MAX_INPUT_MB``, default 2048) and
anything that is not a regular file (a device, a FIFO, a socket) are refused, and so is any value that is not finite
once cast to float32 (NaN, Inf, ``1e300``), naming the file, line and column.

Preprocessing. The values are a raw recording, as the sensor (and the weights' dataset's release) gives them; pretrained
weights' own preprocessing is applied first by default: what their dataset's loader does to one recording with the
entry's ``dataset_kwargs`` (:func:`~tactile_zoo.weights.manifest.entry_preprocessing`; BioTac-DoS: its ``minmax`` or
``baseline`` normalisation), named in each answer's ``preprocessing``; a model built from a ``train --save`` checkpoint
applies the checkpoint's the same way. ``raw=True`` feeds the values as read: a file of
the dataset's own (already preprocessed) test sample, written row by row, then gives exactly
:func:`tactile_zoo.evaluate`'s prediction for that sample.

Memory. :func:`iter_predict` reads, classifies and yields ``batch_size`` inputs at a time, dropping each batch before
the next: the forward pass's activations, not the inputs, dominate, so memory is bounded whatever the number of files;
:func:`predict` keeps only the small answers.

Length: the weights were trained on ``num_steps`` (T) rows per sample.

* ``length="crop"`` (default): what the recordings loader does with ``num_steps`` set: a longer recording is cut to
  its first T rows, a shorter one is refused (as BioTac-DoS refuses a recording shorter than one window).
* ``"pad"``: a longer recording is cut the same way, a shorter one gets rows of zeros after its end (how prefix
  evaluation feeds a non-causal model a partial sequence).
* ``"resample"``: linear interpolation in time onto T evenly spaced rows spanning the whole recording (another frame
  rate). None of the zoo's loaders resample, so this is an approximation; binary event data become fractional.

The preprocessing runs on the rows read, before the length is fitted. For a causal model's running decision frame
by frame on a recording of any length, use ``tactile-zoo stream MODEL --pretrained ... --file FILE``.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..data.datasets._io import check_finite, open_npy, read_csv_table
from ..data.preprocess import RecordingPreprocessing
from ..errors import ConfigError, DatasetError
from .load import load_pretrained
from .manifest import checkpoint_preprocessing, entry_preprocessing

__all__ = ["LENGTHS", "ON_ERROR", "DEFAULT_BATCH", "Recording", "Prediction", "Refused", "read_recording", "predict",
           "iter_predict", "model_preprocessing"]

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
        preprocessing: the name of the preprocessing applied (``None``: the values as read).
    """

    source: str
    x: torch.Tensor
    g: torch.Tensor
    steps_read: int
    length: str
    preprocessing: str | None = None


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
        preprocessing: the name of the weights' preprocessing applied to the file (``None``: fed as read).
    """

    source: str
    index: int
    label: str
    probability: float
    top_k: list[tuple[str, float]]
    probabilities: list[float] = field(repr=False)
    steps_read: int = 0
    length: str = "as recorded"
    preprocessing: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.source, "class": self.label, "index": self.index, "probability": self.probability,
                "top_k": [{"class": c, "probability": p} for c, p in self.top_k], "steps_read": self.steps_read,
                "length": self.length, "preprocessing": self.preprocessing, "probabilities": self.probabilities}


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


def _check_path(path: Path) -> None:
    """What can be said of a file without reading it: it exists and is a ``.csv`` or ``.npy``."""
    try:
        missing = not path.exists()
    except OSError:  # cannot be looked at (permissions): the reader says why
        missing = False
    if missing:
        raise DatasetError(f"{path}: file not found")
    if path.suffix.lower() not in (".csv", ".npy"):
        raise DatasetError(f"{path}: not a recording file (expected .csv or .npy)")


def _read_table(path: Path, spec: Any, max_rows: int | None) -> tuple[np.ndarray, int]:
    """``(the first max_rows rows as float64, the rows in the file)``; the rows not used are not read."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        table = read_csv_table(path, optional_header=True, max_rows=max_rows)
        return table.table, table.rows
    else:  # .npy (_check_path allows no other suffix)
        view = open_npy(path)  # memory-mapped: only the rows copied below are read
        array = np.array(_as_table(view, spec, str(path), max_rows), dtype=np.float64)
        check_finite(array, path)
        return array, int(view.shape[0])


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
                   name: str | None = None, preprocessing: RecordingPreprocessing | None = None) -> Recording:
    """Read one recording (a ``.csv``/``.npy`` file or a 2-D array) in the documented format, apply
    ``preprocessing`` and bring it to ``spec``'s number of steps.

    Args:
        source: the file, or an array ``(T, N * C + G)`` (``(T, N, C)`` without globals).
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` the model expects.
        length: ``"crop"``, ``"pad"`` or ``"resample"`` (see the module docstring); ``None`` keeps every row (a
            stream, which has no fixed length).
        name: what errors call an array (default ``<array>``).
        preprocessing: the weights' dataset's transform of a raw recording
            (:func:`~tactile_zoo.weights.manifest.entry_preprocessing`), applied to the rows read before their length
            is fitted; ``None``: the values as read.

    Shapes:
        file or array ``(T_file, N * C + G)`` (or ``(T_file, N, C)`` when ``G = 0``) -> ``x (T, N, C)``, ``g (T, G)``
        with ``T = spec.num_steps`` (``T = T_file`` with ``length=None``).

    Raises:
        DatasetError: naming the file and what is wrong: not numeric, NaN/Inf, wrong shape or taxel count, too short.
    """
    if length is not None and length not in LENGTHS:
        raise ConfigError(f"length must be one of {', '.join(LENGTHS)}, got {length!r}")
    # crop and pad use the first T rows only (and those the preprocessing needs): the rest of a file is not read
    max_rows = max(spec.num_steps, preprocessing.head_rows if preprocessing else 0) if length in ("crop", "pad") \
        else None
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
        _check_path(path)
        table, steps_read = _read_table(path, spec, max_rows)
    _check_width(table, steps_read, spec, where)
    if preprocessing is not None and len(table):
        table = preprocessing.apply(table, where)
        check_finite(table, f"{where} (after {preprocessing.name})")
    if length is None:
        if steps_read == 0:
            raise DatasetError(f"{where}: no rows (no time steps)")
        action = "as recorded"
    else:
        table, action = _fit_length(table, steps_read, spec.num_steps, length, where, spec.name)
    data = torch.from_numpy(np.ascontiguousarray(table, dtype=np.float32))  # (T, N*C + G)
    n, c = spec.num_nodes, spec.num_channels
    return Recording(where, data[:, : n * c].reshape(-1, n, c), data[:, n * c:], steps_read, action,
                     preprocessing.name if preprocessing is not None else None)


def model_preprocessing(model: nn.Module) -> RecordingPreprocessing | None:
    """What a raw recording goes through before ``model`` reads it: its pretrained weights' preprocessing
    (:func:`~tactile_zoo.weights.manifest.entry_preprocessing`), or that of the ``train --save`` checkpoint it was
    built from (:func:`~tactile_zoo.weights.manifest.checkpoint_preprocessing`); ``None`` for any other model."""
    entry = getattr(model, "zoo_pretrained", None)
    if entry is not None:
        return entry_preprocessing(entry)
    config = getattr(model, "zoo_checkpoint", None)
    return checkpoint_preprocessing(config) if config is not None else None


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
    trained = (getattr(model, "zoo_checkpoint", None) or {}).get("spec")
    if trained:
        from ..data.spec import DatasetSpec

        return DatasetSpec.from_dict(trained, where="the checkpoint")
    if getattr(model, "spec", None) is not None:
        return model.spec
    raise ConfigError(f"predict: pass spec= (the {type(model).__name__} model does not say which data it was built "
                      f"for)")


def _prepare(model: str | nn.Module, pretrained: Any, spec: Any, top_k: int, on_error: str, hparams: dict[str, Any]
             ) -> tuple[nn.Module, Any]:
    """The model and its spec, every argument checked (before any input is read)."""
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
    return model, spec


#: Recordings read and classified at a time by default: the forward pass's activations dominate predict's memory
#: (X-Tacformer on 250 event frames: about 7 MB per recording), so the batch, not the number of files, bounds it.
DEFAULT_BATCH = 32


def iter_predict(model: str | nn.Module, inputs: Any, *, pretrained: Any = None, spec: Any = None, top_k: int = 5,
                 length: str = "crop", device: str | torch.device | None = None, batch_size: int = DEFAULT_BATCH,
                 on_error: str = "raise", raw: bool = False, **hparams: Any) -> Iterator[Prediction | Refused]:
    """:func:`predict`, one answer at a time: the inputs are read ``batch_size`` at a time, classified, yielded and
    dropped, so memory stays bounded whatever their number. Arguments as :func:`predict`'s; they are checked (and the
    model loaded) when this is called, the inputs as they are reached.

    Returns:
        an iterator of one :class:`Prediction` (or :class:`Refused`) per input, in order.
    """
    model, spec = _prepare(model, pretrained, spec, top_k, on_error, hparams)
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ConfigError(f"batch_size must be a positive integer, got {batch_size!r}")
    preprocessing = None if raw else model_preprocessing(model)
    items = _as_list(inputs)
    if not items:
        raise ConfigError("predict: no inputs")
    if on_error == "raise":  # a missing file is found before any work, not after the files before it
        for item in items:
            if isinstance(item, str | os.PathLike):
                _check_path(Path(item).expanduser())
    dev = None
    if device is not None:
        from ..engine.runtime import resolve_device  # the engine on first use: `import tactile_zoo` stays light

        dev = resolve_device(device)
        model.to(dev)
    return _answers(model, spec, items, top_k, length, dev, batch_size, on_error, preprocessing)


def _answers(model: nn.Module, spec: Any, items: list[Any], top_k: int, length: str, dev: torch.device | None,
             batch_size: int, on_error: str, preprocessing: RecordingPreprocessing | None
             ) -> Iterator[Prediction | Refused]:
    for start in range(0, len(items), batch_size):
        read: list[Recording | Refused] = []
        for i, item in enumerate(items[start:start + batch_size], start=start):
            try:
                read.append(read_recording(item, spec, length=length, name=f"<array {i}>",
                                           preprocessing=preprocessing))
            except DatasetError as exc:  # what is wrong with this input only; anything else stops the whole call
                if on_error == "raise":
                    raise
                source = str(Path(item).expanduser()) if isinstance(item, str | os.PathLike) else f"<array {i}>"
                read.append(Refused(source, str(exc)))
        yield from _classify(model, spec, read, top_k, dev)


def _classify(model: nn.Module, spec: Any, read: list[Recording | Refused], top_k: int, dev: torch.device | None
              ) -> list[Prediction | Refused]:
    """One batch of read inputs answered in place (a :class:`Refused` stays as it is)."""
    from ..engine.evaluate import model_loss, predict_scores
    from ..engine.metrics import scores_to_probabilities
    from ..engine.runtime import flush_denormals

    recordings = [r for r in read if isinstance(r, Recording)]
    if not recordings:
        return list(read)
    x = torch.stack([r.x for r in recordings])  # (S, T, N, C)
    g = torch.stack([r.g for r in recordings])  # (S, T, G)
    with flush_denormals():  # as evaluate() runs, so the numbers are the same
        scores = predict_scores(model, x, g, len(recordings), dev)  # (S, K)
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
                              rec.length, rec.preprocessing))
    return out


def predict(model: str | nn.Module, inputs: Any, *, pretrained: Any = None, spec: Any = None, top_k: int = 5,
            length: str = "crop", device: str | torch.device | None = None, batch_size: int = DEFAULT_BATCH,
            on_error: str = "raise", raw: bool = False, **hparams: Any) -> list[Any]:
    """The most probable classes of recorded grasps.

    Args:
        model: a model name (then ``pretrained`` is required) or a built model (a pretrained one, or one built from a
            checkpoint, knows its spec).
        inputs: a ``.csv``/``.npy`` file, a 2-D array ``(T, N * C + G)``, or a list of them.
        pretrained: with a model name: a dataset name, a tag, a local manifest or ``.safetensors`` file, or a
            WeightEntry (see :func:`tactile_zoo.create_model`).
        spec: the spec the inputs follow (default: the weights').
        top_k: how many classes to report per recording.
        length: ``"crop"``, ``"pad"`` or ``"resample"`` (see the module docstring).
        device: where to run (default: where the model is; ``"auto"`` = CUDA when available).
        batch_size: recordings read and classified at a time (memory grows with it, not with the number of inputs).
        on_error: an input that cannot be read (missing, not numeric, NaN, wrong shape, ...): ``"raise"`` (default)
            raises its :class:`~tactile_zoo.errors.DatasetError` (a missing file before any prediction, a bad
            content when its batch is read; nothing is returned); ``"report"`` answers every other input and puts a
            :class:`Refused` in its place.
        raw: feed the values as read. By default the pretrained weights' preprocessing
            (:func:`~tactile_zoo.weights.manifest.entry_preprocessing`: BioTac-DoS's normalisation, for instance), or
            that of the checkpoint a model was built from (:func:`~tactile_zoo.engine.build_from_checkpoint`), is
            applied to every input first (:func:`model_preprocessing`), and each :class:`Prediction` names it in
            ``preprocessing``.
        **hparams: constructor overrides, with a model name.

    Returns:
        one :class:`Prediction` (or, with ``on_error="report"``, :class:`Refused`) per input, in order.
        Probabilities are the softmax of the logits, or the output spike rates normalised to sum 1 for a model
        trained with ``mse_rate`` (SGnet), as :func:`tactile_zoo.evaluate` does. :func:`iter_predict` yields them one
        at a time instead.
    """
    return list(iter_predict(model, inputs, pretrained=pretrained, spec=spec, top_k=top_k, length=length,
                             device=device, batch_size=batch_size, on_error=on_error, raw=raw, **hparams))
