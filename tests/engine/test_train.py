from __future__ import annotations

from typing import Any

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.data.spec import TactileSample
from tactile_zoo.engine import FitResult, TrainingError, fit
from tactile_zoo.errors import ConfigError


def _splits(**kw: Any) -> dict[str, Any]:
    return {s: tz.load_dataset("tiny_blobs", split=s, **kw) for s in ("train", "val", "test")}


def _fit(model: str = "tiny_mlp", seed: int = 0, device: str = "cpu", **kw: Any) -> FitResult:
    s = _splits()
    return fit(model, s["train"], seed=seed, val_dataset=s["val"], test_dataset=s["test"], device=device, **kw)


def test_fit_learns_and_the_same_seed_repeats_exactly() -> None:
    a, b, c = _fit(seed=0), _fit(seed=0), _fit(seed=1)
    assert a.metrics["accuracy"] > 0.6  # 3 classes: chance is 1/3
    assert [r["train_loss"] for r in a.curve] == [r["train_loss"] for r in b.curve]
    assert [r["val_loss"] for r in a.curve] == [r["val_loss"] for r in b.curve]
    assert a.predictions == b.predictions and a.probabilities == b.probabilities
    assert [r["train_loss"] for r in a.curve] != [r["train_loss"] for r in c.curve]
    assert a.params == sum(p.numel() for p in a.model.parameters()) and a.device == "cpu"
    assert set(a.curve[0]) == {"epoch", "train_loss", "val_loss", "val_accuracy", "lr", "seconds"}


def test_public_api_forwards_to_the_engine() -> None:
    assert tz.fit is fit and tz.evaluate is tz.engine.evaluate
    res = tz.fit("tiny_mlp", "tiny_blobs", seed=0, epochs=2, device="cpu")  # names: splits are loaded
    assert res.epochs_run == 2 and res.test is not None and res.n_train == len(tz.load_dataset("tiny_blobs",
                                                                                              split="train"))


class _Spy:
    """A split that logs when its tensors are read."""

    def __init__(self, inner: Any, log: list[str], name: str) -> None:
        self.inner, self.log, self.name, self.spec = inner, log, name, inner.spec

    def tensors(self) -> Any:
        self.log.append(f"read {self.name}")
        return self.inner.tensors()


def test_epoch_is_selected_on_val_and_test_is_read_only_after_training() -> None:
    s = _splits()
    log: list[str] = []
    res = fit("tiny_mlp", s["train"], seed=3, val_dataset=s["val"], test_dataset=_Spy(s["test"], log, "test"),
              device="cpu", recipe={"max_epochs": 12, "patience": None},
              callback=lambda row: log.append(f"epoch {row['epoch']}"))
    assert log.index("read test") > log.index("epoch 12")
    key = [(r["val_accuracy"], -r["val_loss"]) for r in res.curve]
    assert res.best_epoch == 1 + key.index(max(key))
    # the returned model is the best epoch's: its validation numbers are that row's
    row = res.curve[res.best_epoch - 1]
    assert res.val.metrics["accuracy"] == pytest.approx(row["val_accuracy"])


def test_monitor_val_loss_selects_lowest_loss() -> None:
    res = _fit(seed=2, recipe={"monitor": "val_loss", "max_epochs": 10, "patience": None})
    losses = [r["val_loss"] for r in res.curve]
    assert res.best_epoch == 1 + losses.index(min(losses))


def test_early_stopping_after_patience_epochs_without_improvement() -> None:
    res = _fit(seed=0, recipe={"max_epochs": 60, "patience": 2, "lr": 0.1})
    assert res.epochs_run < 60
    assert res.epochs_run == res.best_epoch + 2


def test_refit_retrains_on_train_and_val_for_the_selected_epochs() -> None:
    plain, refit = _fit(seed=0), _fit(seed=0, refit=True)
    assert refit.refit and len(refit.refit_curve) == refit.best_epoch == plain.best_epoch
    assert refit.curve == [{**r, "seconds": refit.curve[i]["seconds"]} for i, r in enumerate(plain.curve)]
    assert any(not torch.equal(p, q) for p, q in zip(plain.model.parameters(), refit.model.parameters()))
    with pytest.raises(ConfigError, match="validation split"):
        fit("tiny_mlp", _splits()["train"], refit=True, device="cpu")


def test_non_finite_loss_is_a_training_error() -> None:
    with pytest.raises(TrainingError, match="became nan"):
        _fit("tiny_nan")


