"""What the weights tests share: the trained cell's settings, the fixture's result type, and writing a dataset's
test sample as a recording file in the documented format."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from tactile_zoo.weights import WeightEntry

MODEL, DATASET = "cnn_lstm", "sim_uskin_textures"
#: 20 test samples of 12 steps; max_frames=4 bins 3 frames into one, so the model depends on the number of steps
DATA_ARGS = {"n_train_per_class": 3, "n_test_per_class": 2, "num_steps": 12}
HPARAMS = {"conv_channels": [4, 8], "frame_features": 12, "hidden": 12, "max_frames": 4}
CONFIG_HASH = "0123456789abcdef"
CELL_ID = f"{MODEL}__{DATASET}__f0__s0__{CONFIG_HASH}"


@dataclass
class Trained:
    """The trained model, its cell record and files, and its logits on the test split."""

    run: Path
    record: dict[str, Any]
    model: torch.nn.Module
    file: Path
    manifest: Path
    entry: WeightEntry
    test: Any
    logits: torch.Tensor


def sample_table(test: Any, i: int) -> np.ndarray:
    """Test sample ``i`` in the documented recordings format: one row per step, taxels row-major, then globals."""
    x, g = test.x[i], test.g[i]  # (T, N, C), (T, G)
    return torch.cat([x.reshape(x.shape[0], -1), g], dim=1).numpy()  # (T, N * C + G)


def write_csv(path: Path, table: np.ndarray, header: bool = True) -> Path:
    lines = [",".join(f"c{j}" for j in range(table.shape[1]))] if header else []
    lines += [",".join(f"{v:.9g}" for v in row) for row in table]  # %.9g: float32 values read back exactly
    path.write_text("\n".join(lines) + "\n")
    return path


def slip_spec() -> Any:
    """The spec of a small ``sim_biotac_slip`` (another sensor: 24 taxels x 1 channel, no globals, 7 classes)."""
    import tactile_zoo as tz

    return tz.load_dataset("sim_biotac_slip", split="test", n_train_per_class=2, n_test_per_class=1,
                           num_steps=12).spec


@contextlib.contextmanager
def installed_weight_pack(plugin: Path, factory: pytest.TempPathFactory) -> Iterator[Path]:
    """``plugin`` installed by pip (offline, once per test run: :func:`plugin_install.installed_once`) and on
    ``sys.path``, the only weight pack discovery sees (not a copy the environment may have installed); yields the
    install target."""
    from plugin_install import installed_once, only_weights_from

    from tactile_zoo.weights import reset_weights

    target = installed_once(plugin, factory)
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("TACTILE_ZOO_NO_PLUGINS", raising=False)
        mp.delenv("TACTILE_ZOO_STRICT_PLUGINS", raising=False)
        mp.syspath_prepend(str(target))
        only_weights_from(mp, target)
        reset_weights()
        yield target
        sys.modules.pop("tactile_zoo_weights", None)
    reset_weights()
