"""Every registered model on every simulated dataset gives the same results on CUDA as on the CPU.

The same weights on both devices, TF32 off and subnormals flushed as in training; ``parity.py`` says what is compared
and within which tolerances. Without a CUDA device the whole module skips. ``python -m benchmarks.gpu_check`` runs
it on a lent GPU machine; ``TACTILE_ZOO_PARITY_DEVICE=cpu`` runs it CPU against CPU, the command's self-test.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from typing import Any

import pytest
import torch
from parity import BATCH, compare_model, sim_split, simulated_datasets, tf32_off

from tactile_zoo.engine.runtime import flush_denormals
from tactile_zoo.errors import ModelCannotConsume
from tactile_zoo.registry import model_names

#: the device compared against the CPU (``cuda``, ``cuda:N``; ``cpu`` for the self-test)
DEVICE = torch.device(os.environ.get("TACTILE_ZOO_PARITY_DEVICE", "cuda"))

pytestmark = pytest.mark.skipif(
    DEVICE.type == "cuda" and not torch.cuda.is_available(),
    reason="no CUDA device: these tests compare every model on CUDA against the CPU (run them on a GPU machine "
           "with `python -m benchmarks.gpu_check`)")

# datasets outermost, sim_evtouch first: a run stopped early has still checked every model once
CASES = [pytest.param(m, d, id=f"{m}-{d}") for d in simulated_datasets() for m in model_names()]


@functools.cache
def _split(dataset: str) -> Any:
    return sim_split(dataset, BATCH)  # one seeded batch per dataset, shared by every model


@pytest.mark.parametrize(("model", "dataset"), CASES)
def test_cuda_matches_cpu(model: str, dataset: str, record_property: Callable[[str, object], None]) -> None:
    with flush_denormals(), tf32_off():
        try:
            rows = compare_model(model, _split(dataset), DEVICE)
        except ModelCannotConsume as exc:
            pytest.skip(str(exc).splitlines()[0])
    for row in rows:  # the measurements of passing checks too, in the JUnit XML that gpu_check keeps
        record_property(row["check"], json.dumps({k: v for k, v in row.items() if k not in ("model", "dataset")}))
    failed = [f"{r['check']}: {r['note']}" for r in rows if r["status"] == "FAIL"]  # "skip": stochastic in training
    assert rows and not failed, f"{model} on {dataset}, {DEVICE} against cpu: " + "; ".join(failed)
