"""Knowledge distillation in the engine (``tactile_zoo.engine.distill``): the loss, the teachers' probabilities, the
configuration's checks and hash, and a cell trained from teacher weight files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import save_file

from tactile_zoo.engine.build import build_model, load_splits
from tactile_zoo.engine.cell import train_cell
from tactile_zoo.engine.config import CellConfig, config_hash, resolve_cell
from tactile_zoo.engine.distill import distillation_loss, teacher_config, teacher_probabilities
from tactile_zoo.engine.tensors import as_split, concat, take
from tactile_zoo.engine.train import train_model
from tactile_zoo.errors import ConfigError, DatasetError
from tactile_zoo.recipe import Recipe

DISTIL = {"distill_weight": 0.7, "distill_temperature": 3.0, "max_epochs": 3, "patience": None}


def test_the_loss_is_the_weighted_sum_of_cross_entropy_and_the_tempered_kl_divergence() -> None:
    gen = torch.Generator().manual_seed(0)
    scores, teacher = torch.randn(5, 4, generator=gen), torch.randn(5, 4, generator=gen)
    y = torch.tensor([0, 1, 2, 3, 0])
    recipe = Recipe(distill_weight=0.25, distill_temperature=2.0, label_smoothing=0.1)
    soft = torch.softmax(teacher / 2.0, dim=-1)
    student = torch.softmax(scores / 2.0, dim=-1)
    # written out by hand: KL(p || q) = sum p (log p - log q), per sample, averaged over the batch
    kl = (soft * (soft.log() - student.log())).sum(-1).mean()
    expected = 0.75 * F.cross_entropy(scores, y, label_smoothing=0.1) + 0.25 * 4.0 * kl
    assert torch.allclose(distillation_loss(scores, y, soft, recipe), expected, atol=1e-6)
    # the student that already matches its teachers pays only the hard term
    same = distillation_loss(teacher, y, torch.softmax(teacher / 2.0, dim=-1), recipe)
    assert torch.allclose(same, 0.75 * F.cross_entropy(teacher, y, label_smoothing=0.1), atol=1e-6)


def test_the_teachers_probabilities_are_the_mean_of_their_tempered_softmaxes() -> None:
    split = as_split(load_splits("tiny_blobs")["val"])
    a, b = build_model("tiny_mlp", split.spec, {}, 1), build_model("tiny_mlp", split.spec, {}, 2)
    got = teacher_probabilities([a, b], split, 2.5)
    by_hand = []
    for model in (a, b):
        model.eval()
        with torch.no_grad():
            by_hand.append(torch.softmax(model(split.x, split.g) / 2.5, dim=-1))
    assert got.shape == (len(split), split.spec.num_classes)
    assert torch.allclose(got, (by_hand[0] + by_hand[1]) / 2, atol=1e-6)
    assert torch.allclose(got.sum(-1), torch.ones(len(split)), atol=1e-6)
    assert not torch.allclose(got, by_hand[0], atol=1e-3)  # both teachers count
    assert teacher_probabilities([a], take(split, 0), 1.0).shape == (0, split.spec.num_classes)


def test_distillation_is_off_by_default_and_leaves_every_hash_where_it_was() -> None:
    plain = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 3})
    assert "distill_weight" not in plain.recipe.to_dict() and "teachers" not in plain.hashed()
    student = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 3, "distill_weight": 0.5},
                           teacher_seeds=[2, 0])
    assert student.teacher_seeds == (0, 2) and student.hashed()["teachers"] == [0, 2]
    assert config_hash(teacher_config(student)) == config_hash(plain)  # the teachers are the plain cells
    other = resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 3, "distill_weight": 0.5}, teacher_seeds=[0])
    assert len({config_hash(plain), config_hash(student), config_hash(other)}) == 3
    assert CellConfig.from_dict(student.to_dict()) == student  # a record reads back to the same configuration


@pytest.mark.parametrize(("recipe", "seeds", "evaluation", "message"), [
    ({"distill_weight": 0.5}, [], None, "needs teachers"),
    ({}, [0, 1], None, "distill_weight is 0"),
    ({"distill_weight": 0.5}, [0], "reference", "not reference"),
    ({"distill_weight": 0.5}, [1, 1], None, "a seed twice"),
    ({"distill_weight": 0.5, "loss": "mse_rate"}, [0], None, "needs loss 'ce'"),
    ({"distill_weight": 1.5}, [0], None, "distill_weight must be <= 1"),
    ({"distill_weight": 0.5, "distill_temperature": 0.0}, [0], None, "distill_temperature must be a positive"),
])
def test_a_distillation_setting_that_cannot_work_is_refused_before_any_cell(
        recipe: dict, seeds: list[int], evaluation: str | None, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        resolve_cell("tiny_mlp", "tiny_blobs", recipe=recipe, teacher_seeds=seeds, evaluation=evaluation)


def test_a_split_without_teacher_probabilities_is_not_trained_on_as_if_it_had_them() -> None:
    splits = load_splits("tiny_blobs")
    train = as_split(splits["train"])
    model = build_model("tiny_mlp", train.spec, {}, 0)
    with pytest.raises(ConfigError, match="hold no teacher probabilities"):
        train_model(model, train, Recipe(**DISTIL), device="cpu", progress=False)
    soft = torch.full((len(train), train.spec.num_classes), 1 / train.spec.num_classes)
    with pytest.raises(DatasetError, match="only one holds teacher probabilities"):
        concat(replace(train, soft=soft), splits["val"])


def _teacher_files(tmp_path: Path, config: CellConfig, seeds: list[int]) -> list[Path]:
    """The weights of ``config``'s teachers, trained here as the bench would (its teacher configuration)."""
    files = []
    for seed in seeds:
        result = train_cell(teacher_config(config), seed=seed, measure=False)
        path = tmp_path / f"teacher{seed}.safetensors"
        save_file({k: v.contiguous() for k, v in result.fit.model.state_dict().items()}, str(path))
        files.append(path)
    return files


