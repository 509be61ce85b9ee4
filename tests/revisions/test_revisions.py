"""Revisions must move with the numbers: a built-in model or simulated dataset whose outputs changed while its
``revision`` did not fails here, and so does one whose revision was bumped without regenerating the record.

The revision is part of every benchmark cell's hash, so a forgotten bump lets committed results computed by old code
be reused silently. ``expected_outputs.json`` records what each built-in model (initial state, logits and gradients
on seeded inputs, per simulated spec) and each simulated dataset (fold-0 fingerprints) computes at its revision;
``regenerate.py`` writes it and holds the fingerprint code this test shares. Parametrised over the file and the
registry together, so a new built-in missing from the file, or a removed one still in it, fails too. The ``guard``
tests at the end show that the comparison really fails on a changed output and on a stale revision.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import pytest
import regenerate as rg  # tests/revisions is on sys.path, as every test folder's own helpers are (no __init__.py)
import torch

from tactile_zoo import registry
from tactile_zoo.data.spec import DatasetSpec

EXPECTED = rg.load_expected()
#: every record key: each built-in model at each revision it builds (``NAME`` or ``NAME@REVISION``), and the file's
MODELS = sorted({rg.record_key(name, rev) for name, rev in rg.builtin_records()} | set(EXPECTED["models"]))
DATASETS = sorted(set(rg.sim_datasets()) | set(EXPECTED["datasets"]))


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A throw-away data root: the simulators never write into the repository or the shared data home."""
    return tmp_path_factory.mktemp("revisions_data")


@pytest.fixture(scope="module")
def specs(sim_root: Path) -> dict[str, DatasetSpec]:
    return rg.sim_specs(sim_root)


def check_model(key: str, expected: Mapping[str, Any], specs: Mapping[str, DatasetSpec]) -> list[str]:
    """Problems of record ``key`` (a model's name: its lowest revision; ``NAME@REVISION``: a later one) against
    ``expected["models"]``; outputs are only recomputed at an equal revision."""
    name, at, number = key.partition("@")
    if name not in rg.builtin_models():
        return [f"model {name} is in tests/revisions/expected_outputs.json but is no built-in model any more: rerun "
                f"{rg.REGENERATE}"]
    revisions = rg.model_revisions(name)
    revision = int(number) if at else min(revisions)
    if revision not in revisions or rg.record_key(name, revision) != key:
        return [f"model {name}: tests/revisions/expected_outputs.json records {key!r}, but the model builds "
                f"revision(s) {revisions} only (recorded as {[rg.record_key(name, r) for r in revisions]}): rerun "
                f"{rg.REGENERATE}"]
    stored = expected["models"].get(key)
    if stored is None or stored["revision"] != revision:
        return [rg.stale_message("model", key, revision, None if stored is None else stored["revision"])]
    return rg.model_problems(key, stored, rg.model_record(name, specs, revision))


def check_dataset(name: str, expected: Mapping[str, Any], root: Path) -> list[str]:
    """Problems of simulated dataset ``name`` against ``expected["datasets"]``."""
    if name not in rg.sim_datasets():
        return [f"simulated dataset {name} is in tests/revisions/expected_outputs.json but is no built-in simulated "
                f"dataset any more: rerun {rg.REGENERATE}"]
    stored, revision = expected["datasets"].get(name), rg.dataset_revision(name)
    if stored is None or stored["revision"] != revision:
        return [rg.stale_message("simulated dataset", name, revision, None if stored is None else stored["revision"])]
    return rg.dataset_problems(name, stored, rg.dataset_record(name, root))


def test_the_record_covers_the_zoo() -> None:
    assert EXPECTED["models"] and EXPECTED["datasets"], f"no record: run {rg.REGENERATE}"
    assert EXPECTED.get("format") == rg.FORMAT, f"the record's format is outdated: run {rg.REGENERATE}"


@pytest.mark.parametrize("name", MODELS)
def test_model_outputs_match_its_revision(name: str, specs: dict[str, DatasetSpec]) -> None:
    problems = check_model(name, EXPECTED, specs)
    if problems:
        pytest.fail("\n".join(problems), pytrace=False)


@pytest.mark.parametrize("name", DATASETS)
def test_simulated_data_matches_its_revision(name: str, sim_root: Path) -> None:
    problems = check_dataset(name, EXPECTED, sim_root)
    if problems:
        pytest.fail("\n".join(problems), pytrace=False)


# ----------------------------------------------------------------------------------------------- the guard itself
def _guard_model() -> str:
    """A built-in model with plain logits (cross-entropy recipe): a nudged output bias moves them one to one."""
    return next(n for n in rg.builtin_models() if registry.get_model_entry(n).meta["recipe"]["loss"] == "ce")


