"""The embedded default (``tactile-zoo bench --models all`` on the simulators) is sized for a first run: the recipes'
per-dataset sections for the simulators give every model optimizer steps to learn from and keep the costly models
short, and they touch nothing on real data (the Table I cells' configurations, hence their hashes, stay as they are).

What the sections hold and why: the comments in ``tactile_zoo/recipes/convlstm.yaml``, ``deeptactile.yaml`` and
``multibarrel.yaml``;
the scores and seconds they gave: docs/quickstart.md, "What `make bench` gives".
"""

from __future__ import annotations

import dataclasses
import math

import pytest

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.engine.config import config_hash, resolve_cell

#: the zoo's own datasets (defined in tactile_zoo.data), not the ones other test modules register in this worker
ZOO_DATASETS = [d for d in registry.list_datasets() if registry.get_dataset_entry(d).dist is None
                and getattr(registry.get_dataset_entry(d).obj, "__module__", "").startswith("tactile_zoo.data.")]
SIMULATORS = sorted(d for d in ZOO_DATASETS if registry.get_dataset_entry(d).meta.get("simulated"))
REAL = sorted(d for d in ZOO_DATASETS if not registry.get_dataset_entry(d).meta.get("simulated"))
#: the zoo's own models (defined in tactile_zoo.models), not the ones other test modules register in this worker
BUILT_IN = sorted(m for m in registry.model_names() if registry.get_model_entry(m).dist is None
                  and registry.get_model_entry(m).obj.__module__.startswith("tactile_zoo.models."))
#: the models whose default recipe carries simulator sections (the three that did not fit a first run)
SIZED = ("convlstm", "deeptactile", "multibarrel")
#: of those, the ones whose recipes have no section for a real dataset
SIMULATOR_SECTIONS_ONLY = ("deeptactile", "multibarrel")
#: ConvLSTM's epochs on a simulator (it was the first run's long pole at the simulators' cap of 15)
CONVLSTM_MAX_EPOCHS = 10
#: DeepTactile's clock on the simulators: at most this many binned time steps per sample
DEEPTACTILE_MAX_STEPS = 5
#: the multi-barrel SNN's optimizer steps on a simulator: per epoch, and in all
MULTIBARREL_STEPS_PER_EPOCH, MULTIBARREL_STEPS = 8, 60

_TRAIN_SIZES: dict[str, int] = {}


def train_size(dataset: str) -> int:
    if dataset not in _TRAIN_SIZES:  # generated in well under a second
        _TRAIN_SIZES[dataset] = len(tz.load_dataset(dataset, split="train"))
    return _TRAIN_SIZES[dataset]


def test_the_grid_has_three_simulators_and_real_datasets() -> None:
    assert len(SIMULATORS) == 3 and {"ev_objects", "ev_containers", "biotac_dos"} <= set(REAL)


@pytest.mark.parametrize("dataset", SIMULATORS)
@pytest.mark.parametrize("model", BUILT_IN)
def test_no_default_recipe_takes_a_simulators_training_split_in_one_batch(model: str, dataset: str) -> None:
    """One batch per epoch is one optimizer step per epoch: 15 in the whole budget, too few to leave chance."""
    recipe = resolve_cell(model, dataset).recipe
    assert math.ceil(train_size(dataset) / recipe.batch_size) >= 2, (model, dataset, recipe.batch_size)


@pytest.mark.parametrize("dataset", SIMULATORS)
def test_the_multibarrel_snn_gets_enough_optimizer_steps_on_a_simulator(dataset: str) -> None:
    recipe = resolve_cell("multibarrel", dataset).recipe
    per_epoch = math.ceil(train_size(dataset) / recipe.batch_size)
    assert per_epoch >= MULTIBARREL_STEPS_PER_EPOCH and per_epoch * recipe.max_epochs >= MULTIBARREL_STEPS
    assert recipe.max_epochs <= registry.get_dataset_entry(dataset).meta["max_epochs"]  # within the protocol's cap


@pytest.mark.parametrize("dataset", SIMULATORS)
def test_deeptactile_reads_the_simulators_in_bins(dataset: str) -> None:
    cell = resolve_cell("deeptactile", dataset)
    steps = registry.get_dataset_entry(dataset).meta["num_steps"]
    assert cell.hparams["bin_size"] > 1 and math.ceil(steps / cell.hparams["bin_size"]) <= DEEPTACTILE_MAX_STEPS


@pytest.mark.parametrize("dataset", SIMULATORS)
def test_convlstm_reads_taxels_for_fewer_epochs_on_a_simulator(dataset: str) -> None:
    cell = resolve_cell("convlstm", dataset)
    assert cell.hparams["readout"] == "taxels" and cell.recipe.max_epochs <= CONVLSTM_MAX_EPOCHS


@pytest.mark.parametrize("model", SIMULATOR_SECTIONS_ONLY)
def test_the_sections_name_simulators_only(model: str) -> None:
    for name, recipe in registry.get_model_entry(model).meta["recipes"].items():
        sections = set(recipe.get("datasets") or {})
        if name == "full":  # `full`'s real-data sections are its declared epoch counts, nothing else
            counts = {d for d, s in (recipe.get("datasets") or {}).items() if d not in SIMULATORS}
            assert all(set(recipe["datasets"][d]) == {"max_epochs", "patience", "evaluation"} for d in counts), model
            sections -= counts
        assert sections <= set(SIMULATORS), (model, name, sections - set(SIMULATORS))


def _without_simulator_sections(entry: registry.Entry) -> registry.Entry:
    recipes = {name: {**recipe, "datasets": {d: s for d, s in (recipe.get("datasets") or {}).items()
                                             if d not in SIMULATORS}}
               for name, recipe in entry.meta["recipes"].items()}
    recipes = {name: {k: v for k, v in recipe.items() if k != "datasets" or v} for name, recipe in recipes.items()}
    meta = {**entry.meta, "recipes": recipes, "recipe": recipes[entry.meta["default_recipe"]]}
    return dataclasses.replace(entry, meta=meta)


@pytest.mark.parametrize("model", SIZED)
def test_real_data_resolves_as_without_the_simulator_sections(model: str, monkeypatch: pytest.MonkeyPatch) -> None:
    names = [None, *registry.get_model_entry(model).meta["recipes"]]

    def hashes() -> dict[tuple[str | None, str], str]:
        return {(name, d): config_hash(resolve_cell(model, d, recipe_name=name))
                for name in names for d in [*REAL, *SIMULATORS]}

    with_sections = hashes()
    real_entry = registry.get_model_entry

    def stripped(name: str) -> registry.Entry:
        entry = real_entry(name)
        return _without_simulator_sections(entry) if entry.name == model else entry

    monkeypatch.setattr(registry, "get_model_entry", stripped)
    without = hashes()
    assert {k: v for k, v in with_sections.items() if k[1] in REAL} == {k: v for k, v in without.items()
                                                                          if k[1] in REAL}
    # the default recipe's sections do change the simulators' cells (else this test would compare nothing)
    assert all(with_sections[None, d] != without[None, d] for d in SIMULATORS)
