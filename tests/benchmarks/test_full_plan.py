"""The ``full`` recipes' epoch counts are the rule of ``benchmarks/results/paper-table1-full/PLAN.md`` applied to the
committed ``zoo`` cells' validation choices, and nothing else: recomputed here from the cell records."""

from __future__ import annotations

import json
import math
import statistics
from dataclasses import replace
from pathlib import Path

import pytest

from tactile_zoo.bench.records import cell_files, read_cell_bytes
from tactile_zoo.engine.config import resolve_model_recipe
from tactile_zoo.registry import get_model_entry, model_names
from tactile_zoo.study.publish import study_folder

STUDIES = Path(__file__).resolve().parents[2] / "benchmarks" / "studies"
ZOO = study_folder(STUDIES, "table1-zoo")  # the `zoo` cells whose validation choices declared `full`'s epochs
#: DeepTactile joined after that round: its `zoo` cells are round 4's and the stage 1 of deeptactile-r5.yaml
DEEPTACTILE = (study_folder(STUDIES, "deeptactile-r4"), study_folder(STUDIES, "deeptactile-r5", "objects"))
DATASETS = ("ev_objects", "ev_containers", "biotac_dos")
BUILT_IN = [m for m in model_names() if get_model_entry(m).obj.__module__.startswith("tactile_zoo.models.")]
#: the built-ins with a `full` recipe (a model added later has none until its `zoo` cells declare one)
WITH_FULL = [m for m in BUILT_IN if "full" in get_model_entry(m).meta["recipes"]]


def declared_epochs(*folders: Path) -> dict[tuple[str, str], int]:
    """(model, dataset) -> the median epoch validation selected over the folders' ok cells, halves rounded up."""
    chosen: dict[tuple[str, str], list[int]] = {}
    for path in (p for folder in folders for p in cell_files(folder)):
        record = json.loads(read_cell_bytes(path))
        if record.get("status") == "ok" and record["config"].get("recipe_name") == "zoo":
            chosen.setdefault((record["model"], record["dataset"]), []).append(int(record["best_epoch"]))
    return {key: math.floor(statistics.median(epochs) + 0.5) for key, epochs in chosen.items()}


@pytest.mark.parametrize("model", WITH_FULL)
def test_full_trains_the_declared_epochs(model: str) -> None:
    rule = declared_epochs(ZOO, *DEEPTACTILE)
    meta = get_model_entry(model).meta
    for dataset in DATASETS:
        full = resolve_model_recipe(meta, "full", dataset)
        zoo = resolve_model_recipe(meta, "zoo", dataset)
        if (model, dataset) not in rule:  # no `zoo` cell declared a count there: `full` is `zoo` itself
            assert replace(full, name="zoo") == zoo, dataset
            continue
        assert full.recipe.max_epochs == rule[model, dataset], dataset
        assert full.evaluation == "final" and full.recipe.patience is None
        # everything else is the zoo recipe's: the model's and the dataset's settings, the optimiser
        assert (full.hparams, full.dataset_kwargs) == (zoo.hparams, zoo.dataset_kwargs)
        assert (full.recipe.lr, full.recipe.batch_size, full.recipe.optimizer) == \
            (zoo.recipe.lr, zoo.recipe.batch_size, zoo.recipe.optimizer)


def test_a_model_lacks_full_only_where_no_zoo_cell_could_declare_it() -> None:
    rule = declared_epochs(ZOO, *DEEPTACTILE)
    assert len(WITH_FULL) >= 7 and "deeptactile" in WITH_FULL
    for model in set(BUILT_IN) - set(WITH_FULL):
        assert not any(m == model for m, _ in rule), f"{model} has zoo cells: declare its `full` from them"


def test_the_rule_uses_several_seeds_never_one() -> None:
    counts: dict[tuple[str, str], int] = {}
    for path in cell_files(ZOO):
        record = json.loads(read_cell_bytes(path))
        if record.get("status") == "ok":
            counts[record["model"], record["dataset"]] = counts.get((record["model"], record["dataset"]), 0) + 1
    assert counts and min(counts.values()) >= 4
