"""``sim_evtouch``: simulated NeuTouch grasps of 10 objects, encoded as ON/OFF events (:class:`SimEvTouch`).

``sim_evtouch`` (NeuTouch, 39 taxels, C = 2 ON/OFF event channels, values 0/1; 10 objects; T = 100)
    *Per class* (an object): contact geometry and curvature (sphere, cylinder, sharp edge, flat face, annular rim;
    radius of curvature), stiffness (Young's modulus), grip ramp duration, viscoelastic relaxation during the hold,
    how far it slips when lifted, and a surface texture (amplitude and wavelength of a periodic relief).
    *Physics*: the grip force ramps up with a smoothstep from a contact onset, holds (soft objects relax), then the
    object is lifted and slips a little along gravity (the grip tightens 35 % against the load). Pressure on the pad
    follows Hertz contact theory: a sphere gives ``p0 sqrt(1 - r^2/a^2)`` with ``a = (3FR/4E)^(1/3)`` and
    ``p0 = 3F/(2 pi a^2)``; a cylinder, edge or rim gives the line-contact profile ``p0 sqrt(1 - d^2/b^2)`` with
    ``b = sqrt(4F'R/(pi E))``, ``p0 = 2F'/(pi b)`` and ``F'`` the force per unit contact length; a flat face gives a
    near-uniform pressure with stiffness-dependent edge concentration. The texture multiplies the pressure in the
    object's frame, so it moves with the object when it slips and produces vibration-like event bursts.
    *Per sample*: contact centre (N(0, 1.2 mm) per axis), axis orientation, grip force (x U(0.7, 1.3)), modulus
    (x lognormal 0.15), radius (x lognormal 0.1), onset time, ramp duration (x lognormal 0.2), hold duration, slip
    distance (x lognormal 0.3) and direction (gravity +- 0.4 rad), texture phase, a tremor random walk of the contact
    centre.
    *Sensor and event encoding* (as NeuTouch/DVS): per-taxel gain (lognormal 0.15) and additive pressure noise; each
    taxel tracks the log pressure ``log(p + p_floor)`` against a reference level and emits an ON (OFF) event in a bin
    where it has risen (fallen) by at least its threshold (``N(0.25, 0.04)`` per taxel, a fabrication mismatch), the
    reference then moving by whole thresholds; 5 % of events are dropped and background events fire with
    probability 0.002 per bin and channel.

See :mod:`._simulator` for what every simulator shares (seeding, splits, default sizes).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from ...registry import register_dataset
from ..sensors import NEUTOUCH, Sensor
from ._simulator import SIM_EPOCH_BUDGET, _Simulator, _smoothstep

__all__ = ["SimEvTouch"]

_SPHERE, _CYLINDER, _FLAT, _RING = 0, 1, 2, 3
_EV_CLASSES = (
    # name,          shape,     R/half-size mm, E,   ramp, relax, slip mm, texture amp, texture wavelength mm
    ("small_ball",   _SPHERE,   8.0,  1.00, 0.08, 0.02, 1.0, 0.00, 4.0),
    ("large_ball",   _SPHERE,  25.0,  1.00, 0.08, 0.02, 0.6, 0.00, 4.0),
    ("foam_ball",    _SPHERE,  15.0,  0.25, 0.20, 0.40, 0.5, 0.15, 3.0),
    ("marker",       _CYLINDER, 6.0,  1.00, 0.08, 0.02, 1.5, 0.00, 4.0),
    ("bottle",       _CYLINDER, 30.0, 0.50, 0.12, 0.15, 2.0, 0.05, 6.0),
    ("box_edge",     _CYLINDER, 1.0,  1.00, 0.08, 0.03, 0.8, 0.00, 4.0),
    ("cracker_box",  _FLAT,    12.0,  0.80, 0.10, 0.05, 1.2, 0.05, 8.0),
    ("sponge",       _FLAT,    12.0,  0.15, 0.25, 0.45, 0.4, 0.30, 2.5),
    ("cup_rim",      _RING,     2.0,  1.00, 0.08, 0.02, 1.0, 0.00, 4.0),
    ("rubiks_cube",  _FLAT,    12.0,  1.00, 0.08, 0.02, 1.5, 0.50, 5.5),
)
_EV_TABLE = np.array([row[1:] for row in _EV_CLASSES], dtype=np.float64)
_EV_FORCE = 10.0  # nominal grip force: makes contact radii a few mm on a pad of radius ~9 mm
_EV_LINE_LENGTH = 12.0  # mm of a cylinder or edge in contact with the pad
_EV_RIM_RADIUS = 6.0  # mm, radius of the cup rim's annulus
_EV_P_SCALE = 0.1  # typical pressure; log encoding sees p / _EV_P_SCALE
_EV_FLOOR = 0.05  # log(p + floor): the floor sets how small a pressure change can still cross a threshold


def _evtouch_pressure(rng: np.random.Generator, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pad pressure ``(S, T, N)`` for objects ``y`` at episode times ``t`` in [0, 1)."""
    s, pos = len(y), np.asarray(NEUTOUCH.positions)  # (N, 2) mm
    shape, radius, modulus, ramp, relax, slip, tex_amp, tex_wl = _EV_TABLE[y].T
    # per-sample variation
    centre = rng.normal(0.0, 1.2, (s, 2))
    theta = rng.uniform(0.0, math.pi, s)  # cylinder / edge axis, texture orientation
    force = _EV_FORCE * rng.uniform(0.7, 1.3, s)
    modulus = modulus * rng.lognormal(0.0, 0.15, s)
    radius = radius * rng.lognormal(0.0, 0.1, s)
    onset = rng.uniform(0.06, 0.16, s)
    ramp = ramp * rng.lognormal(0.0, 0.2, s)
    lift = onset + ramp + rng.uniform(0.15, 0.3, s)
    slip = slip * rng.lognormal(0.0, 0.3, s)
    slip_angle = rng.normal(0.0, 0.4, s)  # gravity pulls along +x of the pad
    tex_phase = rng.uniform(0.0, 2 * math.pi, s)

    tt = t[None, :]  # (1, T)
    u = _smoothstep((tt - onset[:, None]) / ramp[:, None])
    hold = np.clip(tt - (onset + ramp)[:, None], 0.0, None)
    w = _smoothstep((tt - lift[:, None]) / 0.12)  # lift phase, 0 -> 1
    f = force[:, None] * u * (1.0 - relax[:, None] * (1.0 - np.exp(-hold / 0.15))) * (1.0 + 0.35 * w)  # (S, T)
    f = np.maximum(f, 1e-9)

    tremor = np.cumsum(rng.normal(0.0, 0.03, (s, len(t), 2)), axis=1)
    direction = np.stack([np.cos(slip_angle), np.sin(slip_angle)], axis=-1)  # (S, 2)
    centre_t = centre[:, None, :] + (slip[:, None] * w)[..., None] * direction[:, None, :] + tremor  # (S, T, 2)
    rel = pos[None, None] - centre_t[:, :, None, :]  # (S, T, N, 2) taxel positions in the object's frame
    r = np.linalg.norm(rel, axis=-1)  # (S, T, N)
    normal = np.stack([-np.sin(theta), np.cos(theta)], axis=-1)  # (S, 2) perpendicular to the axis
    d_line = np.abs(np.einsum("stnk,sk->stn", rel, normal))

    # Hertz contact: sphere (point contact) and cylinder/edge/rim (line contact)
    rr, ee, ff = radius[:, None, None], modulus[:, None, None], f[:, :, None]
    a = np.cbrt(3.0 * ff * rr / (4.0 * ee))
    p_sphere = 3.0 * ff / (2 * math.pi * a ** 2) * np.sqrt(np.clip(1.0 - (r / a) ** 2, 0.0, None))
    is_ring = (shape == _RING)[:, None, None]
    length = np.where(is_ring, 2 * math.pi * _EV_RIM_RADIUS, _EV_LINE_LENGTH)
    fl = ff / length
    b = np.sqrt(4.0 * fl * rr / (math.pi * ee))
    d = np.where(is_ring, np.abs(r - _EV_RIM_RADIUS), d_line)
    p_line = 2.0 * fl / (math.pi * b) * np.sqrt(np.clip(1.0 - (d / b) ** 2, 0.0, None))
    # a flat face wider than the pad: near-uniform, edge concentration growing with stiffness
    edge = (0.8 * ee / (ee + 0.5))
    p_flat = ff / (math.pi * rr ** 2) * (1.0 + edge * (r / rr) ** 4) * (r < rr)
    p = np.select([(shape == _SPHERE)[:, None, None], (shape == _FLAT)[:, None, None]], [p_sphere, p_flat], p_line)

    # surface relief in the object's frame (moves with the object when it slips)
    along = np.einsum("stnk,sk->stn", rel, np.stack([np.cos(theta), np.sin(theta)], axis=-1))
    relief = np.cos(2 * math.pi * along / tex_wl[:, None, None] + tex_phase[:, None, None])
    return p * (1.0 + tex_amp[:, None, None] * relief)


