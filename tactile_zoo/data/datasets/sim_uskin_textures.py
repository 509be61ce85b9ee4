"""``sim_uskin_textures``: simulated rubbing of 10 fabrics by two uSkin fingertips on an Allegro hand
(:class:`SimUskinTextures`).

``sim_uskin_textures`` (two uSkin fingertips on an Allegro hand, 60 taxels, C = 3 axes x, y, z; G = 8 joint angles;
10 fabrics; T = 50)
    *Per class* (a fabric): spatial frequency of the weave (0.08-0.55 cycles/mm) and its relief, roughness (the
    amplitude of a broadband random relief), friction coefficient (shear/normal ratio), compliance, stick-slip depth.
    *Stroke*: both fingertips press on the fabric and rub it forward then back along the fingertip's long axis (minimum
    jerk profiles, stroke 25-35 mm, the turn at 45-55 % of the episode). A taxel at fabric coordinate ``s`` sees the
    relief ``h(s)``: the weave plus 12 random-phase sinusoids, each component attenuated by the taxel's aperture
    (``sinc(f * 3 mm)``) and by the fabric's compliance (``exp(-2 c f)``).
    *Forces*: normal ``z = F * profile * (1 + 0.6 h)`` with a Gaussian fingertip contact profile that widens with
    compliance (total force kept); shear along the stroke ``x = mu * z * tanh(v / v0) * (1 + stick-slip sawtooth) +
    slope term``, reversing with the stroke, low-passed with a compliance-dependent lag; lateral shear ``y`` from the
    weave's slant. Each taxel-axis has a gain (lognormal 0.05), an offset (N(0, 0.015)), 5 % normal-to-shear crosstalk
    and noise N(0, 0.025) per step.
    *Joint angles* (index and middle finger, 4 joints each, radians): a posture (N(0, 0.05) around a nominal grasp),
    plus a linear map of the stroke position, plus flexion growing with pressing depth (force x compliance), plus a
    friction-dependent tracking lag, plus encoder noise N(0, 0.01) and a random walk.
    *Per sample*: friction (x lognormal 0.08), weave frequency (x lognormal 0.08), roughness (x lognormal 0.2),
    compliance (x lognormal 0.1), pressing force U(0.85, 1.15), contact centre (N(0, 0.25) taxel pitches), stroke
    length and timing, stick-slip rate, relief phases and roughness spectrum.

See :mod:`._simulator` for what every simulator shares (seeding, splits, default sizes).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from ...registry import register_dataset
from ..sensors import USKIN_ALLEGRO, Sensor
from ._simulator import SIM_EPOCH_BUDGET, _min_jerk, _Simulator

__all__ = ["SimUskinTextures"]

_TEX_CLASSES = (
    # name,       weave cycles/mm, weave relief, roughness, friction, compliance, stick-slip
    ("silk",       0.55, 0.05, 0.05, 0.15, 0.15, 0.00),
    ("nylon",      0.30, 0.10, 0.10, 0.28, 0.15, 0.05),
    ("polyester",  0.35, 0.10, 0.15, 0.30, 0.45, 0.05),
    ("cotton",     0.30, 0.15, 0.25, 0.45, 0.40, 0.10),
    ("linen",      0.20, 0.20, 0.40, 0.42, 0.15, 0.10),
    ("denim",      0.25, 0.25, 0.35, 0.60, 0.20, 0.15),
    ("corduroy",   0.12, 0.60, 0.30, 0.55, 0.55, 0.10),
    ("wool",       0.15, 0.20, 0.50, 0.70, 0.70, 0.20),
    ("felt",       0.08, 0.05, 0.20, 0.85, 0.90, 0.25),
    ("fleece",     0.10, 0.10, 0.60, 0.60, 1.10, 0.15),
)
_TEX_TABLE = np.array([row[1:] for row in _TEX_CLASSES], dtype=np.float64)
_USKIN_PITCH = 4.7  # mm between taxel centres
_USKIN_APERTURE = 3.0  # mm, sensing width of one taxel
_ALLEGRO_POSTURE = np.array([0.0, 0.9, 0.8, 0.6, 0.0, 0.9, 0.8, 0.6])  # index then middle finger, radians
_ALLEGRO_STROKE = np.array([0.001, 0.012, 0.010, 0.006, -0.001, 0.011, 0.010, 0.007])  # rad per mm of stroke
_ALLEGRO_PRESS = np.array([0.0, 0.05, 0.08, 0.05, 0.0, 0.05, 0.08, 0.05])  # rad per unit pressing depth


def _uskin_local() -> tuple[np.ndarray, np.ndarray]:
    """Per taxel: (row, column) within its fingertip ``(60, 2)`` and fingertip id ``(60,)``."""
    grid = np.asarray(USKIN_ALLEGRO.grid, dtype=np.float64)
    tip = np.asarray(USKIN_ALLEGRO.groups)
    return np.stack([grid[:, 0], grid[:, 1] - 6 * tip], axis=-1), tip


def _relief(freqs: np.ndarray, amps: np.ndarray, phases: np.ndarray, coord: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Height and slope ``(S, T, L)`` of a sum of sinusoids (components ``(S, K)``) at fabric coordinates
    ``coord (S, T, L)`` in mm."""
    arg = 2 * math.pi * freqs[:, None, None, :] * coord[..., None] + phases[:, None, None, :]  # (S, T, N, K)
    amp = amps[:, None, None, :]
    return (amp * np.sin(arg)).sum(-1), (amp * 2 * math.pi * freqs[:, None, None, :] * np.cos(arg)).sum(-1)


