"""The four Um et al. augmentations against their defining formulas, and the dataset ``augment=`` path."""

from __future__ import annotations

import math
import warnings
from typing import ClassVar

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_zoo.data.augment import (
    Jitter,
    MagnitudeWarp,
    Scaling,
    TimeWarp,
    get_augmentation,
    random_curves,
    resolve_augmentations,
    warp_clock,
)
from tactile_zoo.data.base import TactileDataset, TensorData
from tactile_zoo.data.sensors import NEUTOUCH
from tactile_zoo.errors import ConfigError


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_jitter_adds_gaussian_noise_of_sigma() -> None:
    x = torch.rand(400, 39, 2)
    out = Jitter(0.05)(x, gen(1))
    residual = (out - x).double()
    assert out.shape == x.shape and out.dtype == x.dtype
    assert abs(residual.std().item() - 0.05) < 0.05 * 0.03  # 31200 draws: the std is within ~1 %
    assert abs(residual.mean().item()) < 0.002
    assert torch.equal(out, Jitter(0.05)(x, gen(1)))  # reproducible by seed
    assert not torch.equal(out, Jitter(0.05)(x, gen(2)))


def test_scaling_multiplies_each_signal_by_one_constant_factor() -> None:
    x = torch.rand(30, 24, 3, dtype=torch.float64) + 0.5
    out = Scaling(0.1)(x, gen(3))
    ratio = out / x
    # one factor per (taxel, channel) signal, the same at every time step: x' = x * a exactly
    assert torch.allclose(ratio, ratio[:1].expand_as(ratio), rtol=1e-12, atol=0)
    factor = 1 + 0.1 * torch.randn((1, 24, 3), generator=gen(3), dtype=torch.float64)  # the draws a seed gives
    assert torch.equal(out, x * factor)
    # the factors vary between signals like N(1, 0.1^2)
    factors = Scaling(0.1)(torch.ones(2, 100, 40, dtype=torch.float64), gen(4))[0]
    assert abs(factors.mean().item() - 1) < 0.01 and abs(factors.std().item() - 0.1) < 0.005


def _piecewise_cubic(curve: np.ndarray, knot_times: np.ndarray) -> bool:
    """Equally spaced samples of a cubic have constant third differences inside every knot interval."""
    for a, b in zip(knot_times[:-1].astype(int), knot_times[1:].astype(int)):
        d3 = np.diff(curve[a: b + 1], n=3, axis=0)
        if not np.allclose(d3, d3[:1], atol=1e-9):
            return False
    return True


def test_magnitude_warp_is_x_times_a_spline_through_the_knots() -> None:
    t, signals = 51, 12  # knots at 0, 10, ..., 50: integer steps, so the curve can be read at the knots
    x = torch.randn(t, 6, 2, dtype=torch.float64)
    out = MagnitudeWarp(0.05, knots=4)(x, gen(5))
    curve, times, values = random_curves(t, signals, 4, 0.05, gen(5))
    assert np.allclose(times, [0, 10, 20, 30, 40, 50])
    assert torch.allclose(out, x * curve.reshape(t, 6, 2), atol=1e-12)
    # the curve passes through the 6 knots (4 interior + both ends) ...
    assert torch.allclose(curve[times.astype(int)], values, atol=1e-12)
    # ... and is a smooth cubic between them, different per signal
    assert _piecewise_cubic(curve.numpy(), times)
    assert curve.std(dim=1).mean() > 0.005
    # knot values ~ N(1, sigma^2)
    _, _, many = random_curves(t, 5000, 4, 0.05, gen(6))
    assert abs(many.mean().item() - 1) < 0.002 and abs(many.std().item() - 0.05) < 0.002


def test_magnitude_warp_with_sigma_zero_is_identity() -> None:
    x = torch.randn(20, 4, 3)
    assert torch.allclose(MagnitudeWarp(0.0)(x, gen()), x)


def test_time_warp_sigma_zero_is_identity() -> None:
    x = torch.randn(37, 5, 2)
    assert torch.allclose(TimeWarp(0.0)(x, gen(7)), x, atol=1e-6)