def _log_events(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    """NeuTouch-like ON/OFF events ``(S, T, N, 2)`` from pressure ``(S, T, N)``."""
    s, steps, n = p.shape
    gain = rng.lognormal(0.0, 0.15, (s, 1, n))
    noisy = np.clip(p * gain / _EV_P_SCALE + rng.normal(0.0, 0.01, p.shape), 0.0, None)
    level = np.log(noisy + _EV_FLOOR)
    thresh = np.clip(rng.normal(0.25, 0.04, (s, n)), 0.1, None)
    events = np.zeros((s, steps, n, 2), dtype=np.float32)
    ref = level[:, 0].copy()
    for k in range(1, steps):  # the reference level is a per-taxel state: inherently sequential in time
        crossings = np.trunc((level[:, k] - ref) / thresh)
        events[:, k, :, 0] = crossings > 0
        events[:, k, :, 1] = crossings < 0
        ref += crossings * thresh
    events *= rng.random(events.shape) >= 0.05  # dropped events
    events[rng.random(events.shape) < 0.002] = 1.0  # background activity
    return events


@register_dataset(
    "sim_evtouch", sensor="neutouch", num_classes=len(_EV_CLASSES), class_names=tuple(r[0] for r in _EV_CLASSES),
    num_steps=100, num_nodes=39, num_channels=2, num_globals=0, num_samples=280, folds=1, protocol="fixed",
    splits=("train", "val", "test"), simulated=True, max_epochs=SIM_EPOCH_BUDGET, revision=1,
    licence="generated (MIT, part of tactile-zoo)",
    description="Simulated event-based grasping on NeuTouch: Hertz contact pressure of 10 objects (shape, size, "
                "stiffness, texture) during grasp, hold and lift-induced slip, encoded as ON/OFF log-pressure events")
class SimEvTouch(_Simulator):
    """Simulated NeuTouch grasps of 10 objects as ON/OFF events (see the module docstring for the model)."""

    name = "sim_evtouch"
    sensor: ClassVar[Sensor] = NEUTOUCH
    class_names = tuple(r[0] for r in _EV_CLASSES)
    binary = True
    default_train, default_test, default_steps, min_steps = 20, 8, 100, 20

    @classmethod
    def simulate(cls, rng: np.random.Generator, y: np.ndarray, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(num_steps) / num_steps
        x = _log_events(rng, _evtouch_pressure(rng, y, t))  # (S, T, N, 2)
        return x, np.zeros((len(y), num_steps, 0), dtype=np.float32)

