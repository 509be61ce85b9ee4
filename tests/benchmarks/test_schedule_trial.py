"""The schedule trial's outcome (``tools/schedule_trial.py``): each cell is matched to its arm by what it trained,
the rule reads the validation accuracy at epoch N, and a cell outside the plan stops the tool; synthetic cells."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tactile_zoo.bench.records import InvalidCellsError
from tools import schedule_trial as st


def _cell(folder: Path, model: str, dataset: str, seed: int, arm: str, final: float, best: float = 0.99,
          cpu: str = "AMD EPYC", **recipe_changes: object) -> None:
    """An ok tuning cell of ``arm`` whose validation accuracy is ``final`` at epoch N and ``best`` at epoch 1 (so a
    tool reading the best epoch instead of the last gets other numbers)."""
    epochs = st.EPOCHS[model][dataset]
    schedule = st.registered_schedule(model) if arm == "registered" else st.scaled_schedule(model, epochs)
    recipe = {"schedule": schedule, "max_epochs": epochs, "patience": None, **recipe_changes}
    curve = [{"epoch": e, "val_accuracy": best if e == 1 else 0.5} for e in range(1, epochs)]
    curve.append({"epoch": epochs, "val_accuracy": final})
    config_hash = f"{arm}{len(recipe_changes)}"
    record = {"cell_id": f"{model}__{dataset}__f0__s{seed}__{config_hash}", "model": model, "dataset": dataset,
              "fold": 0, "seed": seed, "config_hash": config_hash, "status": "ok", "test_reads": 0,
              "epochs_run": epochs, "best_epoch": 1, "metrics": {"val": {"accuracy": best}},
              "train_seconds": 360.0, "cpu": cpu, "cpu_isa": {"capability": "AVX512"}, "curve": curve,
              "config": {"recipe": recipe, "evaluation": "tuning", "recipe_name": "zoo"}}
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    (folder / "cells" / f"{record['cell_id']}.json").write_text(json.dumps(record))


def _trial(folder: Path, gains: dict[tuple[str, str], float]) -> None:
    for model, per_dataset in st.EPOCHS.items():
        for dataset in per_dataset:
            for seed in st.SEEDS:
                _cell(folder, model, dataset, seed, "registered", 0.80)
                _cell(folder, model, dataset, seed, "scaled", 0.80 + gains.get((model, dataset), 0.0))


def test_the_rule_reads_epoch_n_and_needs_both_datasets(tmp_path: Path) -> None:
    _trial(tmp_path, {("sgnet", "ev_objects"): 0.02, ("sgnet", "ev_containers"): 0.05,
                      ("tacformer", "ev_objects"): 0.05, ("tacformer", "ev_containers"): 0.025,
                      ("x_tacformer", "ev_objects"): -0.01, ("x_tacformer", "ev_containers"): 0.1})
    arms = st.read_arms(tmp_path)
    assert len(arms) == 12 and {a.accuracies for a in arms if a.arm == "registered"} == {(0.80, 0.80, 0.80)}
    result = st.verdicts(arms)
    assert result["sgnet"][0] is True  # +0.02 >= 0.019 and +0.05 >= 0.05 (the threshold itself adopts)
    assert result["tacformer"][0] is False  # Ev-Containers +0.025 < 0.05
    assert result["x_tacformer"][0] is False
    assert result["sgnet"][1]["ev_objects"] == pytest.approx(0.02)
    text = st.render(arms)
    assert "- sgnet: adopted for the next round" in text and "- tacformer: not adopted" in text
    assert "CPU-hours (training, 36 cells): 3.60" in text


@pytest.mark.parametrize("change, message", [
    ({"max_epochs": 30}, "max_epochs 30"),
    ({"patience": 10}, "patience 10"),
    ({"schedule": {"type": "cosine", "eta_min": 0.0, "t_max": None}}, "neither arm's"),
])
def test_a_cell_that_trained_something_else_stops_the_tool(tmp_path: Path, change: dict, message: str) -> None:
    """The trap the plan's appendix names: zoo's cosine with t_max unset follows max_epochs, so a registered-arm cell
    run without the pinned t_max trained the scaled arm's schedule; it must not be counted as registered."""
    _trial(tmp_path, {})
    _cell(tmp_path, "tacformer", "ev_objects", 1, "registered", 0.8, **change)
    with pytest.raises(st.TrialError, match=message):
        st.read_arms(tmp_path)


def test_missing_seeds_tuning_reads_and_two_cpu_types_are_errors(tmp_path: Path) -> None:
    _trial(tmp_path, {})
    (tmp_path / "cells" / "sgnet__ev_containers__f0__s2__scaled0.json").unlink()
    with pytest.raises(st.TrialError, match=r"sgnet x ev_containers, scaled: seeds \[2\] missing"):
        st.read_arms(tmp_path)
    _cell(tmp_path, "sgnet", "ev_containers", 2, "scaled", 0.8, cpu="Intel Xeon")
    with pytest.raises(st.TrialError, match="2 CPU types"):
        st.read_arms(tmp_path)
    _cell(tmp_path, "sgnet", "ev_containers", 2, "scaled", 0.8)
    path = tmp_path / "cells" / "sgnet__ev_containers__f0__s2__scaled0.json"
    record = json.loads(path.read_text())
    record["test_reads"] = 1
    path.write_text(json.dumps(record))
    with pytest.raises(st.TrialError, match="not a tuning cell"):
        st.read_arms(tmp_path)


def test_a_damaged_cell_file_stops_the_tool_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A truncated cell file is not skipped: an arm would silently lose a seed's number."""
    _trial(tmp_path, {})
    path = tmp_path / "cells" / "tacformer__ev_objects__f0__s1__scaled0.json"
    path.write_text(path.read_text()[:200])
    with pytest.raises(InvalidCellsError, match=r"tacformer__ev_objects__f0__s1__scaled0\.json: not valid JSON"):
        st.read_arms(tmp_path)
    with pytest.raises(SystemExit) as exited:
        st.main(["--folder", str(tmp_path)])
    assert exited.value.code == 2 and "s1__scaled0.json: not valid JSON" in capsys.readouterr().err
