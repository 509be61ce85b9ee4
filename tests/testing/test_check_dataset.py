"""``tactile_zoo.testing.check_dataset`` passes a sound dataset and fails each planted broken one on the rule it breaks.

``Toy`` is a small in-memory dataset on the BioTac SP sensor; every planted dataset changes one thing about it. The
simulated built-ins go through the suite in tests/data/test_simulated.py.
"""

from __future__ import annotations

import pytest
import torch

from tactile_zoo.data.spec import DatasetSpec, TactileSample
from tactile_zoo.registry import get_dataset_entry, get_sensor
from tactile_zoo.testing import DATASET_RULES, ContractError, check_dataset

META = {"sensor": "biotac_sp", "num_classes": 3, "class_names": ("a", "b", "c"), "num_steps": 5, "num_nodes": 24,
        "num_channels": 1, "num_globals": 0, "folds": 1, "splits": ("train", "val", "test"), "protocol": "fixed"}
SIZES = {"train": 9, "val": 3, "test": 6}
OFFSETS = {"train": 0, "val": 100, "test": 200}  # each split draws other samples


class Toy:
    """``split`` of a seeded random dataset: labels cycle through the classes."""

    zoo_meta = META

    def __init__(self, root=None, split=None, fold=0, download=False) -> None:
        self.spec = self.make_spec(split)
        self.num_folds = 1
        n = SIZES[split]
        gen = torch.Generator().manual_seed(OFFSETS[split] + self.seed_offset())
        self.x = torch.rand(n, 5, 24, 1, generator=gen)
        self.g = torch.zeros(n, 5, 0)
        self.y = [i % 3 for i in range(n)]

    def make_spec(self, split: str) -> DatasetSpec:
        return DatasetSpec("toy", 3, ("a", "b", "c"), 5, 24, 1, 0, get_sensor("biotac_sp"))

    def seed_offset(self) -> int:
        return 0

    def __len__(self) -> int:
        return len(self.y)

    def __getitem__(self, i: int) -> TactileSample:
        return TactileSample(self.x[i], self.g[i], self.y[i])


class NoProtocol(Toy):
    zoo_meta = {k: v for k, v in META.items() if k != "protocol"}


class WrongTaxelCount(Toy):
    zoo_meta = {**META, "num_nodes": 23}


class EmptyVal(Toy):
    def __init__(self, root=None, split=None, fold=0, download=False) -> None:
        super().__init__(root, split, fold, download)
        if split == "val":
            self.x, self.y = self.x[:0], []


class SpecDisagrees(Toy):
    def make_spec(self, split: str) -> DatasetSpec:
        return DatasetSpec("toy", 3, ("a", "b", "c"), 5, 24, 1, 0, get_sensor("biotac_sp")) if split != "test" else \
            DatasetSpec("toy", 3, ("x", "y", "z"), 5, 24, 1, 0, get_sensor("biotac_sp"))


class Float64(Toy):
    def __getitem__(self, i: int) -> TactileSample:
        return TactileSample(self.x[i].double(), self.g[i], self.y[i])


class LabelOutOfRange(Toy):
    def __getitem__(self, i: int) -> TactileSample:
        return TactileSample(self.x[i], self.g[i], self.y[i] + 1)


class ShortRecording(Toy):
    def __getitem__(self, i: int) -> TactileSample:
        return TactileSample(self.x[i, :4], self.g[i, :4], self.y[i])


class MissingClass(Toy):
    def __init__(self, root=None, split=None, fold=0, download=False) -> None:
        super().__init__(root, split, fold, download)
        self.y = [i % 2 for i in range(len(self.y))]  # class 2 never occurs


class TestIsTrain(Toy):
    __test__ = False

    def __init__(self, root=None, split=None, fold=0, download=False) -> None:
        super().__init__(root, split, fold, download)
        if split == "test":  # the test split repeats the first training recordings
            self.x = Toy(split="train").x[:6]


class Unseeded(Toy):
    def seed_offset(self) -> int:
        return int(torch.randint(1, 10**6, (1,)))


def test_a_sound_dataset_passes_every_rule() -> None:
    report = check_dataset(Toy)
    assert report.subject == "Toy" and report.rules == list(DATASET_RULES)
    assert [where for rule, where in report.passed if rule == "samples"] == ["train", "val", "test"]


@pytest.mark.parametrize(("dataset", "rule", "detail"), [
    (NoProtocol, "metadata", "metadata lacks ['protocol']"),
    (WrongTaxelCount, "metadata", "sensor 'biotac_sp' has 24 taxels"),
    (EmptyVal, "loads", "the 'val' split is empty"),
    (SpecDisagrees, "spec", "the 'test' split's spec differs"),
    (Float64, "samples", "x is not a float32 tensor"),
    (LabelOutOfRange, "samples", "label 3 outside [0, 3)"),
    (ShortRecording, "samples", "x has shape (4, 24, 1)"),
    (MissingClass, "labels", "classes [2] never occur in the training split"),
    (TestIsTrain, "disjoint", "a sample of the 'test' split is also in the 'train' split"),
    (Unseeded, "deterministic", "gives another sample 0"),
])
def test_a_planted_break_fails_its_rule(dataset: type, rule: str, detail: str) -> None:
    with pytest.raises(ContractError) as info:
        check_dataset(dataset)
    err = info.value
    assert (err.kind, err.rule, err.subject) == ("dataset", rule, dataset.__name__), str(err)
    assert detail in err.detail, str(err)
    assert str(err).startswith(f"dataset {dataset.__name__!r} breaks rule {rule!r}")
    # the break is confined to it (and to what follows from the same metadata or labels)
    also = {WrongTaxelCount: ["spec"], LabelOutOfRange: ["labels"]}.get(dataset, [])
    check_dataset(dataset, skip=[rule, *also])


def test_a_registered_dataset_and_its_loader_keywords() -> None:
    small = {"n_train_per_class": 3, "n_test_per_class": 2}
    report = check_dataset("sim_biotac_slip", num_steps=8, **small)  # a keyword that changes a count on purpose
    assert ("disjoint", "") in report.passed and ("spec", "") in report.passed
    with pytest.raises(ContractError, match=r"dataset 'sim_biotac_slip' breaks rule 'spec': spec num_steps=30, the "
                                            r"metadata says 8"):
        check_dataset("sim_biotac_slip", meta={**get_dataset_entry("sim_biotac_slip").meta, "num_steps": 8},
                      rules=["spec"], **small)
