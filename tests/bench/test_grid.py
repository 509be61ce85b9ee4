from __future__ import annotations

from pathlib import Path

import pytest

from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.grid import build_grid, cell_id, default_out_dir, resolve_models
from tactile_zoo.engine.config import config_hash
from tactile_zoo.errors import ConfigError, UnknownNameError


def _grid(tmp_path: Path, **kw: object):
    kw.setdefault("root", str(tmp_path / "data"))
    return build_grid(BenchConfig(**kw))


def test_names_lists_wildcards_and_all() -> None:
    assert resolve_models(["tiny_mlp,tiny_rate", "tiny_mlp"]) == ["tiny_mlp", "tiny_rate"]
    assert resolve_models(["Tiny-MLP"]) == ["tiny_mlp"]  # normalised like every lookup
    assert {"tiny_broken", "tiny_nan", "tiny_mlp"} <= set(resolve_models(["tiny_*"]))
    assert set(resolve_models(["tiny_*"])) <= set(resolve_models(["all"]))
    with pytest.raises(UnknownNameError, match="Did you mean 'tiny_mlp'"):
        resolve_models(["tiny_mpl"])
    with pytest.raises(UnknownNameError, match="matches no registered model"):
        resolve_models(["nothing_*"])


def test_cells_cover_models_folds_seeds_in_dataset_major_order(tmp_path: Path) -> None:
    grid = _grid(tmp_path, models=["tiny_mlp", "tiny_rate"], datasets=["tiny_blobs", "tiny_kfold"], seeds=[0, 1])
    assert len(grid.cells) == 2 * 2 * (1 + 3)  # models x seeds x (fixed split + 3 folds)
    kfold = [c for c in grid.cells if c.dataset == "tiny_kfold"]
    assert sorted({c.fold for c in kfold}) == [0, 1, 2] and all(c.protocol == "kfold" for c in kfold)
    assert [c.dataset for c in grid.cells] == sorted(c.dataset for c in grid.cells)
    assert grid.cells[0].extra_splits == ("test_shifted",)
    assert len({c.cell_id for c in grid.cells}) == len(grid.cells)
    limited = _grid(tmp_path, models=["tiny_mlp"], datasets=["tiny_kfold"], folds=2)
    assert [c.fold for c in limited.cells] == [0, 1]
    big = _grid(tmp_path, models=["tiny_mlp"], datasets=["tiny_kfold"], folds=10)  # more than defined: all 3
    assert [c.fold for c in big.cells] == [0, 1, 2]


def test_absent_and_broken_datasets_are_skipped_with_reason_and_how_to_obtain(tmp_path: Path) -> None:
    grid = _grid(tmp_path, models=["tiny_mlp", "tiny_rate"], datasets=["tiny_*"])
    assert {d.name for d in grid.datasets} == {"tiny_blobs", "tiny_kfold"}
    assert set(grid.dataset_notes) == {"tiny_absent", "tiny_missing"}
    assert "copy the tiny files" in grid.dataset_notes["tiny_absent"]
    assert str(tmp_path / "data") in grid.dataset_notes["tiny_absent"]
    assert "data server is unreachable" in grid.dataset_notes["tiny_missing"]
    assert {(s.model, s.dataset) for s in grid.skipped} == {(m, d) for m in ("tiny_mlp", "tiny_rate")
                                                            for d in ("tiny_absent", "tiny_missing")}
    text = "\n".join(grid.describe())
    assert "skipped dataset tiny_absent" in text and "skipped dataset tiny_missing" in text


def test_bad_dataset_kwargs_and_recipe_overrides_fail_before_running(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"recipe: unknown recipe key\(s\) \['bogus'\]"):  # as the settings are read
        _grid(tmp_path, models=["tiny_mlp"], datasets=["tiny_blobs"], recipe={"bogus": 1})
    with pytest.raises(ConfigError, match="augment_factor"):
        _grid(tmp_path, models=["tiny_mlp"], datasets=["tiny_blobs"],
              dataset_kwargs={"tiny_blobs": {"augment_factor": 0}})
    with pytest.raises(ConfigError, match=r"tiny_blobs.*keyword argument.*\['bogus'\]"):
        _grid(tmp_path, models=["tiny_mlp"], datasets=["tiny_blobs"], dataset_kwargs={"*": {"bogus": 1}})


