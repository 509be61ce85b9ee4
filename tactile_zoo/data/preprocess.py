"""A dataset's preprocessing of one recording, as a value other layers can apply to a user's file.

A dataset loader turns the release's raw recordings into what its models read (BioTac-DoS: each reading scaled by its
own range, or by a baseline). Weights trained on that dataset expect the same transform on a robot's raw recording;
:meth:`~tactile_zoo.data.base.TactileDataset.recording_preprocessing` returns it as a
:class:`RecordingPreprocessing` for the loading options the weights were trained with (``None``: the loader feeds
recordings as they are). The dataset applies the very same function to its own recordings, so the two cannot drift.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["RecordingPreprocessing"]


@dataclass(frozen=True)
class RecordingPreprocessing:
    """What a dataset does to one recording ``(R, N * C + G)`` (raw units, one row per reading) before its models
    read it.

    Attributes:
        name: short and exact, e.g. ``"biotac_dos normalize='minmax'"``: what outputs name.
        description: one sentence saying what is computed.
        head_rows: rows from the start of the recording the transform needs (a baseline of 10 readings needs 10 even
            when the model reads 5); a recording with fewer is refused by ``apply``.
        apply: ``f(table float64 (R, N * C + G), where) -> table`` of the same shape; ``where`` names the recording
            in errors.
    """

    name: str
    description: str
    head_rows: int
    apply: Callable[[np.ndarray, str], np.ndarray]

    def __str__(self) -> str:
        return f"{self.name}: {self.description}"
