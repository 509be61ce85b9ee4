"""The training loop: train one model on one split with its recipe, select the epoch on validation, evaluate on test.

The loop batches straight from the split's tensors (a seeded ``torch.randperm`` per epoch indexes ``x``, ``g``,
``y``), which is many times faster than a per-sample ``DataLoader`` for these small, fixed-size sequences.

Protocol:

1. seed Python/NumPy/torch with ``seed`` (so a model built here, its dropout and the shuffling repeat exactly on CPU);
2. train up to ``max_epochs``; after every epoch evaluate on the validation split and keep the best state (see
   `tactile_zoo.recipe` for what "best" means); stop after ``patience`` epochs without improvement;
3. restore the best state (test data is never looked at before this point); a model whose ``precise_bn`` is True
   gets its batch norms' running statistics recomputed over the training split for that state
   (:func:`recompute_bn_stats`; after a refit, over train + val for the refit state);
4. with ``refit=True``, restart from the initial weights and train on train + val for the selected number of epochs
   (same seed, same schedule), and use that model;
5. evaluate on the test split when one is given.

Without a validation split there is no selection: every epoch runs and the last state is kept.

Reproducibility: on CPU the same seed gives the same numbers for the same torch thread count (``torch.get_num_threads``;
how many threads split a convolution or matrix product changes its rounding). The harness runs every cell with one
thread unless told otherwise, so its numbers do not depend on where a cell runs.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F

from .._env import env_flag
from ..errors import ConfigError, TactileZooError
from ..recipe import Recipe, lr_factor
from .cuda_graph import GraphedForward
from .distill import distillation_loss
from .evaluate import EvalResult, evaluate, predict_scores
from .progress import Progress
from .runtime import count_parameters, flush_denormals, resolve_device, seed_everything
from .tensors import TensorSplit, as_split, concat

__all__ = ["train_model", "FitResult", "TrainingError", "build_optimizer", "compute_loss"]


class TrainingError(TactileZooError):
    """Training cannot go on: a non-finite loss, or a model whose output has the wrong shape."""


@dataclass
class FitResult:
    """What :func:`fit` returns.

    ``metrics``/``predictions``/``probabilities`` are the test split's when a test split was given, else the
    validation split's (of the selected model). ``curve`` has one row per epoch: ``epoch``, ``train_loss``,
    ``val_loss``, ``val_accuracy``, ``lr``, ``seconds``; ``refit_curve`` the same for the refit run.
    """

    model: torch.nn.Module
    recipe: Recipe
    curve: list[dict[str, Any]]
    best_epoch: int
    epochs_run: int
    train_seconds: float
    params: int
    device: str
    seed: int
    val: EvalResult | None = None
    test: EvalResult | None = None
    refit: bool = False
    refit_curve: list[dict[str, Any]] = field(default_factory=list)
    n_train: int = 0
    n_val: int = 0

    @property
    def _main(self) -> EvalResult | None:
        return self.test if self.test is not None else self.val

    @property
    def metrics(self) -> dict[str, Any]:
        return dict(self._main.metrics) if self._main is not None else {}

    @property
    def predictions(self) -> list[int]:
        return list(self._main.predictions) if self._main is not None else []

    @property
    def probabilities(self) -> list[list[float]]:
        return list(self._main.probabilities) if self._main is not None else []


def build_optimizer(model: torch.nn.Module, recipe: Recipe) -> torch.optim.Optimizer:
    params = [p for p in model.parameters() if p.requires_grad]
    if not params:
        raise ConfigError(f"{type(model).__name__} has no trainable parameters")
    if recipe.optimizer == "sgd":
        return torch.optim.SGD(params, lr=recipe.lr, momentum=recipe.momentum, nesterov=recipe.nesterov,
                               weight_decay=recipe.weight_decay)
    cls = torch.optim.AdamW if recipe.optimizer == "adamw" else torch.optim.Adam
    return cls(params, lr=recipe.lr, weight_decay=recipe.weight_decay, amsgrad=recipe.amsgrad)


def compute_loss(scores: torch.Tensor, y: torch.Tensor, recipe: Recipe) -> torch.Tensor:
    """Cross-entropy on logits, or MSE between output rates and ``rate_targets`` (true class, others)."""
    if recipe.loss == "ce":
        return F.cross_entropy(scores, y, label_smoothing=recipe.label_smoothing)
    on, off = recipe.rate_targets
    target = torch.full_like(scores, off).scatter_(1, y[:, None], on)  # (B, K)
    return F.mse_loss(scores, target)


def _batches(order: torch.Tensor, batch_size: int) -> Iterator[torch.Tensor]:
    """Consecutive slices of ``order``; a lone last sample joins the previous batch (BatchNorm needs two)."""
    n = order.shape[0]
    starts = list(range(0, n, batch_size))
    if len(starts) > 1 and n - starts[-1] == 1:
        starts.pop()
    for i, start in enumerate(starts):
        yield order[start:starts[i + 1] if i + 1 < len(starts) else n]


class _Trainer:
    """One training run: optimiser, schedule and shuffling state for a model on one split."""

    def __init__(self, model: torch.nn.Module, recipe: Recipe, train: TensorSplit, seed: int, device: torch.device,
                 cuda_graphs: bool = False) -> None:
        self.model, self.recipe, self.device = model, recipe, device
        # the training forward replayed from CUDA graphs (.cuda_graph), recorded at the first batch
        self.cuda_graphs, self.graphed = cuda_graphs, None
        self.x, self.y = train.x.to(device), train.y.to(device)  # whole split on the device once
        self.g = train.g.to(device) if train.g.shape[-1] > 0 else None
        # distillation: the teachers' probabilities of each training sample, indexed as x and y are
        self.soft = train.soft.to(device) if recipe.distill_weight > 0 else None
        self.num_classes = train.spec.num_classes
        self.optimizer = build_optimizer(model, recipe)
        self.generator = torch.Generator().manual_seed(seed)
        # the recipe's weight average (EMA), buffers included so BatchNorm statistics follow the averaged weights
        self.average = None if recipe.ema_decay is None else torch.optim.swa_utils.AveragedModel(
            model, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(recipe.ema_decay), use_buffers=True)

    @property
    def evaluated(self) -> torch.nn.Module:
        """The weights that validation, selection and the caller see: the average when the recipe keeps one."""
        return self.model if self.average is None else self.average.module

    def epoch(self, epoch: int) -> float:
        """Train one (0-based) epoch; returns the mean training loss."""
        lr = self.recipe.lr * lr_factor(self.recipe, epoch)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        self.model.train()
        order = torch.randperm(self.x.shape[0], generator=self.generator).to(self.device)
        total = torch.zeros((), device=self.device)
        micro = self.recipe.micro_batch_size
        for idx in _batches(order, self.recipe.batch_size):
            if micro is not None and micro < idx.shape[0]:
                total += self._accumulate(idx, micro)
            else:
                loss = self._loss(idx)
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                total += loss.detach() * idx.shape[0]
            if self.recipe.grad_clip is not None:
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.recipe.grad_clip)
            self.optimizer.step()
            if self.average is not None:
                self.average.update_parameters(self.model)
        mean = float(total) / self.x.shape[0]  # one host sync per epoch, not per batch
        if mean != mean or mean in (float("inf"), float("-inf")):
            raise TrainingError(f"the training loss became {mean} in epoch {epoch + 1} (lr {lr:g}); the model "
                                f"diverged")
        return mean

    def _loss(self, idx: torch.Tensor) -> torch.Tensor:
        """The recipe's mean loss over the samples ``idx`` of the split (the model called once, in training mode)."""
        xb, yb = self.x[idx], self.y[idx]  # (B, T, N, C), (B,)
        gb = self.g[idx] if self.g is not None else None  # (B, T, G)
        if self.cuda_graphs and self.graphed is None:
            self.graphed = GraphedForward(self.model, xb, gb)
        scores = self.model(xb, gb) if self.graphed is None else self.graphed(xb, gb)
        if scores.shape != (idx.shape[0], self.num_classes):
            raise TrainingError(f"{type(self.model).__name__}.forward returned shape {tuple(scores.shape)}; "
                                f"expected [batch={idx.shape[0]}, num_classes={self.num_classes}]")
        if self.soft is not None:
            return distillation_loss(scores, yb, self.soft[idx], self.recipe)
        return compute_loss(scores, yb, self.recipe)

    def _accumulate(self, idx: torch.Tensor, micro: int) -> torch.Tensor:
        """The gradient of one batch ``idx`` summed over its micro-batches (the recipe's ``micro_batch_size``), each
        loss weighted by its share of the batch; returns the batch's summed loss (its mean times its size)."""
        self.optimizer.zero_grad(set_to_none=True)
        total = torch.zeros((), device=self.device)
        for part in _batches(idx, micro):
            loss = self._loss(part)
            (loss * (part.shape[0] / idx.shape[0])).backward()
            total += loss.detach() * part.shape[0]
        return total

    def close(self) -> None:
        """Free the CUDA graphs, if any: the model goes on with its own forward."""
        if self.graphed is not None:
            self.graphed.release()
            self.graphed = None


