"""The contract every registered model keeps, on every registered sensor family (timm-style zoo-wide suite).

Parametrised over ``list_models()`` at collection time, so a model (a plugin's too) is tested the moment it registers.
The contract itself is the public suite :func:`tactile_zoo.testing.check_model` at its publication level (metadata
and its completeness, recipes, build, forward shape and finiteness, the input left unchanged, global inputs, batch
independence, determinism under a seed, gradients on every parameter, causal prefixes, streaming equal to forward on
every prefix, state_dict round trip), run on a tiny spec per sensor:
T = 12 steps, the sensor's taxels and channels, the globals its real datasets carry, 5 classes. On top of it, this
module overfits a tiny batch with each model's own recipe loss on every sensor.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.registry import get_model_entry
from tactile_zoo.testing import MODEL_RULES, check_model, random_batch, tiny_spec

TESTS_DIR = Path(__file__).resolve().parents[1]


def _zoo_member(name: str) -> bool:
    """Built-ins and installed plugins, not the deliberately broken fixture models other test modules register."""
    module = sys.modules.get(getattr(get_model_entry(name).obj, "__module__", ""), None)
    path = getattr(module, "__file__", None)
    return path is None or TESTS_DIR not in Path(path).resolve().parents


MODELS = [name for name in tz.list_models() if _zoo_member(name)]
SENSORS = tz.list_sensors()
STREAMING = [m for m in MODELS if get_model_entry(m).meta.get("streaming")]

NUM_STEPS, NUM_CLASSES = 12, 5
#: hyper-parameters that keep a large model's contract check fast (the ``builds`` rule still builds the defaults):
#: each model's own ``test_hparams`` registry metadata (the multi-barrel SNN's: 28.4 M parameters at full size)
SMALL = {name: dict(get_model_entry(name).meta["test_hparams"]) for name in MODELS
         if "test_hparams" in get_model_entry(name).meta}
#: Adam budget to overfit a tiny batch, per recipe loss (never per model): (max steps, learning rate). Recipes' own
#: learning rates are tuned for epochs over real data, so the test fixes its own. Rate-coded spiking outputs fall
#: silent (rate 0 everywhere, MSE stuck at 1/K) at 1e-2, so "mse_rate" gets a smaller rate and more steps.
OVERFIT_BUDGET = {"ce": (60, 1e-2), "mse_rate": (100, 1e-3)}
OVERFIT_FACTOR = 0.3  # the loss must fall below this fraction of its initial value
RECIPE_KEYS = {"loss", "optimizer", "lr", "max_epochs", "patience", "batch_size"}


def make_spec(sensor_name: str) -> DatasetSpec:
    """The tiny spec of the contract suite on ``sensor_name`` (T = 12, 5 classes)."""
    return tiny_spec(sensor_name, NUM_STEPS, NUM_CLASSES)


def make_batch(spec: DatasetSpec, batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The contract suite's batch: distinct random binary events, density rising with the index, labels in order."""
    return random_batch(spec, batch, seed)


def build(name: str, spec: DatasetSpec, seed: int = 0) -> torch.nn.Module:
    torch.manual_seed(seed)
    return tz.create_model(name, spec)


def recipe_loss(name: str, out: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    loss = get_model_entry(name).meta["recipe"]["loss"]
    if loss == "ce":
        return F.cross_entropy(out, y)
    if loss == "mse_rate":
        return F.mse_loss(out, F.one_hot(y, out.shape[-1]).to(out.dtype))
    raise AssertionError(f"model {name!r}: unknown recipe loss {loss!r}")


@pytest.mark.parametrize("name", MODELS)
def test_every_model_keeps_the_contract(name: str) -> None:
    """check_model over every sensor at the publication level (metadata completeness too): every rule holds, or
    (causal, streaming, inputs) does not apply to it."""
    report = check_model(name, hparams=SMALL.get(name), level="publication")
    meta = get_model_entry(name).meta
    ran = set(report.rules)
    assert ran >= set(MODEL_RULES) - {"causal", "streaming", "inputs"}, report
    assert ("causal" in ran) == meta["causal"] and ("streaming" in ran) == meta["streaming"], report
    assert len({where for rule, where in report.passed if rule == "forward"}) == len(SENSORS), report


def test_zoo_is_populated() -> None:
    """Every public module of ``tactile_zoo.models`` registers a model that this suite tests (no list of names)."""
    modules = {p.stem for p in Path(tz.models.__file__).parent.glob("*.py") if not p.stem.startswith("_")}
    registered = {get_model_entry(name).obj.__module__.rpartition(".")[2] for name in MODELS}
    assert modules and modules <= registered, f"model modules registering nothing: {sorted(modules - registered)}"
    assert len(MODELS) >= 8, MODELS
    assert {"neutouch", "biotac_sp", "optoforce3", "uskin_allegro"} <= set(SENSORS)


@pytest.mark.parametrize("name", MODELS)
def test_recipes_are_spelled_out(name: str) -> None:
    """Beyond the contract (where the harness's defaults fill a partial recipe): the zoo's recipes name the budget."""
    recipe = get_model_entry(name).meta.get("recipe") or {}
    assert RECIPE_KEYS <= set(recipe), f"{name}: recipe lacks {sorted(RECIPE_KEYS - set(recipe))}"
    assert recipe["loss"] in OVERFIT_BUDGET


@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("name", MODELS)
def test_overfits_a_tiny_batch(name: str, sensor: str) -> None:
    spec = make_spec(sensor)
    recipe = get_model_entry(name).meta["recipe"]
    model = build(name, spec, seed=3).train()
    x, g, y = make_batch(spec, 10, seed=4)
    steps, lr = OVERFIT_BUDGET[recipe["loss"]]
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for _ in range(steps):
        loss = recipe_loss(name, model(x, g), y)
        opt.zero_grad()
        loss.backward()
        if recipe.get("grad_clip"):
            torch.nn.utils.clip_grad_norm_(model.parameters(), recipe["grad_clip"])
        opt.step()
        losses.append(loss.item())
        if loss.item() < OVERFIT_FACTOR * losses[0]:
            break
    assert all(math.isfinite(v) for v in losses)
    best_late = min(losses[-5:])
    assert best_late < OVERFIT_FACTOR * losses[0], (
        f"{name} on {sensor}: loss {losses[0]:.4f} -> {best_late:.4f} after {len(losses)} Adam steps at "
        f"lr {lr}, not below {OVERFIT_FACTOR:.0%} of the start")
