"""D-CNN's train-mode numerics on each device against a float64 reference: ``python -m tools.dcnn_precision``.

Written when the first GPU check (``benchmarks/results/cuda/``) failed D-CNN's train-mode parity: CUDA and CPU
disagreed by 1e-3 in the scores. This asks which side is off. The same model and batch run in float64 on the CPU
is the reference; each row gives one run's largest score difference from it and its largest gradient difference
as a fraction of the largest reference gradient. ``cpu32-nchw`` is the CPU with the convolution blocks in the
default (NCHW) layout instead of the model's channels-last one; ``cpu32-two_pass`` and ``cpu32-float64`` keep the
channels-last layout and build batch norm with ``bn_stats="two_pass"`` / ``"float64"`` (accurate training statistics,
:mod:`tactile_zoo.nn.batch_norm`). Rows are printed as JSON lines, CUDA rows only where CUDA exists.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "gpu"))
from parity import _dropout_off, sim_split, tf32_off  # noqa: E402

from tactile_zoo.engine.build import build_model  # noqa: E402
from tactile_zoo.engine.config import resolve_model_recipe  # noqa: E402
from tactile_zoo.engine.runtime import flush_denormals  # noqa: E402
from tactile_zoo.engine.train import compute_loss  # noqa: E402
from tactile_zoo.nn.backend import BatchNormStats, resolve  # noqa: E402
from tactile_zoo.nn.batch_norm import BatchNorm1d, BatchNorm2d  # noqa: E402
from tactile_zoo.registry import get_model_entry  # noqa: E402

#: label -> (device, dtype, channels-last convolution blocks, batch norm's training statistics)
RUNS = {"cpu32": ("cpu", torch.float32, True, "native"), "cpu32-nchw": ("cpu", torch.float32, False, "native"),
        "cpu32-two_pass": ("cpu", torch.float32, True, "two_pass"),
        "cpu32-float64": ("cpu", torch.float32, True, "float64"),
        "cuda32": ("cuda", torch.float32, True, "native"), "cuda64": ("cuda", torch.float64, True, "native")}


def train_step(model: torch.nn.Module, split: Any, recipe: Any, device: str, dtype: torch.dtype,
               channels_last: bool, stats: str = "native") -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Scores and every parameter's gradient of one train-mode step (dropout off), in float64 on the CPU."""
    m = copy.deepcopy(model).to(device=device, dtype=dtype)
    for bn in m.modules():
        if isinstance(bn, (BatchNorm1d, BatchNorm2d)):
            bn.stats = resolve(BatchNormStats, stats, "stats", "dcnn_precision")
    m.features.to(memory_format=torch.channels_last if channels_last else torch.contiguous_format)
    _dropout_off(m)
    g = split.g.to(device=device, dtype=dtype) if split.g.shape[-1] else None
    scores = m(split.x.to(device=device, dtype=dtype), g)
    compute_loss(scores, split.y.to(device), recipe).backward()
    grads = {n: p.grad.detach().double().cpu() for n, p in m.named_parameters() if p.grad is not None}
    return scores.detach().double().cpu(), grads


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.dcnn_precision", description=__doc__.split("\n\n")[0])
    p.add_argument("--datasets", default="sim_evtouch,sim_uskin_textures")
    p.add_argument("--batches", default="4,32")
    args = p.parse_args(argv)
    recipe = resolve_model_recipe(get_model_entry("dcnn").meta, owner="model 'dcnn'").recipe
    runs = {k: v for k, v in RUNS.items() if v[0] == "cpu" or torch.cuda.is_available()}
    with flush_denormals(), tf32_off():
        for dataset in args.datasets.split(","):
            for batch in map(int, args.batches.split(",")):
                split = sim_split(dataset, batch=batch)
                model = build_model("dcnn", split.spec, seed=0)
                ref_s, ref_g = train_step(model, split, recipe, "cpu", torch.float64, False)
                largest = max(g.abs().max().item() for g in ref_g.values())
                for label, (device, dtype, channels_last, stats) in runs.items():
                    s, g = train_step(model, split, recipe, device, dtype, channels_last, stats)
                    errors = {n: (g[n] - ref_g[n]).abs().max().item() / largest for n in g}
                    worst = max(errors, key=errors.__getitem__)
                    print(json.dumps({"dataset": dataset, "batch": batch, "run": label,
                                      "score_err": (s - ref_s).abs().max().item(), "grad_err": errors[worst],
                                      "worst_param": worst}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