def _cuda_graphs(asked: bool | None, device: torch.device) -> bool:
    """Whether to record the training forward in CUDA graphs: ``asked``, or else ``TACTILE_ZOO_CUDA_GRAPHS`` on a
    CUDA device (the variable is for a whole session, which may train on the CPU too, so it is ignored there)."""
    if asked is None:
        return device.type == "cuda" and env_flag("TACTILE_ZOO_CUDA_GRAPHS")
    if asked and device.type != "cuda":
        raise ConfigError(f"cuda_graphs=True needs a CUDA device; this run trains on {device}")
    return bool(asked)


def _val_step(model: torch.nn.Module, val: TensorSplit, recipe: Recipe, device: torch.device
              ) -> tuple[float, float]:
    scores = predict_scores(model, val.x, val.g, recipe.eval_batch_size, device)
    loss = float(compute_loss(scores, val.y, recipe))
    acc = float((scores.argmax(-1) == val.y).float().mean())
    return loss, acc


def _better(recipe: Recipe, loss: float, acc: float, best: tuple[float, float] | None) -> bool:
    if loss != loss:  # a NaN validation loss never improves anything
        return False
    if best is None:
        return True
    key = (acc, -loss) if recipe.monitor == "val_accuracy" else (-loss, acc)
    best_key = (best[1], -best[0]) if recipe.monitor == "val_accuracy" else (-best[0], best[1])
    return key > best_key


