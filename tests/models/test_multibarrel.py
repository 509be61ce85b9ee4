"""The multi-barrel SNN's options for the released code's quirks (the `source` recipe turns them on): BatchNorm frozen
after the first training pass, noise and a random start at test time, softmax scores; and the recipes that declare
them. Small sizes throughout (a 3-step read-out, 3-tap convolutions), on the tiny spec of the zoo-wide tests."""

from __future__ import annotations

import pytest
import torch
from test_zoo import make_batch, make_spec

import tactile_zoo as tz
from tactile_zoo.engine.config import resolve_model_recipe
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import get_model_entry

SMALL = {"channels": 8, "kernel_size": 3, "dilation": 1, "readout_channels": 6, "readout_kernel": 2, "hidden": 5,
         "gate_hidden": 7}


def _model(**hparams) -> torch.nn.Module:
    torch.manual_seed(0)
    return tz.create_model("multibarrel", make_spec("neutouch"), **SMALL, **hparams)


def _bn(model: torch.nn.Module) -> list[torch.nn.Module]:
    return [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]


def test_batchnorm_freezes_after_the_first_training_pass_and_stays_frozen() -> None:
    model = _model(bn_train_steps=1).train()
    x, g, _ = make_batch(model.spec, 4, seed=1)
    stats = [m.running_mean.clone() for m in _bn(model)]
    model(x, g)
    after_first = [m.running_mean.clone() for m in _bn(model)]
    assert all(not torch.equal(a, b) for a, b in zip(stats, after_first))  # the first pass trains BatchNorm
    model.eval()
    model.train()  # what the training loop does every epoch: BatchNorm must stay in eval mode (the source's quirk)
    assert model.training and not any(m.training for m in _bn(model))
    model(x, g)
    assert all(torch.equal(a, m.running_mean) for a, m in zip(after_first, _bn(model)))
    restored = _model(bn_train_steps=1)
    restored.load_state_dict(model.state_dict())  # a checkpoint remembers the freeze
    restored.train()
    restored(x, g)
    assert not any(m.training for m in _bn(restored))


def test_batchnorm_trains_as_usual_by_default() -> None:
    model = _model().train()
    x, g, _ = make_batch(model.spec, 4, seed=1)
    model(x, g)
    first = [m.running_mean.clone() for m in _bn(model)]
    model(x, g)
    assert all(m.training for m in _bn(model)) and "bn_steps_seen" not in model.state_dict()
    assert all(not torch.equal(a, m.running_mean) for a, m in zip(first, _bn(model)))


def test_test_time_noise_is_an_option() -> None:
    x, g, _ = make_batch(make_spec("neutouch"), 3, seed=2)
    quiet, noisy = _model().eval(), _model(eval_noise=True).eval()
    with torch.no_grad():
        assert torch.equal(quiet(x, g), quiet(x, g))
        assert not torch.equal(noisy(x, g), noisy(x, g))  # the source's random start and membrane noise


def test_softmax_output_and_the_recipes_that_declare_the_quirks() -> None:
    x, g, _ = make_batch(make_spec("neutouch"), 3, seed=2)
    probs = _model(output="softmax").eval()(x, g)
    torch.testing.assert_close(probs.sum(dim=1), torch.ones(3))
    meta = get_model_entry("multibarrel").meta
    assert meta["default_recipe"] == "zoo" and set(meta["recipes"]) == {"source", "zoo"}
    source, zoo = resolve_model_recipe(meta, "source", "ev_objects"), resolve_model_recipe(meta, "zoo", "ev_objects")
    assert source.hparams == {"output": "softmax", "bn_train_steps": 1, "eval_noise": True} and zoo.hparams == {}
    assert source.evaluation == "final" and source.recipe.max_epochs == zoo.recipe.max_epochs == 200
    assert source.recipe.batch_size == 600 and source.recipe.optimizer == "adamw"


