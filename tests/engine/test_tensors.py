from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine.tensors import as_split, concat, take
from tactile_zoo.errors import DatasetError


def test_take_is_class_balanced_deterministic_and_keeps_order() -> None:
    train = tz.load_dataset("tiny_blobs", split="train")
    sub = take(train, 9, seed=0)
    assert len(sub) == 9 and torch.bincount(sub.y, minlength=3).tolist() == [3, 3, 3]
    again = take(train, 9, seed=0)
    assert torch.equal(sub.x, again.x)
    assert not torch.equal(take(train, 9, seed=1).x, sub.x)
    assert take(train, 10_000).x.shape == train.x.shape  # no limit hit: the split itself


def test_concat_and_validation() -> None:
    tr, va = (tz.load_dataset("tiny_blobs", split=s) for s in ("train", "val"))
    both = concat(tr, va)
    assert len(both) == len(tr) + len(va) and both.spec == tr.spec
    bad = type("Bad", (), {"spec": tr.spec, "tensors": lambda self: (tr.x, tr.g, tr.y + 5)})()
    with pytest.raises(DatasetError, match="labels must lie in 0..2"):
        as_split(bad)
    flat = type("Flat", (), {"spec": tr.spec, "tensors": lambda self: (tr.x[:, 0], tr.g, tr.y)})()
    with pytest.raises(DatasetError, match=r"expected x \[S, T, N, C\]"):
        as_split(flat)
    with pytest.raises(DatasetError, match="no .spec"):
        as_split([1, 2, 3])


def test_groups_travel_with_take_and_concat() -> None:
    tr, va = (tz.load_dataset("tiny_blobs", split=s) for s in ("train", "val"))
    split = as_split(tr)
    assert split.groups is not None and torch.equal(split.groups, tr.groups.long())
    sub = take(tr, 9, seed=0)
    chosen = [int(torch.nonzero((tr.x == x).flatten(1).all(1))[0]) for x in sub.x]  # rows of tr that were taken
    assert sub.groups.tolist() == tr.groups[chosen].tolist()
    both = concat(tr, va)
    assert both.groups.tolist() == tr.groups.tolist() + va.groups.tolist()
    no_groups = type("Plain", (), {"spec": tr.spec, "tensors": lambda self: (tr.x, tr.g, tr.y)})()
    assert as_split(no_groups).groups is None and as_split(no_groups).unit_ids() == list(range(len(tr)))