@pytest.mark.parametrize("sigma", [0.2, 1.5])  # 1.5: the spline dips below zero, the clock must stay monotone
def test_time_warp_is_a_monotone_clock_shared_by_all_signals(sigma: float) -> None:
    t = 60
    ramp = torch.arange(t, dtype=torch.float64).reshape(t, 1, 1).expand(t, 7, 3).contiguous()
    out = TimeWarp(sigma)(ramp, gen(8))
    # on a ramp, x(phi(t)) = phi(t): the clock itself, the same for every taxel and channel
    phi = out[:, 0, 0]
    assert torch.allclose(out, phi.reshape(t, 1, 1).expand_as(out))
    assert (phi.diff() > 0).all(), "the warped clock must be strictly increasing"
    assert phi[0] == 0 and phi[-1] == t - 1
    assert (phi - torch.arange(t)).abs().max() > 0.1  # it does warp
    speed, _, _ = random_curves(t, 1, 4, sigma, gen(8))
    assert torch.allclose(phi, warp_clock(speed[:, 0]))


def test_time_warp_resamples_by_linear_interpolation() -> None:
    t = 40
    x = torch.randn(t, 3, 2, dtype=torch.float64)
    out = TimeWarp(0.2)(x, gen(9))
    speed, _, _ = random_curves(t, 1, 4, 0.2, gen(9))
    phi = warp_clock(speed[:, 0]).numpy()
    flat = x.reshape(t, -1).numpy()
    expected = np.stack([np.interp(phi, np.arange(t), flat[:, j]) for j in range(flat.shape[1])], axis=1)
    assert np.allclose(out.reshape(t, -1).numpy(), expected, atol=1e-12)


def test_warp_clock_formula() -> None:
    speed = torch.tensor([5.0, 1.0, 3.0, -2.0])  # the first value never matters, negative speeds are clamped
    phi = warp_clock(speed, min_speed=1e-3)
    raw = np.cumsum([0.0, 1.0, 3.0, 1e-3])
    assert np.allclose(phi.numpy(), raw * 3 / raw[-1])


def test_one_step_sequences_pass_through() -> None:
    x = torch.randn(1, 4, 2)
    for fn in (Jitter(), Scaling(), MagnitudeWarp(), TimeWarp()):
        assert fn(x, gen()).shape == x.shape
    assert torch.equal(TimeWarp()(x, gen()), x)


def test_names_and_errors() -> None:
    assert isinstance(get_augmentation("Time-Warp"), TimeWarp)
    assert get_augmentation("magnitude_warp", sigma=0.1) == MagnitudeWarp(0.1)
    fns = resolve_augmentations(["jitter", Scaling(0.2), "time_warp"])
    assert [type(f) for f in fns] == [Jitter, Scaling, TimeWarp]
    assert resolve_augmentations("scaling") == [Scaling()]
    with pytest.raises(ConfigError, match="unknown augmentation 'wiggle'.*jitter"):
        get_augmentation("wiggle")
    with pytest.raises(ConfigError, match="sigmaa"):
        get_augmentation("jitter", sigmaa=1)
    with pytest.raises(ConfigError, match="floating-point"):
        Jitter()(torch.ones(3, 2, dtype=torch.long), gen())
    with pytest.raises(ConfigError, match="names or callables"):
        resolve_augmentations([3])


def test_amplitude_only_transforms_warn_on_binary_data() -> None:
    with pytest.warns(UserWarning, match="only change amplitudes"):
        resolve_augmentations(["jitter", "scaling"], binary=True, dataset="ev_objects")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        resolve_augmentations(["jitter", "time_warp"], binary=True)


class _Events(TactileDataset):
    """Random binary events (a stand-in for Ev-Objects) to exercise the base class's augment path."""

    name = "test_events"
    sensor = NEUTOUCH
    class_names: ClassVar[tuple[str, ...]] = ("a", "b")
    binary = True
    simulated = True

    def process(self) -> TensorData:
        g = torch.Generator().manual_seed(0)
        x = (torch.rand(20, 30, 39, 2, generator=g) < 0.2).float()
        y = torch.arange(20) % 2
        return TensorData(x, torch.zeros(20, 30, 0), y, torch.arange(20), ("train",) * 16 + ("test",) * 4)