def _bump(monkeypatch: pytest.MonkeyPatch, kind: str, name: str) -> int:
    """Raise the registered revision of ``name`` by one, in memory only (as a bump without regenerating)."""
    table = registry._TABLES[kind].builtin
    key = registry.normalize_name(name)
    entry = table[key]
    revision = registry.revision_of(entry) + 1
    monkeypatch.setitem(table, key, dataclasses.replace(entry, meta=MappingProxyType({**entry.meta,
                                                                                        "revision": revision})))
    return revision


def test_guard_fails_on_a_changed_model_output(monkeypatch: pytest.MonkeyPatch,
                                               specs: dict[str, DatasetSpec]) -> None:
    name = _guard_model()
    one_spec = dict(list(specs.items())[:1])
    baseline = rg.model_record(name, one_spec)
    create = registry.instantiate_model

    def nudged(*args: Any, **kwargs: Any) -> torch.nn.Module:
        model = create(*args, **kwargs)
        head = [m for m in model.modules() if isinstance(m, torch.nn.Linear) and m.bias is not None][-1]
        with torch.no_grad():
            head.bias.add_(1e-3)
        return model

    assert rg.model_problems(name, baseline, rg.model_record(name, one_spec)) == []  # deterministic when unchanged
    monkeypatch.setattr(registry, "instantiate_model", nudged)
    problems = rg.model_problems(name, baseline, rg.model_record(name, one_spec))
    revision = rg.model_revision(name)
    assert len(problems) == 1 and "logits differ" in problems[0], problems
    assert problems[0].startswith(f"outputs of model {name} changed but its revision is still {revision}: bump "
                                  f"`revision` in its @register_model(...) and rerun {rg.REGENERATE}"), problems


def test_guard_fails_on_a_bumped_model_revision(monkeypatch: pytest.MonkeyPatch,
                                                specs: dict[str, DatasetSpec]) -> None:
    name = _guard_model()
    one_spec = dict(list(specs.items())[:1])
    expected = {"models": {name: rg.model_record(name, one_spec)}, "datasets": {}}
    old = expected["models"][name]["revision"]
    new = _bump(monkeypatch, "model", name)
    problems = check_model(name, expected, one_spec)
    assert len(problems) == 1, problems
    assert f"model {name} has revision {new} but tests/revisions/expected_outputs.json records revision {old}" \
           in problems[0] and rg.REGENERATE in problems[0] and "same commit" in problems[0], problems


def test_guard_fails_on_a_model_missing_from_the_record(specs: dict[str, DatasetSpec]) -> None:
    problems = check_model(_guard_model(), {"models": {}, "datasets": {}}, specs)
    assert len(problems) == 1 and "is not in tests/revisions/expected_outputs.json" in problems[0] \
           and rg.REGENERATE in problems[0], problems


def _nudge_one_value(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    x = x.clone()
    x[0, 0, 0, 0] += 1.0
    return x


def _swap_two_samples_of_one_class(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Leaves counts, labels, sums and squares alone: only the order-sensitive projection sees it."""
    i = int(torch.nonzero(y[1:] == y[:-1])[0])
    x = x.clone()
    x[[i, i + 1]] = x[[i + 1, i]]
    return x


@pytest.mark.parametrize("change", [_nudge_one_value, _swap_two_samples_of_one_class])
def test_guard_fails_on_changed_simulated_data(monkeypatch: pytest.MonkeyPatch, sim_root: Path,
                                               change: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]) -> None:
    name = rg.sim_datasets()[0]
    baseline = rg.dataset_record(name, sim_root)
    load = registry.load_dataset

    def changed(*args: Any, **kwargs: Any) -> Any:
        dataset = load(*args, **kwargs)
        if kwargs.get("split") == "train":
            dataset.x = change(dataset.x, dataset.y)
        return dataset

    monkeypatch.setattr(registry, "load_dataset", changed)
    problems = rg.dataset_problems(name, baseline, rg.dataset_record(name, sim_root))
    revision = rg.dataset_revision(name)
    assert len(problems) == 1 and "split train:" in problems[0], problems
    assert problems[0].startswith(f"data of simulated dataset {name} changed but its revision is still {revision}: "
                                  f"bump `revision` in its @register_dataset(...) and rerun {rg.REGENERATE}"), problems


def test_guard_fails_on_a_bumped_dataset_revision(monkeypatch: pytest.MonkeyPatch, sim_root: Path) -> None:
    name = rg.sim_datasets()[0]
    expected = {"models": {}, "datasets": {name: {"revision": rg.dataset_revision(name)}}}
    new = _bump(monkeypatch, "dataset", name)
    problems = check_dataset(name, expected, sim_root)
    assert len(problems) == 1 and f"simulated dataset {name} has revision {new}" in problems[0] \
           and rg.REGENERATE in problems[0], problems