def test_a_student_trains_on_its_teachers_probabilities_and_they_change_what_it_learns(tmp_path: Path) -> None:
    student = resolve_cell("tiny_mlp", "tiny_blobs", recipe=DISTIL, teacher_seeds=[0, 1], evaluation="final")
    files = _teacher_files(tmp_path, student, [0, 1])
    a = train_cell(student, seed=5, measure=False, teachers=files)
    b = train_cell(student, seed=5, measure=False, teachers=files)
    plain = train_cell(teacher_config(student), seed=5, measure=False)
    losses = [[r["train_loss"] for r in cell.fit.curve] for cell in (a, b, plain)]
    assert losses[0] == losses[1]  # deterministic
    for key, value in a.fit.model.state_dict().items():
        assert torch.equal(value, b.fit.model.state_dict()[key]), key
    assert a.test_reads == 1 and a.n_train == plain.n_train  # final: train + val, both with probabilities
    assert losses[0] != losses[2]  # the teachers' term is in the loss the student minimises
    one = train_cell(student, seed=5, measure=False, teachers=files[:1] + files[:1])
    assert [r["train_loss"] for r in one.fit.curve] != losses[0]  # which teachers it learnt from matters


def test_teacher_files_must_match_the_cells_teachers(tmp_path: Path) -> None:
    student = resolve_cell("tiny_mlp", "tiny_blobs", recipe=DISTIL, teacher_seeds=[0, 1])
    (file,) = _teacher_files(tmp_path, student, [0])
    with pytest.raises(ConfigError, match="2 teacher seed"):
        train_cell(student, measure=False, teachers=[file])
    with pytest.raises(ConfigError, match="the cell has no teachers"):
        train_cell(teacher_config(student), measure=False, teachers=[file])
    wrong = tmp_path / "wrong.safetensors"
    save_file({"weight": torch.zeros(2, 2)}, str(wrong))
    with pytest.raises(ConfigError, match="do not fit tiny_mlp"):
        train_cell(student, measure=False, teachers=[file, wrong])


def test_fit_distils_from_probabilities_attached_to_a_split() -> None:
    from tactile_zoo.engine.api import fit

    splits = load_splits("tiny_blobs")
    train, val = as_split(splits["train"]), as_split(splits["val"])
    teachers = [train_cell(resolve_cell("tiny_mlp", "tiny_blobs", recipe={"max_epochs": 3}), seed=s,
                           measure=False).fit.model for s in (1, 2)]
    taught = replace(train, soft=teacher_probabilities(teachers, train, 2.0))
    recipe = {"max_epochs": 3, "distill_weight": 0.5, "distill_temperature": 2.0}
    a = fit("tiny_mlp", taught, recipe=recipe, val_dataset=val, device="cpu", progress=False)
    plain = fit("tiny_mlp", train, recipe={"max_epochs": 3}, val_dataset=val, device="cpu", progress=False)
    assert [r["train_loss"] for r in a.curve] != [r["train_loss"] for r in plain.curve]
    with pytest.raises(ConfigError, match="hold no teacher probabilities"):
        fit("tiny_mlp", train, recipe=recipe, val_dataset=val, device="cpu", progress=False)
