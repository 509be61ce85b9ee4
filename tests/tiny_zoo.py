"""A tiny zoo for the engine and harness tests: fast models and datasets, registered on import.

Importing this module registers everything (so ``--plugin-module tiny_zoo`` works in a subprocess or a worker);
the tests' fixture calls :func:`register` / :func:`unregister` around each test so the names never leak into other
test modules running in the same process.

Models:
    tiny_mlp     averages over time, then a 2-layer MLP (with dropout); non-causal by declaration.
    tiny_rate    a causal running-mean model with sigmoid "rates" trained with ``mse_rate``.
    tiny_broken  raises in forward; tiny_nan outputs NaN; tiny_oom raises torch.OutOfMemoryError.
    tiny_picky   refuses (ModelCannotConsume) datasets without global features -> skipped cells.
    tiny_slow    tiny_mlp that sleeps :data:`SLOW_S` per training batch (for the kill tests; a test that runs it in
                 its own process, where only the numbers matter, sets it to 0).
Datasets:
    tiny_blobs   3 classes, T=12, 3 OptoForce nodes x 4 channels, 3 globals; the class signal grows over time;
                 an extra test split ``test_shifted``.
    tiny_kfold   the same generator under a 3-fold protocol, no globals.
    tiny_absent  a "real" dataset whose raw files are never present (skipped, with how to obtain it).
    tiny_missing a plain-callable plugin dataset that raises DatasetError (skipped with its message).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from tactile_zoo import registry
from tactile_zoo.data.base import TactileDataset, TensorData
from tactile_zoo.errors import DatasetError, ModelCannotConsume

TINY_RECIPE = {"loss": "ce", "optimizer": "adam", "lr": 0.03, "max_epochs": 8, "patience": 4, "batch_size": 16}
#: seconds tiny_slow sleeps per training batch: what keeps a bench child busy long enough to be killed mid-run
SLOW_S = 0.03


class TinyMLP(nn.Module):
    """Mean over time, flattened taxels x channels (+ mean globals), then Linear-ReLU-Dropout-Linear."""

    def __init__(self, spec: Any, hidden: int = 16, dropout: float = 0.1) -> None:
        super().__init__()
        inputs = spec.num_nodes * spec.num_channels + spec.num_globals
        self.net = nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(), nn.Dropout(dropout),
                                 nn.Linear(hidden, spec.num_classes))

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        feats = x.mean(dim=1).flatten(1)  # (B, N * C)
        if g is not None:
            feats = torch.cat([feats, g.mean(dim=1)], dim=1)  # (B, N * C + G)
        return self.net(feats)


class TinyRate(TinyMLP):
    """Causal: the running mean up to the last step, squashed to (0, 1) rates."""

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return torch.sigmoid(super().forward(x, g))


class TinyBroken(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        raise RuntimeError("tiny_broken exploded on purpose")


class TinyNaN(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return super().forward(x, g) * float("nan")


class TinyOOM(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 20.00 GiB")


class TinyPicky(TinyMLP):
    def __init__(self, spec: Any, **kw: Any) -> None:
        if spec.num_globals == 0:
            raise ModelCannotConsume(f"tiny_picky needs global features; {spec.name} has none")
        super().__init__(spec, **kw)


class TinySlow(TinyMLP):
    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        if self.training and SLOW_S:
            time.sleep(SLOW_S)
        return super().forward(x, g)


def _generate(seed: int, n_train: int, n_test: int, globals_: int) -> TensorData:
    """Class-dependent means that fade in over time (so prefixes carry less evidence), plus noise."""
    rng = np.random.default_rng(seed)
    k, t, n, c = 3, 12, 3, 4
    means = rng.normal(0.0, 1.0, size=(k, n, c))
    ramp = np.linspace(0.0, 1.0, t)[None, :, None, None]  # (1, T, 1, 1)
    parts, xs, gs, ys = [], [], [], []
    for part, per_class in (("train", n_train), ("test", n_test), ("test_shifted", n_test)):
        y = np.repeat(np.arange(k), per_class)
        x = ramp * means[y][:, None] * 1.2 + rng.normal(0, 2.5, size=(len(y), t, n, c))
        if part == "test_shifted":
            x = x + 0.3
        g = rng.normal(0, 1.0, size=(len(y), t, globals_)) + (y[:, None, None] * 0.2 if globals_ else 0.0)
        xs.append(x)
        gs.append(g)
        ys.append(y)
        parts += [part] * len(y)
    y_all = np.concatenate(ys)
    return TensorData(torch.tensor(np.concatenate(xs), dtype=torch.float32),
                      torch.tensor(np.concatenate(gs), dtype=torch.float32),
                      torch.tensor(y_all, dtype=torch.long), torch.arange(len(y_all)), tuple(parts))


class TinyBlobs(TactileDataset):
    name = "tiny_blobs"
    class_names = ("alpha", "beta", "gamma")
    extra_splits = ("test_shifted",)
    simulated: ClassVar[bool] = True

    def __init__(self, root: Any = None, split: str | None = None, fold: int = 0, download: bool = False, *,
                 seed: int = 0, n_train: int = 16, n_test: int = 8, **kw: Any) -> None:
        self.seed, self.n_train, self.n_test = seed, n_train, n_test
        super().__init__(root, split, fold, download, **kw)

    def process(self) -> TensorData:
        return _generate(self.seed, self.n_train, self.n_test, 3)


class TinyKFold(TinyBlobs):
    name = "tiny_kfold"
    extra_splits = ()
    protocol = "kfold"

    def process(self) -> TensorData:
        return _generate(self.seed + 1, self.n_train, self.n_test, 0)

    def count_folds(self, data: TensorData) -> int:
        return 3

    def split_indices(self, data: TensorData, fold: int) -> dict[str, np.ndarray]:
        return self.kfold_indices(data, fold, 3)


class TinyAbsent(TinyBlobs):
    name = "tiny_absent"
    simulated = False
    obtain = "copy the tiny files to <root>/tiny_absent/raw/"


def tiny_missing(root: Any = None, split: str | None = None, fold: int = 0, download: bool = False, **kw: Any
                 ) -> Any:
    raise DatasetError("tiny_missing: the plugin's data server is unreachable")


MODELS = {"tiny_mlp": (TinyMLP, {"causal": False}), "tiny_rate": (TinyRate, {"causal": True}),
          "tiny_broken": (TinyBroken, {}), "tiny_nan": (TinyNaN, {}), "tiny_oom": (TinyOOM, {}),
          "tiny_picky": (TinyPicky, {}), "tiny_slow": (TinySlow, {})}
DATASETS = {"tiny_blobs": TinyBlobs, "tiny_kfold": TinyKFold, "tiny_absent": TinyAbsent, "tiny_missing": tiny_missing}


def register() -> None:
    """(Re-)register the tiny zoo (idempotent)."""
    sensor = registry.get_sensor("optoforce3")
    for cls in (TinyBlobs, TinyKFold, TinyAbsent):
        cls.sensor = sensor
    for name, (cls, meta) in MODELS.items():
        recipe = {**TINY_RECIPE, "loss": "mse_rate"} if name == "tiny_rate" else TINY_RECIPE
        registry.register_model(name, recipe=recipe, tags=["test"], **meta)(cls)
    for name, obj in DATASETS.items():
        registry.register_dataset(name, description="test dataset")(obj)


def unregister() -> None:
    """Remove the tiny names again (the registry has no public removal: this reaches into its tables)."""
    for kind, names in (("model", MODELS), ("dataset", DATASETS)):
        table = registry._TABLES[kind]
        for name in names:
            table.builtin.pop(registry.normalize_name(name), None)


register()


def write_recordings(root: Path, folder: str = "grasps") -> None:
    """Four small CSV recordings (two classes, 6 rows x 3 values) in the layout ``RecordingsDataset`` reads."""
    rng = np.random.default_rng(0)
    for cls in ("a", "b"):
        for k in range(2):
            path = root / folder / "raw" / cls / f"{k}.csv"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("\n".join(",".join(f"{v:.4f}" for v in row) for row in rng.normal(size=(6, 3))) + "\n")