BASE = {"models": ["tiny_mlp"], "datasets": ["tiny_blobs"]}
CHANGES = [{"recipe": {"lr": 0.02}}, {"recipe": {"batch_size": 8}}, {"recipe": {"patience": None}},
           {"recipe": {"schedule": "cosine"}}, {"recipe": {"weight_decay": 1e-4}}, {"recipe": {"amsgrad": True}},
           {"recipe": {"optimizer": "sgd"}}, {"recipe": {"grad_clip": 1.0}}, {"recipe": {"monitor": "val_loss"}},
           {"epochs": 3}, {"hparams": {"hidden": 8}}, {"model_overrides": {"tiny_mlp": {"hparams": {"dropout": 0.2}}}},
           {"dataset_kwargs": {"tiny_blobs": {"seed": 1}}}, {"dataset_kwargs": {"*": {"n_train": 12}}},
           {"refit": True}, {"quick": True}, {"prefixes": [0.5]}]


@pytest.mark.parametrize("change", CHANGES, ids=[str(c) for c in CHANGES])
def test_config_hash_changes_with_every_setting(tmp_path: Path, change: dict) -> None:
    base = _grid(tmp_path, **BASE).cells[0]
    again = _grid(tmp_path, **BASE).cells[0]
    other = _grid(tmp_path, **{**BASE, **change}).cells[0]
    assert base.config_hash == again.config_hash
    assert other.config_hash != base.config_hash and other.cell_id != base.cell_id


def test_hash_ignores_how_and_where_cells_run(tmp_path: Path) -> None:
    base = _grid(tmp_path, **BASE).cells[0].config_hash
    for change in ({"device": "cpu"}, {"threads": 1}, {"executor": "process", "workers": 2}, {"seeds": [0, 5]},
                   {"out": "elsewhere"}, {"force": True}):
        assert _grid(tmp_path, **{**BASE, **change}).cells[0].config_hash == base
    assert config_hash({"a": 1, "b": 2}) == config_hash({"b": 2, "a": 1})


def test_default_out_dir_is_stable_and_depends_on_the_grid(tmp_path: Path) -> None:
    cfg = BenchConfig(**BASE, root=str(tmp_path))
    one = default_out_dir(cfg, build_grid(cfg))
    assert one == default_out_dir(cfg, build_grid(BenchConfig(**BASE, root=str(tmp_path))))
    assert one.parent == Path("tactile-zoo-results") and one.name.startswith("tiny_mlp_tiny_blobs_")
    seeds = BenchConfig(**BASE, root=str(tmp_path), seeds=[0, 1])
    lr = BenchConfig(**BASE, root=str(tmp_path), recipe={"lr": 0.5})
    assert len({one, default_out_dir(seeds, build_grid(seeds)), default_out_dir(lr, build_grid(lr))}) == 3
    every = BenchConfig(models=["all"], datasets=["tiny_blobs"], root=str(tmp_path))
    assert default_out_dir(every, build_grid(every)).name.startswith("all-models_tiny_blobs_")


def test_cell_ids_are_file_names() -> None:
    assert cell_id("my-dist:tcn", "ds", 1, 2, "abc") == "my-dist-tcn__ds__f1__s2__abc"


def test_a_dataset_epoch_budget_caps_recipes_unless_epochs_are_given(tmp_path: Path) -> None:
    from tactile_zoo.data.datasets._simulator import SIM_EPOCH_BUDGET

    grid = _grid(tmp_path, models=["sgnet", "tiny_mlp"], datasets=["sim_biotac_slip", "tiny_blobs"])
    recipes = {(c.model, c.dataset): c.config.recipe.to_dict() for c in grid.cells}
    sgnet_sim = recipes[("sgnet", "sim_biotac_slip")]
    assert sgnet_sim["max_epochs"] == SIM_EPOCH_BUDGET < 100
    budget = SIM_EPOCH_BUDGET
    assert sgnet_sim["schedule"]["milestones"] == [round(40 * budget / 100), round(80 * budget / 100)]
    assert recipes[("tiny_mlp", "tiny_blobs")]["max_epochs"] == 8  # a dataset without a budget keeps the recipe's
    explicit = _grid(tmp_path, models=["sgnet"], datasets=["sim_biotac_slip"], epochs=40)
    assert explicit.cells[0].config.recipe.max_epochs == 40  # --epochs wins over the budget
