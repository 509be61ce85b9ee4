"""``--evaluation final`` and recipes that declare it (``full``): every training recording, a fixed epoch count
declared beforehand, nothing selected, the test split read once at the end."""

from __future__ import annotations

import pytest
import torch

from tactile_zoo.engine.build import build_model, load_splits
from tactile_zoo.engine.cell import train_cell
from tactile_zoo.engine.config import config_hash, resolve_cell
from tactile_zoo.engine.tensors import concat
from tactile_zoo.engine.train import train_model
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import register_model
from tactile_zoo.registry.entries import _unregister


def test_final_trains_on_train_and_val_for_every_epoch_and_reads_the_test_split_once() -> None:
    honest = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 5, "patience": 1})
    final = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 5, "patience": 1}, evaluation="final")
    a, b = train_cell(honest, seed=3, measure=False), train_cell(final, seed=3, measure=False)
    assert b.n_train == a.n_train + a.n_val and b.n_val == 0 and b.fit.val is None
    assert b.fit.epochs_run == 5 and b.fit.best_epoch == 5  # patience is off and nothing is selected
    assert b.test_reads == 1 and b.reference is None
    # the same training as the loop on train + val with the same seed: the final cell adds nothing of its own
    splits = load_splits("tiny_blobs")
    model = build_model("tiny_mlp", splits["train"].spec, {}, 3)
    loop = train_model(model, concat(splits["train"], splits["val"]), recipe=final.recipe.replace(patience=None),
                       seed=3, device="cpu")
    for key, value in loop.model.state_dict().items():
        assert torch.equal(value, b.fit.model.state_dict()[key]), key


def test_final_gets_its_own_hash_and_refuses_refit() -> None:
    final = resolve_cell("tiny_mlp", "tiny_blobs", evaluation="final")
    assert final.hashed()["evaluation"] == "final"
    assert config_hash(final) != config_hash(resolve_cell("tiny_mlp", "tiny_blobs"))
    with pytest.raises(ConfigError, match="does not combine with --refit"):
        resolve_cell("tiny_mlp", "tiny_blobs", evaluation="final", refit=True)


def test_a_recipe_declares_its_evaluation_and_the_user_still_wins() -> None:
    import tiny_zoo

    # a subclass: registering sets the class's own metadata, which tiny_mlp's class must keep
    register_model("zt_final_model", paper="-", year=2026, inputs=[], default_recipe="zoo",
                   recipes={"zoo": {"loss": "ce", "max_epochs": 4},
                            "full": {"loss": "ce", "max_epochs": 3, "patience": None, "evaluation": "final"}},
                   )(type("ZtFinal", (tiny_zoo.TinyMLP,), {}))
    try:
        assert resolve_cell("zt_final_model", "tiny_blobs").evaluation == "validation"
        full = resolve_cell("zt_final_model", "tiny_blobs", recipe_name="full")
        assert full.evaluation == "final" and full.recipe.max_epochs == 3 and full.recipe_name == "full"
        assert resolve_cell("zt_final_model", "tiny_blobs", recipe_name="full", evaluation="tuning").evaluation \
            == "tuning"
    finally:
        _unregister("model", "zt_final_model")


@pytest.mark.parametrize("bad", [{"evaluation": "reference"}, {"evaluation": "best"},
                                 {"datasets": {"tiny_blobs": {"evaluation": "tuning"}}}])
def test_a_recipe_cannot_declare_a_test_reading_evaluation(bad: dict) -> None:
    import tiny_zoo

    with pytest.raises(ConfigError, match="evaluation"):
        register_model("zt_bad_eval", paper="-", year=2026, inputs=[],
                       recipes={"zoo": {"loss": "ce", **bad}})(type("ZtBad", (tiny_zoo.TinyMLP,), {}))


def test_a_dataset_section_declares_its_own_evaluation() -> None:
    """A fixed budget declared for one dataset does not travel to another: elsewhere the recipe selects on val."""
    import tiny_zoo

    register_model("zt_section_eval", paper="-", year=2026, inputs=[], default_recipe="full",
                   recipes={"full": {"loss": "ce", "max_epochs": 6, "patience": 2,
                                     "datasets": {"tiny_blobs": {"max_epochs": 3, "patience": None,
                                                                 "evaluation": "final"}}}}
                   )(type("ZtSection", (tiny_zoo.TinyMLP,), {}))
    try:
        declared = resolve_cell("zt_section_eval", "tiny_blobs")
        assert declared.evaluation == "final" and declared.recipe.max_epochs == 3
        elsewhere = resolve_cell("zt_section_eval", "tiny_kfold")
        assert elsewhere.evaluation == "validation" and elsewhere.recipe.patience == 2
        assert resolve_cell("zt_section_eval", "tiny_blobs", evaluation="validation").evaluation == "validation"
    finally:
        _unregister("model", "zt_section_eval")
