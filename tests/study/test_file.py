"""The study file's schema: every error names the file and the key, with exit 2 before any work."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from study_helpers import QUICKSTART, tz

from tactile_zoo.errors import ConfigError
from tactile_zoo.study import load_study


def _study(tmp_path: Path, edit: dict) -> Path:
    data = yaml.safe_load(QUICKSTART.read_text())
    for dotted, value in edit.items():
        *parents, key = dotted.split(".")
        target = data
        for part in parents:
            target = target[int(part)] if isinstance(target, list) else target[part]
        if value is None:
            del target[key]
        else:
            target[key] = value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("edit", "named"), [
    ({"colour": "blue"}, "colour is not a known key"),
    ({"question": None}, "question is required"),
    ({"grids": []}, "grids must hold at least 1 item(s), got []"),
    ({"rules.budget_cpu_hours": -1.0}, "rules.budget_cpu_hours must be a positive number, got -1.0"),
    ({"grids.0.settings.epochs": 0}, "grids[0].settings.epochs must be an integer >= 1, got 0"),
    ({"grids.0.settings.epoch": 1}, "grids[0].settings.epoch is not a known key"),
    ({"grids.0.settings.recipe": {"lr": -1.0}}, "grids.main.settings: recipe: lr must be a positive number, got -1.0"),
    ({"grids.0.settings.force": True}, "grids.main.settings.force: not a study setting"),
    ({"grids.0.settings.out": "elsewhere"}, "grids.main.settings.out: not a study setting"),
    ({"reads.ensembles.0.members": [{"model": "sgnet"}]},
     "reads.ensembles.cnn_lstm_ens2: model 'sgnet' is not a model of grid main"),
    ({"reads.ensembles.0.members": [{"model": "cnn_lstm", "seeds": [0, 7]}]},
     "reads.ensembles.cnn_lstm_ens2.members[0].seeds [7] are not seeds of grid main"),
    ({"reads.comparisons.0.dataset": "sim_biotac_slip"},
     "reads.comparisons.dcnn_vs_cnn_lstm.dataset 'sim_biotac_slip' is not a dataset of grid main"),
    ({"reads.thresholds.0.read": "nothing"}, "reads.thresholds.ensemble_above_chance.read 'nothing' names no"),
    ({"reads.thresholds.0.statistic": "p_value"},
     "reads.thresholds.ensemble_above_chance.statistic 'p_value': a ensemble gives accuracy, low, high"),
    ({"reads.thresholds.0.below": 0.5}, "reads.thresholds[0]: give exactly one of at_least and below"),
    ({"rules.test_split": "sometimes"}, "rules.test_split must be one of once, never, got 'sometimes'"),
    ({"grids.0.name": "main grid"}, "grids[0].name "),
    ({"rules.test_split": "never"}, "rules.test_split is 'never' (a tuning study): set evaluation: tuning"),
])
def test_an_error_names_the_file_and_the_key(tmp_path: Path, edit: dict, named: str) -> None:
    path = _study(tmp_path, edit)
    with pytest.raises(ConfigError) as info:
        load_study(path)
    assert str(info.value).startswith(f"{path}: "), info.value
    assert named in str(info.value), info.value


def test_the_command_line_says_it_in_one_line_with_exit_2(tmp_path: Path) -> None:
    path = _study(tmp_path, {"grids.0.settings.seeds": "banana"})
    code, out, err = tz("study", "check", str(path))
    assert code == 2 and out == ""
    assert err.startswith(f"tactile-zoo: error: {path}: grids.main.settings") and len(err.strip().splitlines()) == 1
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    code, _, err = tz("study", "audit", str(tmp_path / "list.yaml"))
    assert code == 2 and "the top level must be a mapping" in err


def test_a_tuning_study_accepts_tuning_grids(tmp_path: Path) -> None:
    path = _study(tmp_path, {"rules.test_split": "never", "grids.0.settings.evaluation": "tuning", "reads": {}})
    assert load_study(path).rules().test_split == "never"
