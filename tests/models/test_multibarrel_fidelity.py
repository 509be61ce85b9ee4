"""The multi-barrel SNN against its released code: ``fixtures/multibarrel_reference.json``, made by
``tools/multibarrel_fixture.py`` from github.com/fun0515/MultiBarrelModel's ``SharedMultiBarrelModel`` at reduced sizes
(7 NeuTouch taxels, a small read-out; the populations, compressor and gate at the released sizes), noise off, both
random starts recorded.

Our model, given the released weights through :func:`convert_released` and the same starts, must give the released
probabilities in training mode (batch statistics) and eval mode (running statistics), the same spikes at every step,
the same running statistics after the training pass, and the same gradients of the released loss (cross-entropy on
the softmax). Tolerances are float32 rounding: the two compute the same sums in different kernels (a Linear for the
released 1x1 Conv1d, a matrix product for the read-out convolution). Measured (torch 2.13, one CPU thread): the
probabilities within 6e-8 (train and eval mode; asserted 1e-6), every spike identical, the time constants' gradients
within 1.3e-10 of gradients up to 3.5e-4, every other gradient's absolute sum within 4.3e-7 relative (asserted 1e-5).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import tactile_zoo as tz
from tactile_zoo.data.sensors import Sensor
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.multibarrel import OUTPUTS, MultiBarrel, convert_released
from tactile_zoo.nn.routing import nearest_neighbours
from tools.multibarrel_fixture import unpack, unpack_weight

FIXTURE = json.loads((Path(__file__).parent / "fixtures" / "multibarrel_reference.json").read_text())
SIZES = FIXTURE["sizes"]
POPS, SIZE = 8, 32


def _spec() -> DatasetSpec:
    positions = tuple(tz.get_sensor("neutouch").positions[i] for i in SIZES["taxels"])
    n = len(positions)
    sensor = Sensor(name="neutouch_centre", positions=positions, grid_shape=(1, n),
                    grid=tuple((0, i) for i in range(n)), channels=("on", "off"))
    k = SIZES["classes"]
    return DatasetSpec("fixture", k, tuple(map(str, range(k))), SIZES["steps"], n, 2, 0, sensor)


def _model() -> MultiBarrel:
    model = MultiBarrel(_spec(), readout_channels=SIZES["readout_channels"], readout_kernel=SIZES["readout_kernel"],
                        hidden=SIZES["hidden"], tau_m_init=SIZES["init_tau_m"], tau_adp_init=SIZES["init_tau_a"],
                        init_b=SIZES["init_b"], output="softmax", noise_std=0.0)
    model.load_state_dict(convert_released({k: unpack_weight(v) for k, v in FIXTURE["weights"].items()}))
    return model


def _start(key: str) -> tuple[torch.Tensor, torch.Tensor]:
    draws = torch.from_numpy(unpack(FIXTURE[key]).astype(np.float32) / 256)  # (2 * P, B, N, S): membranes, spikes
    return draws[:POPS], draws[POPS:]


def _input() -> torch.Tensor:
    shape = FIXTURE["input_shape"]  # (B, N, C, T), the released layout
    bits = np.unpackbits(unpack(FIXTURE["input"]))[: int(np.prod(shape))].reshape(shape)
    return torch.from_numpy(bits.astype(np.float32)).permute(0, 3, 1, 2)  # (B, T, N, C)


def _max_diff(ours: torch.Tensor, theirs: Any) -> float:
    return float((ours.detach().double() - torch.as_tensor(np.asarray(theirs)).double()).abs().max())


def released_run() -> dict[str, Any]:
    """Our model on the fixture: a training-mode pass and its gradients, then an eval-mode pass."""
    torch.manual_seed(0)
    model, x = _model(), _input()
    y = torch.tensor(FIXTURE["labels"])
    model.train()
    spikes = model.columns(model.compress(x), _start("start_train"))  # (B, T', N, 4 * S)
    probs = model.forward_head(model._features(spikes))
    F.cross_entropy(probs, y).backward()
    model.eval()
    with torch.no_grad():
        probs_eval = model.forward_head(model.forward_features(x, start=_start("start_eval")))
    return {"model": model, "spikes": spikes, "probs": probs, "probs_eval": probs_eval}


@pytest.fixture(scope="module")
def run() -> dict[str, Any]:
    return released_run()


def test_the_neighbours_are_the_released_ones() -> None:
    released = torch.tensor(FIXTURE["neighbours_neutouch"])  # the released NeighborAggregator(k=4), 39 taxels
    ours = nearest_neighbours(torch.tensor(tz.get_sensor("neutouch").positions, dtype=torch.float32), 4)
    assert torch.equal(ours, released)
    assert torch.equal(_model().router.neighbours, torch.tensor(FIXTURE["neighbours"]))


def test_training_mode_matches_the_released_code(run: dict[str, Any]) -> None:
    assert run["probs"].shape == (SIZES["batch"], SIZES["classes"])
    shape = FIXTURE["spikes_shape"]  # (B, T', N, P * S): every population
    released = np.unpackbits(unpack(FIXTURE["spikes_train"]))[: int(np.prod(shape))].reshape(shape)
    wanted = np.concatenate([released[..., p * SIZE:(p + 1) * SIZE] for p in OUTPUTS], axis=-1)
    assert 0.05 < wanted.mean() < 0.95, "the fixture's neurons should neither stay silent nor fire always"
    assert np.array_equal(run["spikes"].detach().numpy().astype(np.uint8), wanted)
    assert _max_diff(run["probs"], unpack(FIXTURE["probs_train"])) < 1e-6


def test_running_statistics_after_the_training_pass(run: dict[str, Any]) -> None:
    ours = run["model"].state_dict()
    for name, value in convert_released({k: torch.from_numpy(unpack(v))
                                         for k, v in FIXTURE["buffers_after_train"].items()}).items():
        if value.is_floating_point():
            assert _max_diff(ours[name], value) <= 1e-5 * (1 + float(value.abs().max())), name
        else:
            assert torch.equal(ours[name], value), name


def test_gradients_match_the_released_code(run: dict[str, Any]) -> None:
    params = dict(run["model"].named_parameters())
    for name, grad in convert_released({k: torch.from_numpy(unpack(v)) for k, v in FIXTURE["grads_tau"].items()}
                                       ).items():
        assert _max_diff(params[name].grad, grad) <= 1e-5 * (1 + float(grad.abs().max())), name
    sums = convert_released({k: torch.tensor(v) for k, v in FIXTURE["grad_abs_sums"].items()})
    assert set(sums) == set(params), "a parameter with a gradient in one model only"
    for name, total in sums.items():
        # abs: a bias in front of a BatchNorm has a true gradient of exactly 0; both sums of it are rounding (~1e-8)
        assert float(params[name].grad.double().abs().sum()) == pytest.approx(float(total), rel=1e-5, abs=1e-7), name


def test_eval_mode_matches_the_released_code(run: dict[str, Any]) -> None:
    assert _max_diff(run["probs_eval"], unpack(FIXTURE["probs_eval"])) < 1e-6


def test_an_unknown_released_name_is_one_clear_error() -> None:
    with pytest.raises(ConfigError, match="'readout.fc.weight' is no parameter or buffer of the released"):
        convert_released({"readout.fc.weight": torch.zeros(1)})
