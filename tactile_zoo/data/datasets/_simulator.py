"""The simulators' shared base: :class:`_Simulator` (a generated :class:`~tactile_zoo.data.base.TactileDataset`),
the epoch budget of their protocol, the in-memory memo of generated data, and the easing curves they share.

The simulated datasets (:mod:`.sim_evtouch`, :mod:`.sim_biotac_slip`, :mod:`.sim_uskin_textures`) are the embedded
default on a machine without real data: one per sensor family, each generated from a seed in well under a second with
numpy alone (``numpy.random.default_rng``, never the global RNG). Train and test samples come from two independent
child streams of the seed (``SeedSequence(seed).spawn(2)``), so changing the test size does not change the training
samples. Every sample is its own group; ``val`` is carved from ``train`` by the base class. ``num_steps`` resamples
the same episode more finely or coarsely (``sim_evtouch``, ``sim_uskin_textures``) or lengthens the window
(``sim_biotac_slip``). Units are arbitrary unless stated; the generative models are physically motivated, not fitted
to the real recordings.

Default sizes (per class, train before the ``val`` carve / test): 20/8 (``sim_evtouch``, ``sim_uskin_textures``) and
30/12 (``sim_biotac_slip``). A linear probe (logistic regression on per-taxel time-averaged and five time-binned
means) reaches about 60-70 % on the held-out test samples with them, well above chance (10 %, 14 %) and below what
models of the temporal structure can reach (rotation sense, texture vibration); ``tests/data/test_simulated.py``
checks that such a probe beats chance by a wide margin.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
import torch

from ...errors import ConfigError
from ..base import Augmentation, TactileDataset, TensorData
from ..spec import TactileSample

__all__ = ["SIM_EPOCH_BUDGET"]

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
                 pre_transform: Callable[[TactileSample], TactileSample] | None = None,
                 augment: Augmentation | Sequence[Augmentation] | None = None, augment_factor: int = 1,
                 augment_seed: int = 0) -> None:
        self.seed = self._check_int("seed", seed, 0)
        self.n_train_per_class = self._check_int(
            "n_train_per_class", self.default_train if n_train_per_class is None else n_train_per_class, 2)
        self.n_test_per_class = self._check_int(
            "n_test_per_class", self.default_test if n_test_per_class is None else n_test_per_class, 1)
        self.num_steps = self._check_int("num_steps", self.default_steps if num_steps is None else num_steps,
                                         self.min_steps)
        super().__init__(root, split, fold, download, transform=transform, pre_transform=pre_transform, augment=augment,
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

