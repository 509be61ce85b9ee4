"""The four time-series augmentations of Um et al. (2017) that the X-Tacformer paper applies (its section IV).

Um, Pfister, Pichler, Endo, Lang, Hirche, Fietzek, Kulic: "Data Augmentation of Wearable Sensor Data for Parkinson's
Disease Monitoring using Convolutional Neural Networks", ICMI 2017.

Each transform is ``f(x, generator) -> x'`` on one sample ``x [T, ...]`` (time first; every trailing element, e.g.
each (taxel, channel) pair of ``x [T, N, C]``, is one *signal*). All randomness comes from the explicit
``torch.Generator``, so a seed reproduces an augmented dataset; shape, dtype and device are kept.

* :class:`Jitter`: ``x' = x + eps``, ``eps ~ N(0, sigma^2)`` per element (sigma 0.05).
* :class:`Scaling`: ``x'[t, s] = x[t, s] * a_s``, one factor ``a_s ~ N(1, sigma^2)`` per signal (sigma 0.1).
* :class:`MagnitudeWarp`: ``x'[t, s] = x[t, s] * c_s(t)``; ``c_s`` is a cubic spline (scipy, not-a-knot) through
  ``knots + 2`` evenly spaced knots from ``t = 0`` to ``t = T - 1`` (4 interior knots plus both ends, as in Um et
  al.'s code), knot values ``~ N(1, sigma^2)`` (sigma 0.05), one curve per signal.
* :class:`TimeWarp`: one random speed curve ``v(t)`` per sample (the same kind of spline, sigma 0.2), shared by all
  signals; the warped clock ``phi(0) = 0, phi(t) = sum_{s=1..t} max(v(s), 1e-3)``, rescaled so ``phi(T-1) = T-1``,
  is strictly increasing (the clamp keeps it monotone even for a spline dipping below zero); ``x'[t] = x(phi(t))``
  by linear interpolation between neighbouring steps. With sigma 0 the warp is the identity.

On binary event data (Ev-Objects / Ev-Containers) the dataset base class re-binarises augmented copies at 0.5. At the
paper's sigmas this erases the three amplitude transforms (a jitter of 0.05 flips an event with probability about
``2 * Phi(-10) ~ 1.5e-23``; a scaling or warp factor below 0.5 is a 5- or 10-sigma draw), so only time warping
changes event data: interpolating 0/1 values and thresholding at 0.5 resamples each event stream at the
nearest-neighbour warped time, dropping or repeating events where the clock speeds up or slows down.
:func:`resolve_augmentations` warns when every requested transform would be a no-op on binary data.

Inside a dataset (``augment=``), :func:`apply_augmentation` time-warps the global features ``g`` with the same clock
as the readings (so joint angles stay in step with the taxels); the amplitude transforms change ``x`` only.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch

from ..errors import ConfigError

__all__ = ["Jitter", "Scaling", "MagnitudeWarp", "TimeWarp", "random_curves", "warp_clock", "get_augmentation",
           "resolve_augmentations", "apply_augmentation", "AUGMENTATIONS"]

Augmentation = Callable[[torch.Tensor, torch.Generator], torch.Tensor]


def _check(x: torch.Tensor, what: str) -> None:
    if not torch.is_floating_point(x):
        raise ConfigError(f"{what} needs a floating-point tensor, got {x.dtype}")
    if x.dim() < 1:
        raise ConfigError(f"{what} needs a tensor with a time dimension first, got a scalar")


def _randn(shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
    # float64 draws on the generator's device: the same seed gives the same sample whatever x's dtype/device
    return torch.randn(shape, generator=generator, dtype=torch.float64, device=generator.device)


def random_curves(num_steps: int, num_curves: int, knots: int, sigma: float, generator: torch.Generator
                  ) -> tuple[torch.Tensor, np.ndarray, torch.Tensor]:
    """Smooth random curves around 1: ``(curves [T, num_curves], knot_times [K], knot_values [K, num_curves])``.

    ``K = knots + 2`` knots evenly spaced over ``[0, T - 1]`` with values ``~ N(1, sigma^2)``, joined by a cubic
    spline evaluated at ``t = 0..T-1``. A one-step sequence gets the first knot's value.
    """
    if knots < 0 or sigma < 0:
        raise ConfigError(f"knots and sigma must be non-negative, got knots={knots}, sigma={sigma}")
    values = 1.0 + sigma * _randn((knots + 2, num_curves), generator).cpu()
    times = np.linspace(0.0, num_steps - 1.0, knots + 2)
    if num_steps < 2:
        return values[:1].clone(), times, values
    # imported here: scipy.interpolate costs 0.4 s, paid by every import of the package otherwise
    from scipy.interpolate import CubicSpline

    curves = CubicSpline(times, values.numpy(), axis=0)(np.arange(num_steps, dtype=np.float64))
    return torch.from_numpy(np.ascontiguousarray(curves)), times, values


def warp_clock(speed: torch.Tensor, min_speed: float = 1e-3) -> torch.Tensor:
    """The warped clock ``phi [T]`` (float64) of a speed curve ``[T]``: ``phi(0) = 0``, ``phi(T-1) = T-1``, strictly
    increasing, with increments proportional to ``max(speed, min_speed)``."""
    steps = speed.to(torch.float64).clamp_min(min_speed)[1:]
    phi = torch.cat([steps.new_zeros(1), torch.cumsum(steps, 0)])
    n = speed.shape[0]
    if n < 2:
        return phi
    phi = phi * ((n - 1) / phi[-1])
    phi[-1] = n - 1  # exact end point despite rounding
    return phi


@dataclass(frozen=True)
class Jitter:
    """Additive Gaussian noise: ``x' = x + N(0, sigma^2)`` per element."""

    sigma: float = 0.05
    amplitude_only: ClassVar[bool] = True
    warps_time: ClassVar[bool] = False

    def __call__(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        _check(x, "jitter")
        noise = _randn(tuple(x.shape), generator).to(device=x.device, dtype=x.dtype)
        return x + self.sigma * noise


@dataclass(frozen=True)
class Scaling:
    """One multiplicative factor ``~ N(1, sigma^2)`` per signal (every trailing element), constant over time."""

    sigma: float = 0.1
    amplitude_only: ClassVar[bool] = True
    warps_time: ClassVar[bool] = False

    def __call__(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        _check(x, "scaling")
        factor = 1.0 + self.sigma * _randn((1, *x.shape[1:]), generator)  # (1, ...) broadcast over time
        return x * factor.to(device=x.device, dtype=x.dtype)


@dataclass(frozen=True)
class MagnitudeWarp:
    """Each signal times its own smooth random curve around 1 (cubic spline through ``knots + 2`` knots)."""

    sigma: float = 0.05
    knots: int = 4
    amplitude_only: ClassVar[bool] = True
    warps_time: ClassVar[bool] = False

    def __call__(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        _check(x, "magnitude warp")
        t = x.shape[0]
        signals = int(np.prod(x.shape[1:], dtype=np.int64))
        curves, _, _ = random_curves(t, signals, self.knots, self.sigma, generator)  # (T, S)
        return x * curves.reshape(x.shape).to(device=x.device, dtype=x.dtype)  # (T, ...) again


@dataclass(frozen=True)
class TimeWarp:
    """Resample the whole sample along a smooth, monotone random clock shared by all signals."""

    sigma: float = 0.2
    knots: int = 4
    amplitude_only: ClassVar[bool] = False
    warps_time: ClassVar[bool] = True

    def __call__(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        _check(x, "time warp")
        t = x.shape[0]
        speed, _, _ = random_curves(t, 1, self.knots, self.sigma, generator)
        if t < 2:
            return x.clone()
        phi = warp_clock(speed[:, 0])  # (T,) float64, 0 .. T-1
        lo = phi.floor().long().clamp(0, t - 2)
        frac = (phi - lo).to(device=x.device, dtype=x.dtype).reshape(t, *([1] * (x.dim() - 1)))
        lo = lo.to(x.device)
        # linear interpolation x(phi) = (1 - a) x[lo] + a x[lo + 1]; frac is exactly 0 or 1 at integer phi
        return x[lo] * (1 - frac) + x[lo + 1] * frac


def apply_augmentation(fn: Augmentation, x: torch.Tensor, g: torch.Tensor, generator: torch.Generator
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """Augment one sample ``(x [T, N, C], g [T, G])``.

    A transform that distorts time (``warps_time``) is applied once to the readings and the global features
    together, so joint angles / finger positions stay in step with the taxels; every other transform changes the
    tactile readings ``x`` only (proprioception is not jittered or scaled).
    """
    if not getattr(fn, "warps_time", False) or g.shape[-1] == 0:
        return fn(x, generator), g
    t = x.shape[0]
    joint = torch.cat([x.reshape(t, -1), g.to(x.dtype)], dim=1)  # (T, N*C + G)
    out = fn(joint, generator)
    return out[:, : joint.shape[1] - g.shape[-1]].reshape(x.shape), out[:, joint.shape[1] - g.shape[-1]:].to(g.dtype)


AUGMENTATIONS: dict[str, type] = {"jitter": Jitter, "scaling": Scaling, "magnitude_warp": MagnitudeWarp,
                                  "time_warp": TimeWarp}


def _key(name: str) -> str:
    return "".join(ch for ch in name.lower() if ch.isalnum())


def get_augmentation(name: str, **params: float) -> Augmentation:
    """An augmentation by name (``jitter``, ``scaling``, ``magnitude_warp``, ``time_warp``; case, ``-`` and ``_``
    ignored) with optional parameters, e.g. ``get_augmentation("time_warp", sigma=0.1)``."""
    by_key = {_key(k): v for k, v in AUGMENTATIONS.items()}
    cls = by_key.get(_key(name))
    if cls is None:
        raise ConfigError(f"unknown augmentation {name!r}; choose from {', '.join(AUGMENTATIONS)}")
    try:
        return cls(**params)
    except TypeError as exc:
        raise ConfigError(f"augmentation {name!r}: {exc}") from exc


def resolve_augmentations(augment: str | Augmentation | Sequence[str | Augmentation] | None, binary: bool = False,
                          dataset: str = "") -> list[Augmentation]:
    """Turn the ``augment=`` argument of a dataset (a name, a callable, or a sequence of them) into callables.

    With ``binary=True`` (event data, re-binarised after augmenting) a warning says when every transform only
    changes amplitudes, which re-binarisation undoes.
    """
    if augment is None:
        return []
    items = [augment] if isinstance(augment, str) or callable(augment) else list(augment)
    fns: list[Augmentation] = []
    for item in items:
        if isinstance(item, str):
            fns.append(get_augmentation(item))
        elif callable(item):
            fns.append(item)
        else:
            raise ConfigError(f"augment= takes names or callables f(x, generator) -> x, got {type(item).__name__}")
    if binary and fns and all(getattr(fn, "amplitude_only", False) for fn in fns):
        warnings.warn(f"{dataset or 'this dataset'} holds binary events that augmented copies are re-binarised to; "
                      f"{', '.join(type(fn).__name__ for fn in fns)} only change amplitudes and are undone by that "
                      f"(use time_warp)", UserWarning, stacklevel=3)
    return fns
