"""SGnet's and ConvLSTM's Ev-Objects epoch on a GPU, eager against CUDA graphs, beside the 2-core CPU epoch.

The two models whose time loops launch the most kernels per batch (SGnet's 250 LIF steps, ConvLSTM's recurrence).
Three cases per model, in alternating rounds (``ctx.reps(6, 2)``), each round one training epoch per case:

``cpu``
    the model trained on the CPU with 2 torch threads (the project's 2-core machine; on a GPU machine its host CPU,
    which the CSV's ``cpu_model`` names);
``eager``
    on ``ctx.device``, the model's own forward and backward;
``graphed``
    on ``ctx.device``, each full batch's forward and backward replayed from CUDA graphs
    (:mod:`tactile_zoo.engine.cuda_graph`).

Each case keeps one model and trains it by the engine (``fit``, no validation) for one untimed epoch, in which a
graphed run records its graphs, then for one epoch per round; the time is the epoch's own, as ``fit`` records it
(the epoch ends with a host sync). On the CPU alone (no ``--device cuda``) only ``cpu`` is timed and the other rows
say unmeasured. The issue's target: SGnet's GPU epoch at least 10x the 2-core CPU epoch. ``--quick`` times a
class-balanced 64-sample subset and scales to 576.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from .common import EV_TRAIN_SAMPLES, Context, Timing, ev_objects, model_recipe, write_csv

NAME = "gpu_epoch"
TITLE = "SGnet and ConvLSTM: Ev-Objects epoch on the GPU, eager against CUDA graphs, beside 2 CPU threads"
COLUMNS = ("model", "batch_size", "data", "samples_timed", "epoch_median_s", "epoch_min_s", "repeats",
           "speedup_vs_cpu", "target")
MODELS = ("sgnet", "convlstm")
CPU_THREADS = 2

__all__ = ["run", "NAME", "TITLE", "MODELS"]


class _Case:
    """One model trained in one way, an epoch per call."""

    def __init__(self, name: str, split: Any, device: torch.device, graphs: bool, threads: int | None) -> None:
        from tactile_zoo.engine import seed_everything
        from tactile_zoo.registry import instantiate_model

        self.split, self.device, self.graphs, self.threads = split, device, graphs, threads
        self.recipe = model_recipe(name)
        seed_everything(0)
        self.model = instantiate_model(name, split.spec).to(device)
        self.seconds: list[float] = []

    def epoch(self, timed: bool = True) -> None:
        from tactile_zoo.engine import fit

        before = torch.get_num_threads()
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        try:
            result = fit(self.model, self.split, recipe=self.recipe, device=self.device, epochs=1, progress=False,
                         cuda_graphs=self.graphs if self.device.type == "cuda" else None)
        finally:
            torch.set_num_threads(before)
        if timed:
            self.seconds.append(float(result.curve[0]["seconds"]))


def measure(ctx: Context, name: str) -> list[dict[str, Any]]:
    """The three cases of model ``name`` in alternating rounds; one CSV row each."""
    from tactile_zoo.engine import take

    data = ev_objects(ctx)
    n = min(len(data.train), 64 if ctx.quick else len(data.train))
    split = take(data.train, n, seed=0) if n < len(data.train) else data.train
    scale = EV_TRAIN_SAMPLES / n
    cases = {"cpu": _Case(name, split, torch.device("cpu"), False, CPU_THREADS)}
    if ctx.device.type == "cuda":
        cases["eager"] = _Case(name, split, ctx.device, False, None)
        cases["graphed"] = _Case(name, split, ctx.device, True, None)
    for case in cases.values():  # untimed: allocator, cuDNN's choices, the graphs' recording
        case.epoch(timed=False)
    names = list(cases)
    for r in range(ctx.reps(6, 2)):
        for key in names[r % len(names):] + names[:r % len(names)]:  # the order rotates every round
            cases[key].epoch()
    cpu = Timing(cases["cpu"].seconds).median
    rows = []
    for key in ("cpu", "eager", "graphed"):
        row: dict[str, Any] = {"case": f"{name}/{key}", "model": name, "batch_size": cases["cpu"].recipe.batch_size,
                               "data": data.source, "samples_timed": n,
                               "target": "SGnet's GPU epoch >= 10x the 2-core CPU epoch" if name == "sgnet" else ""}
        if key not in cases:
            rows.append({**row, "note": f"unmeasured: no CUDA device in this run ({ctx.device})"})
            continue
        t = Timing(cases[key].seconds)
        rows.append({**row, "epoch_median_s": t.median * scale, "epoch_min_s": t.min * scale, "repeats": len(t),
                     "speedup_vs_cpu": cpu / t.median,
                     "note": (f"{CPU_THREADS} CPU threads" if key == "cpu" else str(ctx.device))
                     + ("" if n == EV_TRAIN_SAMPLES else f"; {n} samples timed, scaled to {EV_TRAIN_SAMPLES}")})
    return rows


def run(ctx: Context, models: tuple[str, ...] = MODELS) -> Path:
    rows = []
    for name in models:
        got = measure(ctx, name)
        rows.extend(got)
        ctx.log("  " + "; ".join(f"{r['case']} {r['epoch_median_s']:.2f} s ({r['speedup_vs_cpu']:.1f}x cpu)"
                                 for r in got if "epoch_median_s" in r))
    return write_csv(ctx, NAME, COLUMNS, rows)