def _clone_state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


class _Pair(torch.nn.Module):
    """A model called on one ``(x, g)`` pair: the one-input model ``torch.optim.swa_utils.update_bn`` feeds."""

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, pair: tuple[torch.Tensor, torch.Tensor | None]) -> torch.Tensor:
        return self.model(*pair)


def recompute_bn_stats(model: torch.nn.Module, split: TensorSplit, batch_size: int, device: torch.device) -> None:
    """Recompute every batch norm's running statistics over ``split`` with the model's present weights.

    ``torch.optim.swa_utils.update_bn``: each batch norm's statistics are reset and, with ``momentum=None``, become
    the cumulative (equal per batch) average of the batch statistics of one pass in training mode without gradients;
    the momenta are restored after. The batches are the training loop's (``batch_size``, a lone last sample joined to
    the batch before it), in split order, so nothing random is drawn. Every module's training flag is restored.
    """
    modes = {m: m.training for m in model.modules()}
    x = split.x.to(device)
    g = split.g.to(device) if split.g.shape[-1] > 0 else None
    order = torch.arange(x.shape[0], device=device)
    # update_bn calls the model on the first element of a list: each batch is a one-element list of its (x, g) pair
    batches = ([(x[idx], None if g is None else g[idx])] for idx in _batches(order, batch_size))
    try:
        torch.optim.swa_utils.update_bn(batches, _Pair(model))
    finally:
        for m, mode in modes.items():
            m.training = mode


