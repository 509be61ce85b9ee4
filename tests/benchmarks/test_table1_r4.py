"""Table I, round 4 (``tools/table1_r4.py``) and the headline's pooling of ``full``'s two rounds: seeds 5-9 beside
seeds 0-4, the pooled ten, the declared ensembles over seeds 5-9 only, the cross-model ensemble, one CPU type; from
synthetic cell records, and the committed block is what the committed cells give."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from seed_probabilities import one_wrong_each

from tactile_zoo import registry
from tools import table1_r4 as r4
from tools.table1_common import MODELS

TARGETS = [0, 1, 2, 0, 1]  # five test samples, one test set for every cell


def _cell(folder: Path, model: str, seed: int, accuracy: float, dataset: str = "ev_objects",
          probabilities: list[list[float]] | None = None, predictions: list[int] | None = None,
          cpu: str = "AMD EPYC", config_hash: str = "h", seconds: float = 1800.0) -> dict:
    """One ok, current ``full`` cell (``--evaluation final``) written to ``folder/cells``."""
    split = "test_textures" if dataset == "biotac_dos" else "test"
    right = round(accuracy * len(TARGETS))
    predictions = predictions or [t if i < right else (t + 1) % 3 for i, t in enumerate(TARGETS)]
    stored = {"targets": TARGETS, "predictions": predictions,
              **({"probabilities": probabilities} if probabilities is not None else {})}
    record = {"cell_id": f"{model}__{dataset}__f0__s{seed}__{config_hash}", "model": model, "dataset": dataset,
              "fold": 0, "seed": seed, "status": "ok", "config_hash": config_hash, "train_seconds": seconds,
              "seconds": seconds, "epochs_run": 1, "best_epoch": 1, "n_test": len(TARGETS), "cpu": cpu,
              "cpu_isa": {"capability": "AVX512"},
              "metrics": {"test": {"accuracy": accuracy}, split: {"accuracy": accuracy}},
              "predictions": {"test": stored, split: stored},
              "config": {"model_revision": registry.revision_of(registry.get_model_entry(model)),
                         "dataset_revision": registry.revision_of(registry.get_dataset_entry(dataset)),
                         "recipe_name": "full", "evaluation": "final"}}
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    (folder / "cells" / f"{record['cell_id']}.json").write_text(json.dumps(record))
    return record


def _rows(text: str, title: str) -> dict[str, str]:
    block = text.split(f"**{title}")[1].split("\n\n**")[0]
    return {line.split(" | ")[0].lstrip("| "): line for line in block.splitlines() if line.startswith("| ")}


def test_seeds_5_9_pool_with_round_3_and_their_ensemble_reads_only_seeds_5_9(tmp_path: Path) -> None:
    old, new = tmp_path / "paper-table1-full", tmp_path / "paper-table1-full-r4"
    for seed in range(5):  # round 3: confidently wrong everywhere; in the round-4 ensemble they would sink it
        _cell(old, "x_tacformer", seed, 0.0, probabilities=[[1.0 if c == (t + 1) % 3 else 0.0 for c in range(3)]
                                                            for t in TARGETS])
    for seed in range(5, 10):  # round 4: each seed wrong on one sample, their mean right on all five
        probabilities, predictions = one_wrong_each(TARGETS, seed - 5)
        _cell(new, "x_tacformer", seed, 0.8, probabilities=probabilities, predictions=predictions)
    rows = _rows(r4.table(*r4.load(old, new)), "Seeds 5-9 of `full` on Ev-Objects")
    row = rows["X-Tacformer"].split(" | ")
    assert row[2].startswith("0.0000 ± 0.000 [") and row[2].endswith("(5)")
    assert row[3].startswith("0.8000 ± 0.000 [") and row[3].endswith("(5)")
    assert row[4].startswith("0.4000 ± 0.422 [") and row[4].endswith("(10)")  # ten seeds
    assert row[5] == "1.0000 [1.000, 1.000] |"
    assert rows["SGnet"].endswith("| not run yet | not run yet | when seeds 5-9 are in | 0 of 5 members so far |")
    # four of five round-4 seeds: no pooled figure and no ensemble yet, not a four-seed one
    (new / "cells" / "x_tacformer__ev_objects__f0__s9__h.json").unlink()
    row = _rows(r4.table(*r4.load(old, new)), "Seeds 5-9 of `full` on Ev-Objects")["X-Tacformer"]
    assert row.endswith("| when seeds 5-9 are in | 4 of 5 members so far |")


def test_the_cross_model_ensemble_averages_the_six_seed_5_cells_with_equal_weights(tmp_path: Path) -> None:
    new = tmp_path / "paper-table1-full-r4"
    for i, model in enumerate(MODELS):  # models 0-4 each wrong on one sample; D-CNN right everywhere but unsure
        if i < 5:
            probabilities, predictions = one_wrong_each(TARGETS, i)
        else:
            probabilities, predictions = [[0.4 if c == t else 0.3 for c in range(3)] for t in TARGETS], TARGETS
        _cell(new, model, 5, 0.8 if i < 5 else 1.0, probabilities=probabilities, predictions=predictions)
        _cell(new, model, 6, 0.2)  # another seed: not a member
    text = r4.table(*r4.load(tmp_path / "none", new))
    rows = _rows(text, "The cross-model ensemble")
    assert rows["Ev-Objects"] == "| Ev-Objects | D-CNN 1.0000 | 0.8333 | 1.0000 [1.000, 1.000] |"
    assert rows["Ev-Containers"] == "| Ev-Containers | - | - | 0 of 6 members so far |"
    assert "on Ev-Objects the best declared ensemble is `all6_full_seed5` at 1.0000 (target 0.93: met)" in text
    (new / "cells" / "dcnn__ev_objects__f0__s5__h.json").unlink()
    assert _rows(r4.table(*r4.load(tmp_path / "none", new)), "The cross-model ensemble")["Ev-Objects"].endswith(
        "| 5 of 6 members so far |")


def test_cost_counts_the_round_4_cells_against_the_budget(tmp_path: Path) -> None:
    new = tmp_path / "paper-table1-full-r4"
    for seed in range(5, 8):
        _cell(new, "sgnet", seed, 0.8, seconds=3600.0)
    _cell(new, "tacformer", 5, 0.8, dataset="biotac_dos", seconds=1800.0)
    assert r4.cost(r4.load(tmp_path / "none", new)[1]) == (
        "Seeds 5-9 cost 3.50 CPU-hours for 4 of the 90 planned runs (Ev-Objects 3.00, Ev-Containers 0.00, BioTac-DoS "
        "(textures) 0.50; the cells' own times, one torch thread each, two at a time), of the round's budget of 16. "
        "CPU: AMD EPYC (AVX512).")


def test_two_cpu_types_or_two_configurations_stop_the_pooling(tmp_path: Path) -> None:
    import tools.headline as hl

    old, new = tmp_path / "paper-table1-full", tmp_path / "paper-table1-full-r4"
    _cell(old, "sgnet", 0, 0.8)
    _cell(new, "sgnet", 5, 0.8, config_hash="other")
    with pytest.raises(SystemExit, match="round 4's configuration other is not round 3's h"):
        r4.table(*r4.load(old, new))
    (new / "cells" / "sgnet__ev_objects__f0__s5__other.json").unlink()
    _cell(new, "sgnet", 5, 0.8, cpu="Intel Xeon")
    with pytest.raises(SystemExit, match=r"cells of 2 CPU types \(AMD EPYC \(AVX512\); Intel Xeon \(AVX512\)\)"):
        r4.table(*r4.load(old, new))
    # the headline pools both folders' `full` cells, and refuses two CPU types the same way
    with pytest.raises(SystemExit, match="`full` cells of 2 CPU types"):
        hl.recipe_cells(tmp_path / "paper-table1", "full")
    (new / "cells" / "sgnet__ev_objects__f0__s5__h.json").unlink()
    _cell(new, "sgnet", 5, 0.8)
    assert sorted(r["seed"] for r in hl.recipe_cells(tmp_path / "paper-table1", "full")) == [0, 5]


def test_the_committed_round_4_block_is_what_the_cells_give() -> None:
    assert r4.main(["--check"]) == 0, "run python -m tools.table1_r4 --readme and commit docs/table1.md"
