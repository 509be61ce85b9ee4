"""Deterministic, stratified, group-aware splitting: the one place splits and folds are computed.

A *group* is the unit that must never be split (a recording cut into windows, a sample and its augmented copies).
Every function here is a pure function of its arguments and a seed, so every consumer of a dataset sees the same
validation set and the same folds.
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError

__all__ = ["carve_holdout", "stratified_group_kfold"]


def _groups_by_class(indices: np.ndarray, labels: np.ndarray, groups: np.ndarray) -> dict[int, list[int]]:
    """class -> sorted distinct groups whose first sample (in ``indices`` order) has that class."""
    first_label: dict[int, int] = {}
    for i in indices:
        first_label.setdefault(int(groups[i]), int(labels[i]))
    by_class: dict[int, list[int]] = {}
    for grp, lab in sorted(first_label.items()):
        by_class.setdefault(lab, []).append(grp)
    return by_class


def carve_holdout(indices: np.ndarray, labels: np.ndarray, groups: np.ndarray | None, fraction: float, seed: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Split ``indices`` into (kept, held out), holding out about ``fraction`` of each class's groups.

    Every class with at least two groups keeps at least one and holds out at least one; a class with a single group
    stays entirely in the kept part. Order within each part follows ``indices``.
    """
    if not 0.0 < fraction < 1.0:
        raise ConfigError(f"holdout fraction must be in (0, 1), got {fraction}")
    indices = np.asarray(indices, dtype=np.int64)
    groups = np.arange(len(labels)) if groups is None else np.asarray(groups)
    rng = np.random.default_rng(seed)
    held: set[int] = set()
    for _, class_groups in sorted(_groups_by_class(indices, labels, groups).items()):
        if len(class_groups) < 2:
            continue
        order = rng.permutation(len(class_groups))
        n_out = min(len(class_groups) - 1, max(1, int(round(fraction * len(class_groups)))))
        held |= {class_groups[j] for j in order[:n_out]}
    mask = np.isin(groups[indices], list(held))
    return indices[~mask], indices[mask]


def stratified_group_kfold(indices: np.ndarray, labels: np.ndarray, groups: np.ndarray | None, k: int, seed: int
                           ) -> list[np.ndarray]:
    """``k`` disjoint folds covering ``indices``; each class's groups are shuffled and dealt round-robin.

    A class with fewer groups than ``k`` is absent from the test part of some folds (its groups go to the folds that
    come next in the deal, which rotates per class so small classes do not all crowd fold 0).
    """
    if k < 2:
        raise ConfigError(f"k-fold needs k >= 2, got {k}")
    indices = np.asarray(indices, dtype=np.int64)
    groups = np.arange(len(labels)) if groups is None else np.asarray(groups)
    rng = np.random.default_rng(seed)
    fold_of_group: dict[int, int] = {}
    offset = 0
    for _, class_groups in sorted(_groups_by_class(indices, labels, groups).items()):
        order = rng.permutation(len(class_groups))
        for rank, j in enumerate(order):
            fold_of_group[class_groups[j]] = (offset + rank) % k
        offset = (offset + len(class_groups)) % k
    assign = np.array([fold_of_group[int(groups[i])] for i in indices], dtype=np.int64)
    return [indices[assign == f] for f in range(k)]