def test_wrong_output_shape_is_a_training_error() -> None:
    class Bad(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.lin = torch.nn.Linear(4, 5)

        def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
            return self.lin(x.mean((1, 2)))

    with pytest.raises(TrainingError, match=r"shape \(32, 5\).*num_classes=3"):
        fit(Bad(), _splits()["train"], device="cpu")


def test_mse_rate_probabilities_are_normalised_rates() -> None:
    res = _fit("tiny_rate")
    assert res.recipe.loss == "mse_rate"
    probs = torch.tensor(res.probabilities)
    torch.testing.assert_close(probs.sum(-1), torch.ones(len(probs)))
    assert res.metrics["accuracy"] > 0.5


def test_a_module_and_a_plain_dataset_of_samples_work() -> None:
    s = _splits()

    class Plain(torch.utils.data.Dataset):
        def __init__(self, ds: Any) -> None:
            self.ds, self.spec = ds, ds.spec

        def __len__(self) -> int:
            return len(self.ds)

        def __getitem__(self, i: int) -> TactileSample:
            return self.ds[i]

    torch.manual_seed(0)
    model = tz.create_model("tiny_mlp", s["train"].spec)
    res = fit(model, Plain(s["train"]), val_dataset=Plain(s["val"]), device="cpu", epochs=3)
    assert res.model is model and res.epochs_run == 3
    assert res.metrics == res.val.metrics  # no test split: the validation numbers of the selected model
    ev = tz.evaluate(model, Plain(s["test"]))
    assert ev.metrics["n"] == len(s["test"]) and len(ev.probabilities) == len(s["test"])


def test_evaluate_repeats_the_fit_test_numbers() -> None:
    res = _fit("tiny_rate", seed=4)
    ev = tz.evaluate(res.model, _splits()["test"])  # knows the loss from fit: rates, not softmax
    assert ev.metrics == res.test.metrics and ev.probabilities == res.probabilities


@pytest.mark.skipif(torch.cuda.is_available(), reason="tests the error without a GPU")
def test_cuda_without_a_gpu_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="CUDA is not available"):
        _fit(device="cuda")


def test_ema_returns_the_moving_average_of_the_weights_and_leaves_training_alone() -> None:
    """``ema_decay``: the model returned is the exponential moving average of the weights after every step, over the
    very trajectory training takes without it (one step per epoch here, so each epoch's weights are one step's)."""
    splits = _splits()
    train, spec = splits["train"], splits["train"].spec
    one_step = {"batch_size": len(train), "max_epochs": 3, "patience": None, "lr": 0.05}
    seen: list[dict[str, torch.Tensor]] = []
    plain_model = tz.create_model("tiny_mlp", spec)
    start = {k: v.clone() for k, v in plain_model.state_dict().items()}
    fit(plain_model, train, recipe=one_step, seed=1,
        callback=lambda row: seen.append({k: v.clone() for k, v in plain_model.state_dict().items()}))
    averaged_model = tz.create_model("tiny_mlp", spec)
    averaged_model.load_state_dict(start)
    fit(averaged_model, train, recipe={**one_step, "ema_decay": 0.9}, seed=1)
    for key, value in averaged_model.state_dict().items():
        w1, w2, w3 = (step[key] for step in seen)
        expected = 0.9 * (0.9 * w1 + 0.1 * w2) + 0.1 * w3  # the first update copies, the next ones average
        assert torch.allclose(value, expected, atol=1e-6), key
        assert not torch.allclose(value, w3), key  # the raw last weights are not what came back


def _trained(recipe: dict[str, Any], model: torch.nn.Module, start: dict[str, torch.Tensor]) -> FitResult:
    model.load_state_dict(start)
    return fit(model, _splits()["train"], recipe=recipe, seed=2)


def test_micro_batches_make_the_whole_batch_step() -> None:
    """``micro_batch_size``: the summed, share-weighted micro-batch gradients are the whole batch's (a model without
    batch norm or dropout, so only rounding differs), the loss curve too; at or above the batch size the loop is the
    plain one, bit for bit."""
    spec = _splits()["train"].spec
    model = tz.create_model("tiny_mlp", spec, dropout=0.0)
    start = {k: v.clone() for k, v in model.state_dict().items()}
    whole = {"batch_size": 40, "max_epochs": 3, "patience": None, "lr": 0.05}
    plain = _trained(whole, model, start)
    weights = {k: v.clone() for k, v in model.state_dict().items()}
    micro = _trained({**whole, "micro_batch_size": 7}, model, start)  # 40 -> 7 x 5 + 5; a lone last one joins
    for key, value in model.state_dict().items():
        assert torch.allclose(value, weights[key], atol=1e-6), key
    assert [r["train_loss"] for r in micro.curve] == pytest.approx([r["train_loss"] for r in plain.curve], rel=1e-6)
    same = _trained({**whole, "micro_batch_size": 40}, model, start)
    assert [r["train_loss"] for r in same.curve] == [r["train_loss"] for r in plain.curve]
    for key, value in model.state_dict().items():
        assert torch.equal(value, weights[key]), key


class _Normed(torch.nn.Module):
    """Mean over time, then Linear -> BatchNorm1d -> Linear."""

    def __init__(self, spec: Any) -> None:
        super().__init__()
        self.net = torch.nn.Sequential(torch.nn.Linear(spec.num_nodes * spec.num_channels, 8),
                                       torch.nn.BatchNorm1d(8), torch.nn.Linear(8, spec.num_classes))

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.net(x.mean(dim=1).flatten(1))


def test_micro_batches_normalise_batch_norm_per_micro_batch() -> None:
    """The declared difference from one large batch: batch norm sees each micro-batch, and updates its running
    statistics once per micro-batch (one optimiser step a batch all the same)."""
    train = _splits()["train"]
    model = _Normed(train.spec)
    start = {k: v.clone() for k, v in model.state_dict().items()}
    whole = {"batch_size": len(train), "max_epochs": 1, "patience": None}
    _trained(whole, model, start)
    assert int(model.net[1].num_batches_tracked) == 1
    weights = {k: v.clone() for k, v in model.state_dict().items()}
    _trained({**whole, "micro_batch_size": len(train) // 3}, model, start)
    assert int(model.net[1].num_batches_tracked) == 3
    assert not torch.allclose(model.net[0].weight, weights["net.0.weight"], atol=1e-6)