@flush_denormals()
def train_model(model: torch.nn.Module, dataset: Any, recipe: Recipe, seed: int = 0, val_dataset: Any = None,
                device: str | torch.device = "auto", *, test_dataset: Any = None, refit: bool = False,
                progress: bool = True, callback: Callable[[dict[str, Any]], None] | None = None,
                cuda_graphs: bool | None = None) -> FitResult:
    """The training loop behind :func:`tactile_zoo.engine.fit` and :func:`tactile_zoo.engine.cell.train_cell`: a
    built ``model`` trained on the ``dataset`` split with the resolved ``recipe``, used as it is (resolving names,
    overrides and epoch counts is :mod:`.config`'s, before this is called). The other arguments are ``fit``'s."""
    train = as_split(dataset)
    val = as_split(val_dataset) if val_dataset is not None else None
    if refit and val is None:
        raise ConfigError("refit=True needs a validation split: it retrains for the epoch count chosen on it")
    if len(train) == 0:
        raise ConfigError("the training split is empty")
    if not isinstance(recipe, Recipe):
        raise ConfigError(f"train_model() takes a resolved Recipe, got {type(recipe).__name__}; tactile_zoo.fit "
                          f"resolves names and overrides")
    if recipe.distill_weight > 0 and (train.soft is None or (refit and val is not None and val.soft is None)):
        raise ConfigError(f"the recipe's distill_weight is {recipe.distill_weight:g}, but the split(s) it trains on "
                          f"hold no teacher probabilities (tactile_zoo.engine.distill; a cell's teachers setting)")
    dev = resolve_device(device)
    graphs = _cuda_graphs(cuda_graphs, dev)
    module, rec = model, recipe
    seed_everything(seed)  # dropout and any other randomness during training
    module.to(dev)
    module.zoo_loss = rec.loss  # so evaluate(model, ...) later knows how scores become probabilities
    initial = _clone_state(module) if refit else None

    start = time.perf_counter()
    trainer = _Trainer(module, rec, train, seed, dev, graphs)
    curve: list[dict[str, Any]] = []
    best: tuple[float, float] | None = None
    best_state: dict[str, torch.Tensor] | None = None
    best_epoch, waited = 0, 0
    what = f"train {type(module).__name__} on {getattr(train.spec, 'name', 'its data')}"
    bar = Progress(rec.max_epochs, what, "epochs", enabled=progress)
    try:
        for epoch in range(rec.max_epochs):
            t0 = time.perf_counter()
            train_loss = trainer.epoch(epoch)
            row: dict[str, Any] = {"epoch": epoch + 1, "train_loss": train_loss, "val_loss": None,
                                   "val_accuracy": None, "lr": trainer.optimizer.param_groups[0]["lr"]}
            if val is not None:
                val_loss, val_acc = _val_step(trainer.evaluated, val, rec, dev)
                row.update(val_loss=val_loss, val_accuracy=val_acc)
                if _better(rec, val_loss, val_acc, best):
                    best, best_state = (val_loss, val_acc), _clone_state(trainer.evaluated)
                    best_epoch, waited = epoch + 1, 0
                else:
                    waited += 1
            else:
                best_epoch = epoch + 1
            row["seconds"] = time.perf_counter() - t0
            curve.append(row)
            if callback is not None:
                callback(row)
            bar.update(1, f"loss {train_loss:.3f}" + ("" if row["val_accuracy"] is None else
                                                      f" val_acc {row['val_accuracy']:.3f}"))
            if rec.patience is not None and val is not None and waited >= rec.patience:
                break
    finally:
        bar.close()
        trainer.close()
    if best_state is not None:
        module.load_state_dict(best_state)
    elif val is not None:
        raise TrainingError("no epoch produced a finite validation loss")
    elif trainer.average is not None:  # nothing selected: the last epoch's average is the model
        module.load_state_dict(trainer.evaluated.state_dict())
    # a model that asks for it (``precise_bn = True``) is handed on, validated and tested with its batch norms'
    # statistics recomputed for the kept weights; selection above read the moving averages of each epoch
    precise = getattr(module, "precise_bn", False) is True
    if precise:
        recompute_bn_stats(module, train, rec.batch_size, dev)
    val_result = (evaluate(module, val, loss=rec.loss, batch_size=rec.eval_batch_size, progress=False)
                  if val is not None else None)

    refit_curve: list[dict[str, Any]] = []
    if refit:
        assert initial is not None and val is not None
        module.load_state_dict(initial)
        seed_everything(seed)
        both = concat(train, val)
        trainer = _Trainer(module, rec, both, seed, dev, graphs)
        with Progress(best_epoch, f"{what}: refit on train + val", "epochs", enabled=progress) as bar:
            try:
                for epoch in range(best_epoch):
                    t0 = time.perf_counter()
                    loss = trainer.epoch(epoch)
                    lr = trainer.optimizer.param_groups[0]["lr"]
                    refit_curve.append({"epoch": epoch + 1, "train_loss": loss, "lr": lr,
                                        "seconds": time.perf_counter() - t0})
                    bar.update(1, f"loss {loss:.3f}")
            finally:
                trainer.close()
        if trainer.average is not None:
            module.load_state_dict(trainer.evaluated.state_dict())
        if precise:  # the refit model's statistics, over what it was trained on
            recompute_bn_stats(module, both, rec.batch_size, dev)
    train_seconds = time.perf_counter() - start
    test_result = None
    if test_dataset is not None:
        test_result = evaluate(module, test_dataset, loss=rec.loss, batch_size=rec.eval_batch_size, progress=False)
    return FitResult(model=module, recipe=rec, curve=curve, best_epoch=best_epoch, epochs_run=len(curve),
                     train_seconds=train_seconds, params=count_parameters(module), device=str(dev), seed=seed,
                     val=val_result, test=test_result, refit=refit, refit_curve=refit_curve,
                     n_train=len(train), n_val=len(val) if val is not None else 0)
