"""The contract every registered model keeps, on every registered sensor family (timm-style zoo-wide suite).

Parametrised over ``list_models()`` x ``list_sensors()`` at collection time, so a model (a plugin's too) is tested the
moment it registers. Each (model, sensor) pair gets a small synthetic spec: T = 12 steps, the sensor's taxels and
channels, the globals its real datasets carry, 5 classes. Checks: output shape, a finite non-zero gradient on every
parameter, determinism under a seed, overfitting a tiny batch with the model's own recipe loss, step-by-step
streaming equal to the full forward on every prefix (streaming models), and complete metadata and recipe.
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
#: global features of the built-in sensors' real datasets (Augment8000: 3 finger positions; ALU-Textures: 8 joints)
GLOBALS = {"optoforce3": 3, "uskin_allegro": 8}
RECIPE_KEYS = {"loss", "optimizer", "lr", "max_epochs", "patience", "batch_size"}
#: Adam budget to overfit a tiny batch, per recipe loss (never per model): (max steps, learning rate). Recipes' own
#: learning rates are tuned for epochs over real data, so the test fixes its own. Rate-coded spiking outputs fall
#: silent (rate 0 everywhere, MSE stuck at 1/K) at 1e-2, so "mse_rate" gets a smaller rate and more steps.
OVERFIT_BUDGET = {"ce": (60, 1e-2), "mse_rate": (100, 1e-3)}
OVERFIT_FACTOR = 0.3  # the loss must fall below this fraction of its initial value


def make_spec(sensor_name: str) -> DatasetSpec:
    sensor = tz.get_sensor(sensor_name)
    return DatasetSpec(f"synthetic_{sensor_name}", NUM_CLASSES, tuple(f"c{i}" for i in range(NUM_CLASSES)),
                       NUM_STEPS, sensor.num_nodes, len(sensor.channels) or 2, GLOBALS.get(sensor_name, 0), sensor)


def make_batch(spec: DatasetSpec, batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Distinct random binary event patterns; labels spread evenly over the classes in order.

    The event density rises with the sample index, so the classes also differ in density: a model that pools over
    taxels early (global average pooling) can tell them apart as well as one that memorises patterns. Binary
    events drive spiking models.
    """
    gen = torch.Generator().manual_seed(seed)
    density = torch.linspace(0.1, 0.9, batch).view(batch, 1, 1, 1)
    x = (torch.rand(batch, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen) < density).float()
    g = torch.randn(batch, spec.num_steps, spec.num_globals, generator=gen)
    return x, g, torch.arange(batch) * spec.num_classes // batch


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


def test_zoo_is_populated() -> None:
    assert {"sgnet", "dcnn", "convlstm", "cnn_lstm", "tacformer", "x_tacformer", "deeptactile"} <= set(MODELS), MODELS
    assert {"neutouch", "biotac_sp", "optoforce3", "uskin_allegro"} <= set(SENSORS)


@pytest.mark.parametrize("name", MODELS)
def test_metadata_and_recipe_are_complete(name: str) -> None:
    meta = get_model_entry(name).meta
    for key in ("paper", "description"):
        assert isinstance(meta.get(key), str) and meta[key].strip(), f"{name}: missing {key}"
    assert meta.get("tags") and all(isinstance(t, str) for t in meta["tags"]), f"{name}: no tags"
    assert set(meta.get("inputs", ())) <= {"graph", "grid", "globals"}, f"{name}: unknown inputs {meta.get('inputs')}"
    assert isinstance(meta.get("causal"), bool) and isinstance(meta.get("streaming"), bool)
    assert meta["causal"] or not meta["streaming"], f"{name}: streaming needs a causal model"
    recipe = meta.get("recipe") or {}
    assert RECIPE_KEYS <= set(recipe), f"{name}: recipe lacks {sorted(RECIPE_KEYS - set(recipe))}"
    assert recipe["loss"] in OVERFIT_BUDGET and recipe["optimizer"] in {"adam", "adamw", "sgd"}
    assert recipe["lr"] > 0 and recipe["max_epochs"] >= 1 and recipe["batch_size"] >= 1
    assert recipe["patience"] is None or recipe["patience"] >= 1


@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("name", MODELS)
def test_forward_shape_and_gradients(name: str, sensor: str) -> None:
    spec = make_spec(sensor)
    model = build(name, spec).train()
    x, g, y = make_batch(spec, 4, seed=1)
    out = model(x, g)
    assert out.shape == (4, NUM_CLASSES) and torch.isfinite(out).all()
    recipe_loss(name, out, y).backward()
    for pname, p in model.named_parameters():
        assert p.grad is not None, f"{name} on {sensor}: parameter {pname} gets no gradient"
        assert torch.isfinite(p.grad).all(), f"{name} on {sensor}: non-finite gradient in {pname}"
        assert p.grad.abs().sum() > 0, f"{name} on {sensor}: parameter {pname} has an all-zero gradient"
    if spec.num_globals == 0:  # g may be omitted, or come as the (B, T, 0) tensor collate() builds
        model.eval()
        with torch.no_grad():
            assert torch.allclose(model(x, None), model(x, g), atol=1e-6)


@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("name", MODELS)
def test_deterministic_under_a_seed(name: str, sensor: str) -> None:
    spec = make_spec(sensor)
    a, b = build(name, spec, seed=7).eval(), build(name, spec, seed=7).eval()
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    x, g, _ = make_batch(spec, 3, seed=2)
    with torch.no_grad():
        first = a(x, g)
        assert torch.equal(first, b(x, g))
        assert torch.equal(first, a(x, g)), f"{name}: a second forward differs (state leaks between calls)"


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


@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("name", STREAMING)
def test_streaming_equals_forward_on_every_prefix(name: str, sensor: str) -> None:
    spec = make_spec(sensor)
    model = build(name, spec, seed=5).eval()
    assert callable(getattr(model, "init_state", None)) and callable(getattr(model, "step", None)), \
        f"{name} declares streaming=True but lacks init_state/step"
    x, g, _ = make_batch(spec, 2, seed=6)
    steps = 7
    with torch.no_grad():
        state = model.init_state(2)
        for t in range(steps):
            g_t = g[:, t] if spec.num_globals else None
            scores, state = model.step(x[:, t], g_t, state)
            full = model(x[:, : t + 1], g[:, : t + 1])
            assert scores.shape == full.shape == (2, NUM_CLASSES)
            assert torch.allclose(scores, full, atol=1e-5, rtol=1e-4), \
                f"{name} on {sensor}: step {t} differs from forward on the prefix by {(scores - full).abs().max()}"
