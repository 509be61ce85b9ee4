"""Predicting the class of recorded grasps with pretrained weights: :func:`predict` and :func:`read_recording`.

Input files are the bring-your-own recordings format (:mod:`tactile_zoo.data.datasets.recordings`): one row per time
step; the columns are the taxel readings in row-major taxel order, all channels of a taxel together (``[ch0 ..
chC-1]`` of taxel 0, then of taxel 1, ...), then the global features: ``N * C + G`` columns. A ``.csv`` may start with
one row of column names; a ``.npy`` is a 2-D real array ``(T, N * C + G)``, read without unpickling. The values are
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

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..data.datasets._io import check_finite, load_npy, read_numeric_csv
from ..errors import ConfigError, DatasetError
from .load import load_pretrained

__all__ = ["LENGTHS", "Recording", "Prediction", "read_recording", "predict"]

#: How a recording of another length is brought to the weights' number of steps (see the module docstring).
LENGTHS = ("crop", "pad", "resample")


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


def _read_table(path: Path) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return read_numeric_csv(path, optional_header=True)
    if suffix == ".npy":
        array = load_npy(path)
        if array.ndim != 2:
            raise DatasetError(f"{path}: array of shape {array.shape}; expected 2-D (time steps, columns): one row "
                               f"per time step")
        array = array.astype(np.float64)
        check_finite(array, path)
        return array
    if not path.exists():
        raise DatasetError(f"{path}: file not found")
    raise DatasetError(f"{path}: not a recording file (expected .csv or .npy)")


def _check_width(table: np.ndarray, spec: Any, where: str) -> None:
    n, c, g = spec.num_nodes, spec.num_channels, spec.num_globals
    width, (rows, cols) = n * c + g, table.shape
    if cols == width:
        return
    message = (f"{where}: {cols} columns, expected {width} = {n} taxels x {c} channel(s) + {g} global(s) (sensor "
               f"{spec.sensor.name!r}; one row per time step, taxels row-major, then globals)")
    if rows == width:
        message += f"; it has {rows} rows: transposed? (write one row per time step)"
    elif cols > g and (cols - g) % c == 0:
        message += f"; that would be {(cols - g) // c} taxels: wrong taxel count (another sensor?)"
    raise DatasetError(message)


def _fit_length(table: np.ndarray, steps: int, length: str, where: str, dataset: str) -> tuple[np.ndarray, str]:
    rows = table.shape[0]
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
        source: the file, or an array ``(T, N * C + G)``.
        spec: the :class:`~tactile_zoo.data.spec.DatasetSpec` the model expects.
        length: ``"crop"``, ``"pad"`` or ``"resample"`` (see the module docstring); ``None`` keeps every row (a
            stream, which has no fixed length).
        name: what errors call an array (default ``<array>``).

    Shapes:
        file or array ``(T_file, N * C + G)`` -> ``x (T, N, C)``, ``g (T, G)`` with ``T = spec.num_steps``
        (``T = T_file`` with ``length=None``).

    Raises:
        DatasetError: naming the file and what is wrong: not numeric, NaN/Inf, wrong shape or taxel count, too short.
    """
    if length is not None and length not in LENGTHS:
        raise ConfigError(f"length must be one of {', '.join(LENGTHS)}, got {length!r}")
    if isinstance(source, np.ndarray | torch.Tensor):
        where = name or "<array>"
        table = np.asarray(source.detach().cpu() if isinstance(source, torch.Tensor) else source)
        if table.ndim != 2 or table.dtype.kind not in "biuf":
            raise DatasetError(f"{where}: expected a 2-D real array (time steps, columns), got shape {table.shape} "
                               f"dtype {table.dtype}")
        table = table.astype(np.float64)
        check_finite(table, where)
    else:
        path = Path(source).expanduser()
        where = str(path)
        table = _read_table(path)
    _check_width(table, spec, where)
    steps_read = int(table.shape[0])
    if length is None:
        if steps_read == 0:
            raise DatasetError(f"{where}: no rows (no time steps)")
        action = "as recorded"
    else:
        table, action = _fit_length(table, spec.num_steps, length, where, spec.name)
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
            **hparams: Any) -> list[Prediction]:
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
        **hparams: constructor overrides, with a model name.

    Returns:
        one :class:`Prediction` per input, in order. Probabilities are the softmax of the logits, or the output spike
        rates normalised to sum 1 for a model trained with ``mse_rate`` (SGnet), as :func:`tactile_zoo.evaluate` does.
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
    items = _as_list(inputs)
    if not items:
        raise ConfigError("predict: no inputs")
    recordings = [read_recording(item, spec, length=length, name=f"<array {i}>") for i, item in enumerate(items)]
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
    out = []
    for rec, score_row, prob_row in zip(recordings, scores, probs):
        best = int(score_row.argmax())
        order = torch.argsort(prob_row, descending=True, stable=True)[:k].tolist()
        out.append(Prediction(rec.source, best, names[best], float(prob_row[best]),
                              [(names[j], float(prob_row[j])) for j in order], prob_row.tolist(), rec.steps_read,
                              rec.length))
    return out