def _uskin_rub(rng: np.random.Generator, y: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Taxel forces ``(S, T, 60, 3)`` and joint angles ``(S, T, 8)`` of a forward-and-back rubbing stroke."""
    s = len(y)
    local, tip = _uskin_local()
    freq, weave, rough, mu, comp, stick = _TEX_TABLE[y].T
    freq = freq * rng.lognormal(0.0, 0.08, s)
    rough = rough * rng.lognormal(0.0, 0.2, s)
    mu = mu * rng.lognormal(0.0, 0.08, s)
    comp = comp * rng.lognormal(0.0, 0.1, s)
    force = rng.uniform(0.85, 1.15, s)

    # stroke: fabric displacement under the fingertips (mm), forward then back
    t = np.arange(steps) / max(steps - 1, 1)
    turn = rng.uniform(0.45, 0.55, s)[:, None]
    length = rng.uniform(25.0, 35.0, s)[:, None]
    stroke = length * np.where(t < turn, _min_jerk(t / turn), 1.0 - _min_jerk((t - turn) / (1.0 - turn)))  # (S, T)
    velocity = np.gradient(stroke, axis=1)  # mm per step
    # fabric coordinate under each (fingertip, row): the stroke runs along the fingertip's rows, so the taxels of one
    # row share it; the two fingertips rub side by side, over unrelated stretches of the fabric
    line_row = np.tile(np.arange(6), 2)  # (12,) row of each fabric line; line = 6 * tip + row
    coord = stroke[:, :, None] + line_row * _USKIN_PITCH + np.repeat(rng.uniform(0, 50.0, (s, 1, 2)), 6, axis=2)
    line = (6 * tip + local[:, 0]).astype(int)  # (60,) fabric line under each taxel

    # relief: the weave (and its second harmonic) plus broadband roughness, attenuated by aperture and compliance
    k_rough = 12
    f_comp = np.concatenate([freq[:, None], 2 * freq[:, None], rng.uniform(0.05, 1.0, (s, k_rough))], axis=1)
    a_comp = np.concatenate([weave[:, None], 0.3 * weave[:, None],
                             rough[:, None] * rng.rayleigh(1.0 / math.sqrt(k_rough), (s, k_rough))], axis=1)
    a_comp = a_comp * np.abs(np.sinc(f_comp * _USKIN_APERTURE)) * np.exp(-2.0 * comp[:, None] * f_comp)
    height, slope = _relief(f_comp, a_comp, rng.uniform(0, 2 * math.pi, f_comp.shape), coord)  # (S, T, 12)
    height, slope = height[:, :, line], slope[:, :, line]  # (S, T, 60)

    # fingertip contact profile: a Gaussian patch that widens on compliant fabric, total force preserved
    centre = np.array([3.2, 2.5]) + rng.normal(0.0, 0.25, (s, 2))
    width = 1.2 * (1.0 + 0.5 * comp)
    dist2 = ((local[None] - centre[:, None]) ** 2).sum(-1)  # (S, 60)
    profile = np.exp(-0.5 * dist2 / width[:, None] ** 2)
    profile = profile / profile.sum(1, keepdims=True) * 30.0 / 3.0  # ~ unit peak for the nominal patch
    normal = force[:, None, None] * profile[:, None] * np.clip(1.0 + 0.6 * height, 0.1, None)  # (S, T, 60)

    # shear along the stroke: Coulomb friction smoothed through zero speed, stick-slip sawtooth, relief slope
    direction = np.tanh(velocity / 0.4)[..., None]
    saw = 2.0 * ((t[None, :] * rng.uniform(6.0, 10.0, (s, 1)) + rng.uniform(0, 1, (s, 1))) % 1.0) - 1.0
    fric = mu[:, None, None] * (1.0 + stick[:, None, None] * saw[..., None])
    shear_x = -fric * normal * direction + 0.3 * normal * slope
    # a compliant fabric lets the shear build up with a lag (first-order low-pass along time)
    alpha = (1.0 / (1.0 + 2.0 * comp))[:, None]
    for k in range(1, steps):
        shear_x[:, k] = shear_x[:, k - 1] + alpha * (shear_x[:, k] - shear_x[:, k - 1])
    shear_y = 0.15 * normal * slope * rng.choice([-1.0, 1.0], (s, 1, 1))  # the weave's slant
    forces = np.stack([shear_x, shear_y, normal], axis=-1)  # (S, T, 60, 3)

    # sensor: gain, offset, normal-to-shear crosstalk, noise
    forces = forces * rng.lognormal(0.0, 0.05, (s, 1, 60, 3)) + rng.normal(0.0, 0.015, (s, 1, 60, 3))
    forces[..., :2] += 0.05 * forces[..., 2:3]
    forces += rng.normal(0.0, 0.025, forces.shape)

    # joint angles: posture + stroke kinematics + pressing flexion + friction lag + encoder noise
    posture = _ALLEGRO_POSTURE + rng.normal(0.0, 0.05, (s, 8))
    press = (force * comp)[:, None, None] * _ALLEGRO_PRESS
    lag = -(mu[:, None] * np.tanh(velocity / 0.4))[..., None] * 0.5 * _ALLEGRO_STROKE * _USKIN_PITCH
    joints = (posture[:, None] + stroke[..., None] * _ALLEGRO_STROKE + press + lag
              + np.cumsum(rng.normal(0.0, 0.003, (s, steps, 8)), axis=1) + rng.normal(0.0, 0.01, (s, steps, 8)))
    return forces, joints


@register_dataset(
    "sim_uskin_textures", sensor="uskin_allegro", num_classes=len(_TEX_CLASSES),
    class_names=tuple(r[0] for r in _TEX_CLASSES), num_steps=50, num_nodes=60, num_channels=3, num_globals=8,
    num_samples=280, folds=1, protocol="fixed", splits=("train", "val", "test"), simulated=True,
    max_epochs=SIM_EPOCH_BUDGET, revision=1,
    licence="generated (MIT, part of tactile-zoo)",
    description="Simulated bidirectional fabric rubbing with two uSkin fingertips on an Allegro hand: 10 fabrics "
                "differing in weave frequency, roughness, friction and compliance; 3-axis taxels plus 8 joint angles")
class SimUskinTextures(_Simulator):
    """Simulated ALU-Textures-like rubbing of 10 fabrics (see the module docstring for the model)."""

    name = "sim_uskin_textures"
    sensor: ClassVar[Sensor] = USKIN_ALLEGRO
    class_names = tuple(r[0] for r in _TEX_CLASSES)
    default_train, default_test, default_steps, min_steps = 20, 8, 50, 10

    @classmethod
    def simulate(cls, rng: np.random.Generator, y: np.ndarray, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
        return _uskin_rub(rng, y, num_steps)
