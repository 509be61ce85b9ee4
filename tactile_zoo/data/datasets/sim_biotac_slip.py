"""``sim_biotac_slip``: simulated BioTac SP direction-of-slip windows, 7 classes (:class:`SimBiotacSlip`).

``sim_biotac_slip`` (BioTac SP, 24 electrodes, C = 1; 7 classes in BioTac-DoS label order n, s, e, w, cw, aw, t;
T = 30 readings at 100 Hz)
    *Surface chart*: the electrodes' 3-D coordinates are unrolled around the finger's long axis,
    ``u = x`` (towards the tip is north), ``v = 0.3 * atan2(z, -y)`` (east is +v, the electrode-e3 side).
    *Contact patch*: an elliptic Gaussian pressure patch (semi-axes 0.10-0.18 and 0.45-0.8 of that, any orientation)
    pressing with a depth of 450-1100 raw units. Translational slip moves it north/south/east/west (direction +- 0.25
    rad, 0.003-0.008 chart units per reading); rotational slip turns it about a pivot near its centre by 0.02-0.05
    rad per reading, clockwise (``cw``, as drawn on the chart with north up and east right) or anticlockwise
    (``aw``), and twists the skin, which is anchored at the nail: a quadrupole of compression and stretch about the
    contact (cw compresses the north-east and south-west quadrants, 10-25 % of the patch pressure, building up over
    about 4 readings); stable touch (``t``) only has the tremor every class has (a random walk of centre and
    angle). Skin pile-up ahead of a moving contact adds ``beta * (p(t+1) - p(t))`` (beta ~ U(1.5, 3)), so a
    single reading already shows the motion's leading edge; slipping contacts unload by up to 15 % over the window.
    *Electrodes*: raw impedance-like integers that DROP under contact: ``E = baseline + drift * t - gain * pressure +
    noise``, baselines U(3050, 3650), gains lognormal 0.15, thermal drift N(0, 0.25) units per reading, noise N(0, 8),
    rounded and clipped to the 12-bit range, so values lie roughly in 1900-3750 as in the release.
    *Normalisation* (what the real ``biotac_dos`` loader is expected to apply): per electrode, the baseline ``b`` is the
    mean of the recording's first 10 readings, taken before contact (30-120 readings before the window, so drift makes
    it imperfect), and ``x = (b - E) / 1000``: 0 at rest, positive under pressure, 1.0 = a drop of 1000 raw units.

See :mod:`._simulator` for what every simulator shares (seeding, splits, default sizes).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from ...registry import register_dataset
from ..sensors import BIOTAC_SP, Sensor
from ._simulator import SIM_EPOCH_BUDGET, _Simulator

__all__ = ["SimBiotacSlip"]

_DOS_CLASSES = ("n", "s", "e", "w", "cw", "aw", "t")
_DOS_TRANSLATION = {0: 0.0, 1: math.pi, 2: math.pi / 2, 3: -math.pi / 2}  # angle from north (+u) towards east (+v)
_DOS_BASELINE_READINGS = 10
_DOS_SCALE = 1000.0


def _biotac_chart() -> np.ndarray:
    """Electrode coordinates ``(24, 2)`` on the unrolled pad surface: ``u`` along the finger, ``v`` around it."""
    xyz = np.asarray(BIOTAC_SP.positions)
    return np.stack([xyz[:, 0], 0.3 * np.arctan2(xyz[:, 2], -xyz[:, 1])], axis=-1)


def _biotac_raw(rng: np.random.Generator, y: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Raw electrode readings of the window ``(S, T, 24)`` and each recording's pre-contact baseline ``(S, 24)``."""
    s, chart = len(y), _biotac_chart()
    n_e = chart.shape[0]
    centre0 = np.stack([rng.uniform(-0.12, 0.18, s), rng.uniform(-0.08, 0.08, s)], axis=-1)
    major = rng.uniform(0.10, 0.18, s)
    minor = major * rng.uniform(0.45, 0.8, s)
    phi0 = rng.uniform(0.0, math.pi, s)
    depth = rng.uniform(450.0, 1100.0, s)
    beta = rng.uniform(1.5, 3.0, s)

    k = np.arange(steps + 1)  # one extra pose for the pile-up (look-ahead) term
    translating = np.isin(y, list(_DOS_TRANSLATION))
    heading = np.array([_DOS_TRANSLATION.get(int(c), 0.0) for c in y]) + rng.normal(0.0, 0.25, s)
    speed = np.where(translating, rng.uniform(0.003, 0.008, s), 0.0)
    # angles run from north towards east, i.e. clockwise on a chart drawn north up, east right: cw spins positive
    spin = rng.uniform(0.02, 0.05, s) * np.select([y == 4, y == 5], [1.0, -1.0], 0.0)
    pivot = centre0 + rng.normal(0.0, 0.03, (s, 2))

    # poses (S, T+1): angle, centre
    phi = phi0[:, None] + spin[:, None] * k + np.cumsum(rng.normal(0.0, 0.005, (s, steps + 1)), axis=1)
    turn = spin[:, None] * k  # rotation of the centre about the pivot
    off = centre0 - pivot
    cos_t, sin_t = np.cos(turn), np.sin(turn)
    rot_centre = pivot[:, None, :] + np.stack([cos_t * off[:, None, 0] - sin_t * off[:, None, 1],
                                               sin_t * off[:, None, 0] + cos_t * off[:, None, 1]], axis=-1)
    glide = (speed[:, None] * k)[..., None] * np.stack([np.cos(heading), np.sin(heading)], axis=-1)[:, None, :]
    tremor = np.cumsum(rng.normal(0.0, 0.0015, (s, steps + 1, 2)), axis=1)
    centre = rot_centre + glide + tremor  # (S, T+1, 2)

    du = chart[None, None, :, 0] - centre[..., 0:1]  # (S, T+1, E)
    dv = chart[None, None, :, 1] - centre[..., 1:2]
    cp, sp = np.cos(phi)[..., None], np.sin(phi)[..., None]
    q = ((du * cp + dv * sp) / major[:, None, None]) ** 2 + ((-du * sp + dv * cp) / minor[:, None, None]) ** 2
    p = np.exp(-0.5 * q)  # (S, T+1, E)
    p = p[:, :-1] + beta[:, None, None] * (p[:, 1:] - p[:, :-1])  # skin piles up ahead of the motion
    # torsion: skin anchored at the nail, dragged round by a rotating contact, is compressed in one pair of opposite
    # quadrants about the contact and stretched in the other (cw compresses north-east and south-west); the
    # stretch builds up over the first readings of the slip and then saturates
    du, dv = du[:, :-1], dv[:, :-1]
    quad = du * dv / 0.12 ** 2 * np.exp(-0.5 * (du ** 2 + dv ** 2) / 0.15 ** 2)
    torsion = np.sign(spin) * rng.uniform(0.1, 0.25, s)
    p = p + torsion[:, None, None] * (1.0 - np.exp(-np.arange(steps) / 4.0))[None, :, None] * quad
    unload = np.where(y == 6, rng.uniform(-0.03, 0.03, s), rng.uniform(-0.15, 0.02, s))
    load = depth[:, None] * (1.0 + unload[:, None] * np.arange(steps) / 30.0)  # (S, T)
    pressure = np.clip(p, 0.0, None) * load[..., None]

    # electrodes: baseline + drift - gain * pressure + noise, in raw ADC units
    base = rng.uniform(3050.0, 3650.0, (s, n_e))
    drift = rng.normal(0.0, 0.25, (s, n_e))
    gain = rng.lognormal(0.0, 0.15, (s, n_e))
    gap = rng.integers(30, 121, s)  # readings between the pre-contact baseline and the window
    pre_t = np.arange(_DOS_BASELINE_READINGS)
    pre = base[:, None] + drift[:, None] * pre_t[None, :, None] + rng.normal(0.0, 8.0, (s, len(pre_t), n_e))
    win_t = (_DOS_BASELINE_READINGS + gap)[:, None] + np.arange(steps)[None]  # (S, T)
    raw = (base[:, None] + drift[:, None] * win_t[..., None] - gain[:, None] * pressure
           + rng.normal(0.0, 8.0, (s, steps, n_e)))
    raw = np.clip(np.rint(raw), 0, 4095)
    baseline = np.clip(np.rint(pre), 0, 4095).mean(axis=1)
    return raw, baseline