def test_short_inputs_are_padded_and_bad_settings_are_one_clear_error() -> None:
    model = _model()
    assert model.min_steps == (2 + 2 - 1) * 2 + 2 + 1  # two read-out steps after two 3-tap convolutions
    x, g, _ = make_batch(model.spec, 2, seed=3)
    assert model(x[:, :1], g[:, :1]).shape == (2, 5)
    with pytest.raises(ConfigError, match="output must be one of logits, softmax"):
        _model(output="probs")
    with pytest.raises(ConfigError, match="bn_train_steps must be >= 0"):
        _model(bn_train_steps=-1)


def test_a_source_recipe_cell_trains() -> None:
    train = tz.load_dataset("sim_evtouch", split="train", n_train_per_class=2, n_test_per_class=1, num_steps=20)
    # a split object, not a dataset name: the recipe's training keys apply, its hparams are given here
    result = tz.fit("multibarrel", train, recipe="source", epochs=2, hparams={**SMALL, "bn_train_steps": 1})
    assert result.epochs_run == 2 and int(result.model.bn_steps_seen) == 2  # one batch per epoch, as released
    assert not any(m.training for m in _bn(result.model.train()))


def test_the_zoo_recipe_runs_the_batch_of_600_in_micro_batches_on_real_data_only() -> None:
    meta = get_model_entry("multibarrel").meta
    for dataset in ("ev_objects", "ev_containers", "biotac_dos"):
        assert resolve_model_recipe(meta, "zoo", dataset).recipe.micro_batch_size == 120
        assert resolve_model_recipe(meta, "source", dataset).recipe.micro_batch_size is None  # one batch, as released
    for dataset in ("sim_evtouch", "sim_biotac_slip", "sim_uskin_textures"):  # batch 16: their hashes as before
        assert "micro_batch_size" not in resolve_model_recipe(meta, "zoo", dataset).recipe.to_dict()


def test_micro_batches_count_as_training_passes_for_the_batchnorm_freeze() -> None:
    """What the model card warns of: ``bn_train_steps`` counts forward passes, so each micro-batch is one."""
    train = tz.load_dataset("sim_evtouch", split="train", n_train_per_class=2, n_test_per_class=1, num_steps=20)
    result = tz.fit("multibarrel", train, recipe={"batch_size": 600, "micro_batch_size": 4, "max_epochs": 1},
                    hparams={**SMALL, "bn_train_steps": 3})
    assert len(train) == 10 and int(result.model.bn_steps_seen) == 3  # 10 in micro-batches of 4, 4, 2: three passes
    assert not any(m.training for m in _bn(result.model.train()))


def test_the_drive_is_time_major_in_memory_and_computes_what_the_view_did() -> None:
    """Each step's block of the compressed input is one contiguous slice (read 9 times a step without a copy); the
    columns give the same spikes and gradients from it as from the permuted view it was before."""
    model = _model().train()
    x, _, _ = make_batch(model.spec, 3, seed=4)
    drive = model.compress(x)
    assert drive.is_contiguous() and drive[1].is_contiguous()
    runs = []
    for layout in (lambda d: d, lambda d: d.permute(1, 2, 3, 0).contiguous().permute(3, 0, 1, 2)):
        model.zero_grad()
        torch.manual_seed(7)
        spikes = model.columns(layout(model.compress(x)))
        spikes.sum().backward()
        runs.append((spikes.detach(), [p.grad.clone() for p in model.parameters() if p.grad is not None]))
    assert torch.equal(runs[0][0], runs[1][0])
    assert all(torch.allclose(a, b, rtol=0, atol=1e-5 * float(b.abs().max())) for a, b in zip(runs[0][1], runs[1][1]))


def test_the_columns_read_the_drive_through_one_unbind() -> None:
    """Each ``drive[t]`` was a select whose gradient is a zero-filled copy of the whole drive, 35 of them added up per
    pass (about 3 % of a training step); one ``unbind`` gives the same values with one stack."""
    model = _model().train()
    x, _, _ = make_batch(model.spec, 2, seed=5)
    drive = model.compress(x)
    seen, todo, consumers = set(), [model.columns(drive).grad_fn], []
    while todo:
        node = todo.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        consumers += [node.name() for nxt, _ in node.next_functions if nxt is drive.grad_fn]
        todo += [nxt for nxt, _ in node.next_functions]
    assert consumers == ["UnbindBackward0"]
