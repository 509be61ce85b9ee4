"""Whole splits as tensors: the engine batches by indexing them, never through a per-sample ``DataLoader``.

A :class:`TactileDataset` hands out its split at once (``dataset.tensors()``); any other ``torch`` dataset of
``TactileSample`` (a plugin's) is collated once. :func:`take` draws the class-balanced subsets of ``--quick`` runs and
:func:`concat` joins train and val for ``--refit``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from ..data.spec import DatasetSpec
from ..errors import DatasetError

__all__ = ["TensorSplit", "as_split", "take", "concat"]


@dataclass
class TensorSplit:
    """One split held as tensors ``x [S, T, N, C]``, ``g [S, T, G]``, ``y [S]`` with its spec.

    ``groups [S]`` (optional) names each sample's independent unit, such as the recording a window was cut from;
    ``None`` means every sample is its own. ``soft [S, K]`` (optional) holds distillation's teacher probabilities of
    each sample (:mod:`.distill`).
    """

    x: torch.Tensor
    g: torch.Tensor
    y: torch.Tensor
    spec: DatasetSpec
    name: str = ""
    groups: torch.Tensor | None = None
    soft: torch.Tensor | None = None

    def unit_ids(self) -> list[int]:
        """The independent unit of every sample, in order (what a bootstrap resamples)."""
        return list(range(len(self))) if self.groups is None else self.groups.tolist()

    def tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.x, self.g, self.y

    def __len__(self) -> int:
        return int(self.y.shape[0])

    def __getitem__(self, i: int) -> Any:
        from ..data.spec import TactileSample

        return TactileSample(self.x[i], self.g[i], int(self.y[i]))


def _describe(dataset: Any) -> str:
    spec = getattr(dataset, "spec", None)
    split = getattr(dataset, "split", None) or getattr(dataset, "name", "")
    return f"{getattr(spec, 'name', type(dataset).__name__)}" + (f" [{split}]" if split else "")


def as_split(dataset: Any) -> TensorSplit:
    """Any dataset with ``.spec`` (a :class:`TactileDataset`, a plugin's, a :class:`TensorSplit`) as tensors."""
    if isinstance(dataset, TensorSplit):
        return dataset
    spec = getattr(dataset, "spec", None)
    if not isinstance(spec, DatasetSpec):
        raise DatasetError(f"{type(dataset).__name__} has no .spec (a DatasetSpec); the engine needs it to build "
                           f"and check the model")
    if hasattr(dataset, "tensors"):
        x, g, y = dataset.tensors()
    else:  # a plain torch Dataset of TactileSample: collate it once
        from ..data.spec import collate

        if len(dataset) == 0:
            raise DatasetError(f"{_describe(dataset)} is empty")
        x, g, y = collate([dataset[i] for i in range(len(dataset))])
    x, g, y = torch.as_tensor(x), torch.as_tensor(g), torch.as_tensor(y)
    where = _describe(dataset)
    if x.dim() != 4 or g.dim() != 3 or y.dim() != 1 or not (x.shape[0] == g.shape[0] == y.shape[0]) \
            or g.shape[1] != x.shape[1]:
        raise DatasetError(f"{where}: expected x [S, T, N, C], g [S, T, G], y [S]; got {tuple(x.shape)}, "
                           f"{tuple(g.shape)}, {tuple(y.shape)}")
    if y.numel() and (int(y.min()) < 0 or int(y.max()) >= spec.num_classes):
        raise DatasetError(f"{where}: labels must lie in 0..{spec.num_classes - 1}, found {int(y.min())}.."
                           f"{int(y.max())}")
    groups = getattr(dataset, "groups", None)
    groups = groups.long() if isinstance(groups, torch.Tensor) and groups.shape == y.shape else None
    return TensorSplit(x.float(), g.float(), y.long(), spec, str(getattr(dataset, "split", "") or ""), groups)


def take(dataset: Any, limit: int | None, seed: int = 0) -> TensorSplit:
    """At most ``limit`` samples, class-balanced: classes take turns, each giving its samples in a seeded order."""
    split = as_split(dataset)
    if limit is None or len(split) <= limit:
        return split
    gen = torch.Generator().manual_seed(seed)
    order = torch.randperm(len(split), generator=gen)
    # round-robin over classes: the i-th sample of every class comes before the (i+1)-th of any class
    rank = torch.empty(len(split), dtype=torch.long)
    labels = split.y[order]
    for cls in labels.unique():
        where = (labels == cls).nonzero().flatten()
        rank[where] = torch.arange(len(where))
    chosen = order[torch.sort(rank * (split.spec.num_classes + 1) + labels, stable=True).indices[:limit]]
    chosen = chosen.sort().values  # keep the dataset's own order
    return TensorSplit(split.x[chosen], split.g[chosen], split.y[chosen], split.spec, split.name,
                       None if split.groups is None else split.groups[chosen],
                       None if split.soft is None else split.soft[chosen])


def concat(a: Any, b: Any) -> TensorSplit:
    """Two splits of one dataset as one (train + val for ``refit``)."""
    a, b = as_split(a), as_split(b)
    if a.x.shape[1:] != b.x.shape[1:] or a.g.shape[1:] != b.g.shape[1:]:
        raise DatasetError(f"cannot join splits of shapes {tuple(a.x.shape[1:])} and {tuple(b.x.shape[1:])}")
    if (a.soft is None) != (b.soft is None):  # half a split without its teachers' probabilities would train wrongly
        raise DatasetError(f"cannot join {a.name or 'a split'} and {b.name or 'a split'}: only one holds teacher "
                           f"probabilities")
    groups = None if a.groups is None or b.groups is None else torch.cat([a.groups, b.groups])
    soft = None if a.soft is None or b.soft is None else torch.cat([a.soft, b.soft])
    return TensorSplit(torch.cat([a.x, b.x]), torch.cat([a.g, b.g]), torch.cat([a.y, b.y]), a.spec,
                       f"{a.name}+{b.name}", groups, soft)