def test_binary_events_are_rebinarised_and_only_time_warp_changes_them() -> None:
    plain = _Events(split="train")
    with pytest.warns(UserWarning, match="only change amplitudes"):
        amp = _Events(split="train", augment=["jitter", "scaling", "magnitude_warp"], augment_factor=2)
    n = len(plain)
    assert len(amp) == 2 * n
    # at sigma 0.05/0.1/0.05 no event flips: re-binarisation undoes amplitude augmentations on event data
    assert torch.equal(amp.x[n:], plain.x)
    warped = _Events(split="train", augment="time_warp", augment_factor=3, augment_seed=1)
    assert len(warped) == 3 * n and set(warped.x.unique().tolist()) <= {0.0, 1.0}
    assert not torch.equal(warped.x[n: 2 * n], plain.x)
    assert torch.equal(warped.y, plain.y.repeat(3)) and torch.equal(warped.groups, plain.groups.repeat(3))
    assert len(_Events(split="val", augment="time_warp", augment_factor=3)) == len(_Events(split="val"))
    with pytest.raises(ConfigError, match="unknown augmentation"):
        _Events(split="train", augment="nope", augment_factor=2)


_shapes = st.lists(st.integers(1, 5), min_size=0, max_size=3).flatmap(
    lambda rest: st.tuples(st.integers(1, 40), st.just(tuple(rest))))


@settings(max_examples=60, deadline=None)
@given(shape=_shapes, dtype=st.sampled_from([torch.float32, torch.float64]), scale=st.floats(1e-3, 1e3),
       seed=st.integers(0, 2**31), name=st.sampled_from(["jitter", "scaling", "magnitude_warp", "time_warp"]))
def test_property_shape_dtype_finiteness(shape: tuple[int, tuple[int, ...]], dtype: torch.dtype, scale: float,
                                         seed: int, name: str) -> None:
    t, rest = shape
    x = (torch.rand((t, *rest), generator=gen(seed), dtype=torch.float64) * 2 - 1).mul(scale).to(dtype)
    fn = get_augmentation(name)
    out = fn(x, gen(seed))
    assert out.shape == x.shape and out.dtype == x.dtype
    assert torch.isfinite(out).all()
    assert torch.equal(out, fn(x, gen(seed)))
    if name == "time_warp":  # a convex combination of neighbouring steps never leaves the data's range
        assert out.max() <= x.max() + 1e-6 * scale and out.min() >= x.min() - 1e-6 * scale
    assert math.isfinite(float(out.double().sum()))


class _Ramps(TactileDataset):
    """x and g both hold the time index, so a shared clock keeps them equal after warping."""

    name = "test_ramps"
    sensor = NEUTOUCH
    class_names: ClassVar[tuple[str, ...]] = ("a", "b")
    simulated = True

    def process(self) -> TensorData:
        t = torch.arange(40, dtype=torch.float32)
        x = t.reshape(1, 40, 1, 1).expand(10, 40, 39, 2).contiguous()
        g = t.reshape(1, 40, 1).expand(10, 40, 3).contiguous()
        return TensorData(x, g, torch.arange(10) % 2, torch.arange(10), ("train",) * 8 + ("test",) * 2)


def test_time_warp_moves_the_global_features_with_the_readings() -> None:
    ds = _Ramps(split="train", augment=["time_warp"], augment_factor=2)
    n = len(ds) // 2
    assert not torch.equal(ds.x[n:], ds.x[:n])  # warped ...
    assert torch.allclose(ds.g[n:], ds.x[n:, :, 0, :1].expand(-1, -1, 3))  # ... with the same clock for g
    amp = _Ramps(split="train", augment=["jitter", "scaling"], augment_factor=2)
    assert torch.equal(amp.g[n:], amp.g[:n]) and not torch.equal(amp.x[n:], amp.x[:n])  # g is not jittered
