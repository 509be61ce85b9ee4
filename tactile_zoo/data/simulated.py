"""Simulated tactile datasets: the embedded default on a machine without real data.

Three registered datasets, one per sensor family, each generated from a seed in well under a second with numpy
alone (``numpy.random.default_rng``, never the global RNG). Train and test samples come from two independent child
streams of the seed (``SeedSequence(seed).spawn(2)``), so changing the test size does not change the training
samples. Every sample is its own group; ``val`` is carved from ``train`` by the base class. ``num_steps`` resamples
the same episode more finely or coarsely (``sim_evtouch``, ``sim_uskin_textures``) or lengthens the window
(``sim_biotac_slip``). Units are arbitrary unless stated; the generative models are physically motivated, not fitted
to the real recordings.

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

Default sizes (per class, train before the ``val`` carve / test): 20/8 (``sim_evtouch``, ``sim_uskin_textures``) and
30/12 (``sim_biotac_slip``). A linear probe (logistic regression on per-taxel time-averaged and five time-binned
means) reaches about 60-70 % on the held-out test samples with them, well above chance (10 %, 14 %) and below what
models of the temporal structure can reach (rotation sense, texture vibration); ``tests/data/test_simulated.py``
checks that such a probe beats chance by a wide margin.
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
import torch

from ..errors import ConfigError
from ..registry import register_dataset
from .base import Augmentation, TactileDataset, TensorData
from .sensors import BIOTAC_SP, NEUTOUCH, USKIN_ALLEGRO, Sensor
from .spec import TactileSample

__all__ = ["SimEvTouch", "SimBiotacSlip", "SimUskinTextures", "SIM_EPOCH_BUDGET"]

#: The simulators' protocol trains every model for at most this many epochs (the bench caps each recipe, compressing
#: its schedule; ``--epochs`` overrides): the embedded default must finish ``tactile-zoo bench --models all`` in
#: minutes on two cores, and these small, clean datasets do not need the hundreds of epochs real data gets.
SIM_EPOCH_BUDGET = 15

# generated data is a pure function of (class, options): keep the last few in memory, because the harness builds
# the train, val and test split of one dataset as three objects and each would otherwise regenerate everything
_MEMO: OrderedDict[tuple[Any, ...], TensorData] = OrderedDict()
_MEMO_SIZE = 6


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _min_jerk(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)


class _Simulator(TactileDataset):
    """A generated dataset: ``seed`` and size keywords instead of raw files.

    Args:
        seed: seed of the generator; the same seed always gives the same tensors.
        n_train_per_class: samples per class in the release ``train`` partition (``val`` is carved from it).
        n_test_per_class: samples per class in ``test``.
        num_steps: time steps ``T`` per sample.
        The remaining arguments are :class:`~tactile_zoo.data.base.TactileDataset`'s.
    """

    simulated: ClassVar[bool] = True
    protocol: ClassVar[str] = "fixed"
    default_train: ClassVar[int] = 20
    default_test: ClassVar[int] = 8
    default_steps: ClassVar[int] = 50
    min_steps: ClassVar[int] = 8

    def __init__(self, root: str | os.PathLike | None = None, split: str | None = None, fold: int = 0,
                 download: bool = False, *, seed: int = 0, n_train_per_class: int | None = None,
                 n_test_per_class: int | None = None, num_steps: int | None = None,
                 transform: Callable[[TactileSample], TactileSample] | None = None,
                 augment: Augmentation | Sequence[Augmentation] | None = None, augment_factor: int = 1,
                 augment_seed: int = 0) -> None:
        self.seed = self._check_int("seed", seed, 0)
        self.n_train_per_class = self._check_int(
            "n_train_per_class", self.default_train if n_train_per_class is None else n_train_per_class, 2)
        self.n_test_per_class = self._check_int(
            "n_test_per_class", self.default_test if n_test_per_class is None else n_test_per_class, 1)
        self.num_steps = self._check_int("num_steps", self.default_steps if num_steps is None else num_steps,
                                         self.min_steps)
        super().__init__(root, split, fold, download, transform=transform, augment=augment,
                         augment_factor=augment_factor, augment_seed=augment_seed)

    @classmethod
    def _check_int(cls, arg: str, value: Any, minimum: int) -> int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
            raise ConfigError(f"{cls.name}: {arg} must be an integer >= {minimum}, got {value!r}")
        return int(value)

    def process_options(self) -> dict[str, Any]:
        return {"seed": self.seed, "n_train_per_class": self.n_train_per_class,
                "n_test_per_class": self.n_test_per_class, "num_steps": self.num_steps}

    def process(self) -> TensorData:
        key = (type(self), *self.process_options().values())
        if key in _MEMO:
            _MEMO.move_to_end(key)
            return _MEMO[key]
        data = self.generate(**self.process_options())
        _MEMO[key] = data  # split selection indexes (copies) these tensors, so sharing them is safe
        while len(_MEMO) > _MEMO_SIZE:
            _MEMO.popitem(last=False)
        return data

    @classmethod
    def generate(cls, seed: int = 0, n_train_per_class: int | None = None, n_test_per_class: int | None = None,
                 num_steps: int | None = None) -> TensorData:
        """Every sample, freshly generated (no memo): ``train`` then ``test``, classes in blocks."""
        n_tr = cls.default_train if n_train_per_class is None else n_train_per_class
        n_te = cls.default_test if n_test_per_class is None else n_test_per_class
        steps = cls.default_steps if num_steps is None else num_steps
        k = len(cls.class_names)
        xs, gs, ys = [], [], []
        for child, n in zip(np.random.SeedSequence(seed).spawn(2), (n_tr, n_te)):
            y = np.repeat(np.arange(k), n)
            x, g = cls.simulate(np.random.default_rng(child), y, steps)
            xs.append(x)
            gs.append(g)
            ys.append(y)
        y_all = np.concatenate(ys)
        return TensorData(torch.from_numpy(np.concatenate(xs).astype(np.float32)),
                          torch.from_numpy(np.concatenate(gs).astype(np.float32)),
                          torch.from_numpy(y_all.astype(np.int64)), torch.arange(len(y_all), dtype=torch.long),
                          ("train",) * (k * n_tr) + ("test",) * (k * n_te))

    @classmethod
    def simulate(cls, rng: np.random.Generator, y: np.ndarray, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """``x (S, T, N, C)`` and ``g (S, T, G)`` for labels ``y (S,)``."""
        raise NotImplementedError


# ----------------------------------------------------------------------------------------------- sim_evtouch
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
    splits=("train", "val", "test"), simulated=True, max_epochs=SIM_EPOCH_BUDGET,
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


# ----------------------------------------------------------------------------------------------- sim_biotac_slip
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
    simulated=True, max_epochs=SIM_EPOCH_BUDGET, licence="generated (MIT, part of tactile-zoo)",
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


# ----------------------------------------------------------------------------------------------- sim_uskin_textures
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
    max_epochs=SIM_EPOCH_BUDGET,
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