@register_dataset(
    "sim_biotac_slip", sensor="biotac_sp", num_classes=7, class_names=_DOS_CLASSES, num_steps=30, num_nodes=24,
    num_channels=1, num_globals=0, num_samples=294, folds=1, protocol="fixed", splits=("train", "val", "test"),
    simulated=True, max_epochs=SIM_EPOCH_BUDGET, revision=1, licence="generated (MIT, part of tactile-zoo)",
    description="Simulated BioTac SP direction of slip (BioTac-DoS label order): an elliptic contact patch moving "
                "N/S/E/W, rotating CW/CCW or still, read as baseline-removed electrode impedance drops")
class SimBiotacSlip(_Simulator):
    """Simulated BioTac SP slip-direction windows, 7 classes (see the module docstring for the model)."""

    name = "sim_biotac_slip"
    sensor: ClassVar[Sensor] = BIOTAC_SP
    class_names = _DOS_CLASSES
    default_train, default_test, default_steps, min_steps = 30, 12, 30, 5
    frame_period = 0.01  # 100 Hz readings; num_steps lengthens the window, it does not resample it

    @classmethod
    def simulate(cls, rng: np.random.Generator, y: np.ndarray, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
        raw, baseline = _biotac_raw(rng, y, num_steps)
        x = (baseline[:, None, :] - raw) / _DOS_SCALE  # (S, T, 24)
        return x[..., None], np.zeros((len(y), num_steps, 0), dtype=np.float32)

