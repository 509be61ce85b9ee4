"""A GPU check ready to run: ``python -m benchmarks.gpu_check [--quick] [--timeout SECONDS] [--out DIR]``.

One command for a short session on a machine with a CUDA GPU (issue 18, section 4). Run it from the repository root
of a checkout; it needs no network and installs nothing: torch (with CUDA), torch_geometric and snntorch must already
be importable there (a missing one is named on one line, exit status 2). When ``tactile_zoo`` is not installed, the
checkout it sits in is put on ``sys.path``. Only the simulated datasets are used (the registered datasets with
``simulated=True``: generated from a seed, no files), so no data needs to be copied over.

Three sections, in this order, each writing its rows as soon as it ends (``<out>/gpu_check_<section>.csv`` with the
environment columns of :mod:`benchmarks.common`, and everything together in ``<out>/gpu_check.json``; ``<out>`` is
``benchmarks/results/cuda/`` unless ``--out`` says otherwise):

``compare``
    Every registered model on seeded samples of every simulated dataset: the same weights on CPU and on CUDA, with
    TF32 off (``torch.backends.cuda.matmul.allow_tf32`` and ``torch.backends.cudnn.allow_tf32`` False) so that both
    compute in float32. Three checks per model and dataset: ``forward`` (eval mode), ``stream`` (``init_state`` /
    ``step`` frame by frame, for models registered with ``streaming=True``: the running scores after every frame)
    and ``backward`` (train mode with dropout off: the loss of the model's recipe and every parameter's gradient).
    Logits must agree within 1e-4 (max abs difference) and gradients within 1e-3 of the largest gradient. Spiking
    models (those with :class:`~tactile_zoo.nn.lif.MultiStepLIF` layers, whose output spikes are counted per neuron)
    must not differ by more than one spike per neuron over a sequence of ``T`` steps of that layer: a spike-rate
    mismatch of at most ``1/T`` (a stream calls a layer once per frame, re-reading an open frame bin, and is held to
    the same ``1/T`` of the layer's forward sequence). One membrane landing within rounding of the threshold on one
    device legitimately flips a spike, and with it the logits downstream, so logits and gradients of a spiking model
    are judged only when every spike agrees (the usual case); otherwise they are recorded and the row says so.
``timing``
    Per model, on ``sim_evtouch`` (the first of ``--datasets``), on CUDA at PyTorch's default TF32 settings (as
    training runs; the ``tf32`` column says which): one training epoch at the recipe's batch size (``fit``, after an
    untimed warm-up batch), batch-1 latency and batch-64 throughput in eval mode, the peak GPU memory of the epoch,
    and the batch-1 latency on 1 CPU thread beside it (cheap).
``bench``
    The embedded default, ``tactile-zoo bench --models all`` with an empty data home (so: every model on the
    simulated datasets) and ``--device cuda``, in a fresh temporary folder, as ``benchmarks/bench_wall.py`` runs it:
    ``--executor process --workers N``; with ``--quick`` it is ``tactile-zoo bench --quick``, otherwise the full data
    with ``--epochs 3`` (``--bench-epochs``). Wall time, and the cells that finished ``ok``, ``failed`` or
    ``skipped``; the child's output is kept in ``<out>/gpu_check_bench.log``.

``--timeout`` (default 270 s) bounds the whole command: ``compare`` stops starting new items at 35 % of it,
``timing`` at 65 %, and the bench child is stopped (its whole process group) when the time is up; what did not run
is written as ``skipped`` rows with a note, and does not count as a failure. ``--quick`` uses smaller sizes (batch 2,
at most 40 steps for ``compare``; 64 training samples, fewer repeats for ``timing``; bench ``--quick``).

Without CUDA the command prints one line saying so, writes nothing and exits 0 (it asks before importing more than
torch). ``--allow-cpu`` (internal, for the test suite) runs every code path with the "device" side on the CPU too, so
the comparison logic runs for real without a GPU (its results go to a fresh temporary folder unless ``--out`` is
given). Exit status: 0 when every check passed (skipped items included), 1 when any failed or raised, 2 for a missing
package or a bad option.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import importlib
import importlib.util
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # torch and the checkout's modules are imported after the package check in main()
    import torch

    from .common import Context

REPO = Path(__file__).resolve().parents[1]
NAME = "gpu_check"
TITLE = "GPU check: CUDA against CPU (forward, backward, streaming), CUDA timings and the embedded-default bench"
#: what must already be installed on the GPU machine (nothing is installed from the network)
REQUIRED = ("torch", "torch_geometric", "snntorch")
SECTIONS = ("compare", "timing", "bench")
#: logits: max abs difference CUDA vs CPU
LOGIT_TOL = 1e-4
#: gradients: max abs difference over all parameters / max abs gradient
GRAD_TOL = 1e-3
#: the part of --timeout after which a section starts no new item (bench: whatever is left)
SECTION_END = {"compare": 0.35, "timing": 0.65, "bench": 1.0}
DEFAULT_TIMEOUT_S = 270.0
#: the simulated dataset checked first and timed (event-based NeuTouch, like Ev-Objects), when registered
FIRST_DATASET = "sim_evtouch"
#: compare sizes: (batch, max steps) quick, full
COMPARE_SIZES = {True: (2, 40), False: (4, None)}

COMPARE_COLUMNS = ("model", "dataset", "check", "status", "batch", "steps", "max_abs_diff", "spike_rate_diff",
                   "spike_rate_limit", "spikes_equal", "spike_total", "grad_max_abs_diff", "grad_rel_diff",
                   "stream_vs_forward_diff", "seconds")
TIMING_COLUMNS = ("model", "dataset", "status", "batch_size", "samples", "steps", "epoch_s", "epoch_min_s",
                  "train_samples_per_s", "repeats", "latency_ms", "latency_p90_ms", "throughput_batch",
                  "throughput_sps", "cpu_latency_ms", "gpu_peak_mb", "tf32")
BENCH_COLUMNS = ("status", "command", "exit_code", "cells_ok", "cells_failed", "cells_skipped", "wall_s", "workers",
                 "timeout_s")

__all__ = ["main", "run_check", "Plan", "Budget", "Run", "SpikeRecorder", "compare_runs", "compare_model",
           "missing_package", "run_bench_command", "NAME", "TITLE", "LOGIT_TOL", "GRAD_TOL"]


# --------------------------------------------------------------------------------------------- setup and budget
def missing_package(required: Sequence[str] = REQUIRED, checkout: bool = True) -> str | None:
    """The first package that cannot be imported (``required``, then with ``checkout`` ``tactile_zoo`` and what it
    imports), or ``None``. Puts the checkout on ``sys.path`` first when ``tactile_zoo`` is not installed."""
    if importlib.util.find_spec("tactile_zoo") is None and str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    for name in (*required, *(["tactile_zoo.registry"] if checkout else [])):
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            return exc.name or name
    return None


class Budget:
    """The command's time budget: ``seconds`` from construction; each section ends at its share of it."""

    def __init__(self, seconds: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.seconds, self.clock = float(seconds), clock
        self.start = clock()

    def spent(self) -> float:
        return self.clock() - self.start

    def left(self, section: str | None = None) -> float:
        """Seconds left in the whole budget, or before ``section``'s share of it ends."""
        end = self.seconds * (SECTION_END[section] if section else 1.0)
        return end - self.spent()


@contextlib.contextmanager
def tf32_off() -> Iterator[None]:
    """TF32 off for matmuls and cuDNN inside the block (float32 on both devices), restored after it."""
    import torch

    before = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = before


def _tf32_setting() -> str:
    import torch

    return f"matmul={torch.backends.cuda.matmul.allow_tf32},cudnn={torch.backends.cudnn.allow_tf32}"


# --------------------------------------------------------------------------------------------- the comparison
class SpikeRecorder:
    """Counts the output spikes of every :class:`~tactile_zoo.nn.lif.MultiStepLIF` of a model while active.

    The layer's ``forward`` is wrapped on the instance, so both ``layer(x)`` and ``layer.step(x_t)`` (which calls
    ``self.forward``) are seen. Per layer (by module name): ``counts`` the spikes of each neuron summed over time and
    calls (float64), ``steps`` the time steps it ran, ``calls`` how often it ran.
    """

    def __init__(self, model: torch.nn.Module) -> None:
        from tactile_zoo.nn.lif import MultiStepLIF

        self.layers = {name: m for name, m in model.named_modules() if isinstance(m, MultiStepLIF)}
        self.counts: dict[str, torch.Tensor] = {}
        self.steps: dict[str, int] = {}
        self.calls: dict[str, int] = {}

    def _wrap(self, name: str, layer: torch.nn.Module) -> Callable[..., Any]:
        import torch

        inner = layer.forward

        def forward(*args: Any, **kwargs: Any) -> Any:
            out = inner(*args, **kwargs)
            spikes = out[0] if isinstance(out, tuple) else out  # (T, *) 0/1
            total = spikes.detach().sum(0, dtype=torch.float64)
            self.counts[name] = total if name not in self.counts else self.counts[name] + total
            self.steps[name] = self.steps.get(name, 0) + int(spikes.shape[0])
            self.calls[name] = self.calls.get(name, 0) + 1
            return out

        return forward

    def __enter__(self) -> SpikeRecorder:
        for name, layer in self.layers.items():
            layer.forward = self._wrap(name, layer)  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: Any) -> None:
        for layer in self.layers.values():
            layer.__dict__.pop("forward", None)
        self.counts = {k: v.cpu() for k, v in self.counts.items()}


@dataclass
class Run:
    """What one device produced for one check.

    Attributes:
        scores: the model's scores (``(B, K)``; ``(T, B, K)`` for a stream), on CPU.
        counts: spikes per neuron of each LIF layer, summed over the run (empty for a non-spiking model).
        steps: time steps each LIF layer ran in the run (the denominator of its spike rates).
        horizon: the sequence length ``T`` of each LIF layer, for the ``1/T`` limit (its steps per forward call).
        grads: each parameter's gradient (backward checks only).
    """

    scores: torch.Tensor
    counts: dict[str, torch.Tensor] = field(default_factory=dict)
    steps: dict[str, int] = field(default_factory=dict)
    horizon: dict[str, int] = field(default_factory=dict)
    grads: dict[str, torch.Tensor | None] | None = None


def _max_abs(a: torch.Tensor, b: torch.Tensor) -> float:
    if a.shape != b.shape:
        return math.inf
    if a.numel() == 0:
        return 0.0
    diff = (a.double() - b.double()).abs().max()
    return float(diff) if bool(diff.isfinite()) else math.inf


def compare_runs(ref: Run, dev: Run, logit_tol: float = LOGIT_TOL, grad_tol: float = GRAD_TOL) -> dict[str, Any]:
    """Judge ``dev`` (CUDA) against ``ref`` (CPU): scores within ``logit_tol``, gradients within ``grad_tol`` of the
    largest reference gradient, and for spiking models at most one spike per neuron more or less over a sequence
    (rate mismatch ``<= 1/T``). Logits and gradients of a spiking model are judged only when all spikes agree.

    Returns the row's measurements, ``passed`` and ``why`` (the reasons it failed, or a note)."""
    out: dict[str, Any] = {"max_abs_diff": _max_abs(ref.scores, dev.scores), "spike_rate_diff": None,
                           "spike_rate_limit": None, "spikes_equal": None, "spike_total": None,
                           "grad_max_abs_diff": None, "grad_rel_diff": None}
    fails: list[str] = []
    notes: list[str] = []
    spiking = bool(ref.counts) or bool(dev.counts)
    spikes_equal = True
    if spiking:
        worst, worst_layer = -1.0, ""
        if set(ref.counts) != set(dev.counts):
            fails.append(f"spiking layers differ: {sorted(set(ref.counts) ^ set(dev.counts))}")
            spikes_equal = False
        for name in sorted(set(ref.counts) & set(dev.counts)):
            a, b = ref.counts[name], dev.counts[name]
            steps = ref.steps.get(name, 0)
            if a.shape != b.shape or steps != dev.steps.get(name) or steps <= 0:
                fails.append(f"{name}: spike counts of shapes {tuple(a.shape)}, {tuple(b.shape)} over "
                             f"{steps}, {dev.steps.get(name)} steps")
                spikes_equal = False
                continue
            delta = float((a - b).abs().max()) if a.numel() else 0.0
            spikes_equal = spikes_equal and delta == 0.0
            rate, limit = delta / steps, 1.0 / max(1, ref.horizon.get(name, steps))
            if rate / limit > worst:
                worst, worst_layer = rate / limit, name
                out["spike_rate_diff"], out["spike_rate_limit"] = rate, limit
        out["spikes_equal"] = spikes_equal
        out["spike_total"] = float(sum(float(c.sum()) for c in ref.counts.values()))
        if worst > 1.0 + 1e-9:
            fails.append(f"spike-rate mismatch {out['spike_rate_diff']:.3g} > 1/T = {out['spike_rate_limit']:.3g} "
                         f"(layer {worst_layer})")
    judged = not spiking or spikes_equal
    if not judged:
        notes.append("spikes differ (within 1/T): logits and gradients recorded, not judged")
    if judged and not out["max_abs_diff"] <= logit_tol:
        fails.append(f"scores differ by {out['max_abs_diff']:.3g} > {logit_tol:g}")
    if ref.grads is not None or dev.grads is not None:
        rg, dg = ref.grads or {}, dev.grads or {}
        worst_abs, largest, missing = 0.0, 0.0, []
        for name in sorted(set(rg) | set(dg)):
            a, b = rg.get(name), dg.get(name)
            if a is None or b is None:
                if (a is None) != (b is None):
                    missing.append(name)
                continue
            worst_abs = max(worst_abs, _max_abs(a, b))
            largest = max(largest, float(a.abs().max()) if a.numel() else 0.0)
        out["grad_max_abs_diff"] = worst_abs
        out["grad_rel_diff"] = worst_abs / largest if largest > 0 else (0.0 if worst_abs == 0 else math.inf)
        if missing:
            fails.append(f"gradient on one device only: {missing[:3]}")
        if judged and not out["grad_rel_diff"] <= grad_tol:
            fails.append(f"gradients differ by {out['grad_rel_diff']:.3g} of the largest > {grad_tol:g}")
    out["passed"] = not fails
    out["why"] = "; ".join(fails + notes)
    return out


def _dropout_off(model: torch.nn.Module) -> None:
    """Train mode (batch statistics, cuDNN's training kernels) without the randomness of dropout."""
    from torch import nn

    model.train()
    for m in model.modules():
        if isinstance(m, (nn.Dropout, nn.Dropout1d, nn.Dropout2d, nn.Dropout3d, nn.AlphaDropout,
                          nn.FeatureAlphaDropout)):
            m.eval()


def run_forward(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None) -> Run:
    """Eval-mode forward under ``inference_mode``, spikes counted."""
    import torch

    model.eval()
    with torch.inference_mode(), SpikeRecorder(model) as rec:
        scores = model(x, g)
    return Run(scores.float().cpu(), rec.counts, rec.steps, {k: rec.steps[k] // rec.calls[k] for k in rec.steps})


def run_backward(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, y: torch.Tensor, recipe: Any
                 ) -> Run:
    """Train-mode forward (dropout off) and backward of the recipe's loss: scores, spikes and every gradient."""
    from tactile_zoo.engine.train import compute_loss

    _dropout_off(model)
    model.zero_grad(set_to_none=True)
    with SpikeRecorder(model) as rec:
        scores = model(x, g)
        compute_loss(scores, y, recipe).backward()
    grads = {name: None if p.grad is None else p.grad.detach().float().cpu() for name, p in model.named_parameters()}
    model.zero_grad(set_to_none=True)
    return Run(scores.detach().float().cpu(), rec.counts, rec.steps,
               {k: rec.steps[k] // rec.calls[k] for k in rec.steps}, grads)


def run_stream(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None, horizon: dict[str, int]) -> Run:
    """``init_state`` / ``step`` over every frame in eval mode: the running scores ``(T, B, K)``; ``horizon`` is the
    forward run's (a stream calls each layer once per frame)."""
    import torch

    model.eval()
    scores = []
    with torch.inference_mode(), SpikeRecorder(model) as rec:
        state = model.init_state(x.shape[0])
        for t, x_t in enumerate(x.unbind(1)):
            out, state = model.step(x_t, None if g is None else g[:, t], state)
            scores.append(out.float().cpu())
    return Run(torch.stack(scores), rec.counts, rec.steps, dict(horizon))


def compare_model(name: str, split: Any, device: torch.device, reference: torch.device | None = None,
                  checks: Sequence[str] = ("forward", "stream", "backward")) -> list[dict[str, Any]]:
    """Model ``name`` built for ``split.spec`` (seed 0), copied to ``device`` with the same weights, run on the
    samples of ``split`` on both devices; one row per check (``stream`` only for streaming models). The train-mode
    ``backward`` comes last: a batch-norm layer updates its running statistics there."""
    import torch

    from benchmarks.common import model_recipe
    from tactile_zoo.engine.build import build_model
    from tactile_zoo.registry import get_model_entry

    reference = reference or torch.device("cpu")
    spec = split.spec
    x, y = split.x, split.y
    g = split.g if split.g.shape[-1] > 0 else None
    ref_model = build_model(name, spec, seed=0).to(reference)
    dev_model = copy.deepcopy(ref_model).to(device)
    recipe = model_recipe(name)
    streaming = bool(get_model_entry(name).meta.get("streaming")) and callable(getattr(ref_model, "step", None))
    on = {"ref": (ref_model, x.to(reference), None if g is None else g.to(reference), y.to(reference)),
          "dev": (dev_model, x.to(device), None if g is None else g.to(device), y.to(device))}
    base = {"model": name, "dataset": spec.name, "batch": int(x.shape[0]), "steps": int(x.shape[1])}
    rows: list[dict[str, Any]] = []
    forward: dict[str, Run] = {}
    for check in checks:
        if check == "stream" and not streaming:
            continue
        start = time.perf_counter()
        runs: dict[str, Run] = {}
        for side, (model, xs, gs, ys) in on.items():
            if check == "forward":
                runs[side] = forward[side] = run_forward(model, xs, gs)
            elif check == "backward":
                runs[side] = run_backward(model, xs, gs, ys, recipe)
            else:
                fwd = forward.get(side) or run_forward(model, xs, gs)
                forward[side] = fwd
                runs[side] = run_stream(model, xs, gs, fwd.horizon)
        verdict = compare_runs(runs["ref"], runs["dev"])
        row = {**base, "check": check, "status": "pass" if verdict.pop("passed") else "FAIL",
               "note": verdict.pop("why"), **verdict, "seconds": time.perf_counter() - start}
        if check == "stream":  # the device's last streamed scores against its own forward (recorded, not judged)
            row["stream_vs_forward_diff"] = _max_abs(runs["dev"].scores[-1], forward["dev"].scores)
        rows.append(row)
    return rows


# --------------------------------------------------------------------------------------------- data
def simulated_datasets() -> list[str]:
    """The registered datasets generated by a simulator (no files needed), :data:`FIRST_DATASET` first."""
    from tactile_zoo.registry import get_dataset_entry, list_datasets

    names = [d for d in list_datasets() if get_dataset_entry(d).meta.get("simulated")]
    return sorted(names, key=lambda d: d != FIRST_DATASET)  # stable: the others keep the registry's order


def sim_split(name: str, split: str, steps: int | None = None, samples: int | None = None,
              per_class: int | None = None) -> Any:
    """A split of simulated dataset ``name`` as tensors: ``steps`` time steps (at least the simulator's minimum;
    ``None``: its default), ``per_class`` samples per class generated (``None``: its default), at most ``samples``
    of them kept (class-balanced, seeded)."""
    from tactile_zoo.engine import as_split, take
    from tactile_zoo.registry import get_dataset_entry, load_dataset

    kwargs: dict[str, Any] = {}
    if steps is not None:
        kwargs["num_steps"] = max(int(steps), int(getattr(get_dataset_entry(name).obj, "min_steps", 1)))
    if per_class is not None:  # the smallest generation that still holds the split asked for
        kwargs.update(n_train_per_class=max(2, per_class), n_test_per_class=max(1, per_class))
    return take(as_split(load_dataset(name, split=split, **kwargs)), samples, seed=0)


# --------------------------------------------------------------------------------------------- sections
def section_compare(ctx: Context, budget: Budget, models: list[str], datasets: list[str], batch: int,
                    steps: int | None, reference: torch.device) -> list[dict[str, Any]]:
    """Every model on every dataset (datasets outermost, so a short budget still checks every model once)."""
    from tactile_zoo.engine.build import ModelCannotConsume

    rows = []
    with tf32_off():
        for dataset in datasets:
            num_classes = _num_classes(dataset)
            split = sim_split(dataset, "test", steps=steps, samples=batch, per_class=-(-batch // num_classes))
            for name in models:
                base = {"model": name, "dataset": dataset, "batch": batch, "steps": int(split.x.shape[1])}
                if budget.left("compare") <= 0:
                    rows.append({**base, "check": "all", "status": "skipped", "note": "time budget spent"})
                    continue
                try:
                    got = compare_model(name, split, ctx.device, reference)
                except ModelCannotConsume as exc:
                    rows.append({**base, "check": "all", "status": "skipped", "note": str(exc).splitlines()[0]})
                    continue
                except Exception as exc:  # noqa: BLE001 - one broken model must not hide the others
                    traceback.print_exc()
                    rows.append({**base, "check": "all", "status": "error", "note": _first_line(exc)})
                    ctx.log(f"  {name} x {dataset}: ERROR {_first_line(exc)}")
                    continue
                rows += got
                ctx.log(f"  {name} x {dataset}: " + ", ".join(
                    f"{r['check']} {r['status']} (diff {r['max_abs_diff']:.2g}"
                    + (f", spikes {r['spike_rate_diff']:.2g} <= {r['spike_rate_limit']:.2g}"
                       if r.get("spike_rate_diff") is not None else "")
                    + (f", grad {r['grad_rel_diff']:.2g}" if r.get("grad_rel_diff") is not None else "") + ")"
                    for r in got))
    return rows


def time_model(ctx: Context, name: str, train: Any, reference: torch.device) -> dict[str, Any]:
    """One timing row of model ``name`` on ``train``: epoch seconds at the recipe's batch size (after a warm-up
    batch), batch-1 latency, batch-64 throughput and the epoch's peak GPU memory on ``ctx.device``; the batch-1
    latency on 1 thread of ``reference`` (the CPU) beside them when that is another device."""
    import torch

    from benchmarks.common import model_recipe, time_calls
    from tactile_zoo.engine import fit, take
    from tactile_zoo.engine.build import build_model

    recipe = model_recipe(name)
    model = build_model(name, train.spec, seed=0).to(ctx.device)
    fit(model, take(train, recipe.batch_size, seed=1), recipe=recipe, device=ctx.device, epochs=1)  # warm-up
    if ctx.device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(ctx.device)
    epoch = time_calls(lambda: fit(model, train, recipe=recipe, device=ctx.device, epochs=1), ctx.reps(3, 1), ctx,
                       warmup=0)
    peak = torch.cuda.max_memory_allocated(ctx.device) / 2**20 if ctx.device.type == "cuda" else None
    model.eval()
    x = train.x.to(ctx.device)
    g = train.g.to(ctx.device) if train.g.shape[-1] > 0 else None
    n = min(64, len(train))
    cpu_ms = None
    with torch.inference_mode():
        lat = time_calls(lambda: model(x[:1], None if g is None else g[:1]), ctx.reps(30, 10), ctx, warmup=3)
        thr = time_calls(lambda: model(x[:n], None if g is None else g[:n]), ctx.reps(10, 3), ctx)
        if ctx.device.type != reference.type:
            cpu_model = copy.deepcopy(model).to(reference)
            xc, gc = train.x[:1], (train.g[:1] if g is not None else None)
            with ctx.threads_scope(1):
                cpu_ms = time_calls(lambda: cpu_model(xc, gc), ctx.reps(10, 3), ctx).median * 1e3
    ordered = sorted(lat.times)
    return {"status": "ok", "batch_size": recipe.batch_size, "epoch_s": epoch.median, "epoch_min_s": epoch.min,
            "train_samples_per_s": len(train) / epoch.median, "repeats": len(epoch), "latency_ms": lat.median * 1e3,
            "latency_p90_ms": ordered[int(0.9 * (len(ordered) - 1))] * 1e3, "throughput_batch": n,
            "throughput_sps": n / thr.median, "cpu_latency_ms": cpu_ms, "gpu_peak_mb": peak}


def section_timing(ctx: Context, budget: Budget, models: list[str], dataset: str, samples: int | None,
                   steps: int | None, reference: torch.device) -> list[dict[str, Any]]:
    """:func:`time_model` for every model on the train split of ``dataset`` (at most ``samples`` of it)."""
    train = sim_split(dataset, "train", steps=steps, samples=samples)
    rows = []
    for name in models:
        base = {"model": name, "dataset": dataset, "samples": len(train), "steps": int(train.x.shape[1]),
                "tf32": _tf32_setting()}
        if budget.left("timing") <= 0:
            rows.append({**base, "status": "skipped", "note": "time budget spent"})
            continue
        try:
            row = {**base, **time_model(ctx, name, train, reference)}
        except Exception as exc:  # noqa: BLE001 - one broken model must not hide the others
            traceback.print_exc()
            rows.append({**base, "status": "error", "note": _first_line(exc)})
            ctx.log(f"  {name}: ERROR {_first_line(exc)}")
            continue
        rows.append(row)
        cpu = f" (CPU {row['cpu_latency_ms']:.1f} ms)" if row["cpu_latency_ms"] is not None else ""
        ctx.log(f"  {name}: epoch {row['epoch_s']:.2f} s ({len(train)} samples, batch {row['batch_size']}), "
                f"latency {row['latency_ms']:.2f} ms{cpu}, {row['throughput_sps']:.0f} samples/s at batch "
                f"{row['throughput_batch']}")
    return rows


def bench_command(device: str, out: Path, workers: int, quick: bool, epochs: int | None, models: str = "all",
                  datasets: str | None = None) -> list[str]:
    """The ``tactile-zoo bench`` arguments of the bench section (bench_wall's command, on ``device``)."""
    args = ["bench", "--models", models, "--out", str(out), "--device", device, "--executor", "process",
            "--workers", str(workers), "-q", "--no-plots"]
    if datasets:
        args += ["--datasets", datasets]
    if quick:
        args.append("--quick")
    if epochs is not None:
        args += ["--epochs", str(epochs)]
    return args


def run_bench_command(command: list[str], out: Path, timeout: float, env: dict[str, str] | None = None
                      ) -> dict[str, Any]:
    """Run ``command`` in its own process group, stopping the whole group after ``timeout`` seconds; count the
    cell records ``out/cells/*.json`` it left by status. Its output goes to ``bench-log.txt`` beside ``out``. A row
    of the bench section (without ``command``)."""
    log = out.parent / "bench-log.txt"
    start = time.perf_counter()
    with log.open("w") as fh:
        proc = subprocess.Popen(command, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        try:
            code: int | None = proc.wait(timeout=max(1.0, timeout))
        except subprocess.TimeoutExpired:
            code = None
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        except BaseException:  # interrupted: do not leave the bench running
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
    wall = time.perf_counter() - start
    statuses = []
    for path in sorted((out / "cells").glob("*.json")):
        try:
            statuses.append(str(json.loads(path.read_text()).get("status")))
        except (OSError, ValueError):
            statuses.append("unreadable")
    ok, skipped = statuses.count("ok"), statuses.count("skipped")
    failed = len(statuses) - ok - skipped
    if code is None:
        status, note = "timeout", f"stopped after {timeout:.0f} s (time budget); cells finished so far are counted"
    elif code != 0 or failed:
        status, note = "FAIL", f"exit {code}, {failed} cell(s) not ok: {log.read_text()[-600:].strip()}"
    else:
        status, note = "ok", ""
    return {"status": status, "exit_code": code, "cells_ok": ok, "cells_failed": failed, "cells_skipped": skipped,
            "wall_s": wall, "timeout_s": timeout, "note": note}


def section_bench(ctx: Context, budget: Budget, workers: int, epochs: int | None, models: str = "all",
                  datasets: str | None = None) -> list[dict[str, Any]]:
    """The embedded-default bench on ``ctx.device`` in a fresh folder with an empty data home and cache."""
    timeout = budget.left("bench") - 5.0  # keep a few seconds to write the results
    with tempfile.TemporaryDirectory(prefix="tz-gpu-check-bench-") as tmp:
        tmp_path = Path(tmp)
        (tmp_path / "data").mkdir()
        args = bench_command(str(ctx.device), tmp_path / "out", workers, ctx.quick, epochs, models, datasets)
        shown = "tactile-zoo " + " ".join("<fresh tmp dir>" if a.startswith(tmp) else a for a in args)
        base = {"case": "quick" if ctx.quick else "reduced", "command": shown, "workers": workers}
        if timeout < 20:
            return [{**base, "status": "skipped", "note": "time budget spent"}]
        env = {**os.environ, "TACTILE_ZOO_DATA": str(tmp_path / "data"), "TACTILE_ZOO_CACHE": str(tmp_path / "cache"),
               "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
        row = {**base, **run_bench_command([sys.executable, "-m", "tactile_zoo.cli", *args], tmp_path / "out",
                                           timeout, env)}
        ctx.out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(tmp_path / "bench-log.txt", ctx.out / f"{NAME}_bench.log")  # the child's own output
    ctx.log(f"  {shown}: {row['status']}, {row['wall_s']:.0f} s, {row['cells_ok']} cells ok, {row['cells_failed']} "
            f"failed, {row['cells_skipped']} skipped")
    return [row]


# --------------------------------------------------------------------------------------------- helpers
def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:300] if text else ''}"


def _num_classes(dataset: str) -> int:
    from tactile_zoo.registry import get_dataset_entry

    return int(get_dataset_entry(dataset).meta.get("num_classes") or 1)


def _names(arg: str | None, known: list[str], what: str, parser: argparse.ArgumentParser) -> list[str]:
    if arg is None:
        return list(known)
    names = [n.strip() for n in arg.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"unknown {what} {', '.join(unknown)}; choose from {', '.join(known)}")
    return names


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.gpu_check", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="sections: " + ", ".join(SECTIONS) + ". See benchmarks/README.md.")
    p.add_argument("--quick", action="store_true", help="smaller sizes and repeats; bench --quick")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="SECONDS",
                   help=f"time budget of the whole command (default {DEFAULT_TIMEOUT_S:.0f}); what does not fit is "
                        "skipped with a note")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="results folder (default benchmarks/results/cuda/)")
    p.add_argument("--only", default=None, metavar="SECTIONS", help="comma list of sections to run (default all)")
    p.add_argument("--skip", default=None, metavar="SECTIONS", help="comma list of sections to leave out")
    p.add_argument("--models", default=None, metavar="NAMES", help="comma list of models (default: all registered)")
    p.add_argument("--datasets", default=None, metavar="NAMES",
                   help="comma list of simulated datasets for compare; the first one is timing's (default: all "
                        "simulated ones, sim_evtouch first)")
    p.add_argument("--device", default="cuda", help="the CUDA device (default cuda)")
    p.add_argument("--batch", type=int, default=None, help="compare batch size (default 4; 2 with --quick)")
    p.add_argument("--steps", type=int, default=None,
                   help="time steps of the simulated samples (default: each dataset's own; at most 40 in compare "
                        "with --quick); raised to a simulator's minimum")
    p.add_argument("--samples", type=int, default=None,
                   help="training samples of the timed epoch (default: the whole train split; 64 with --quick)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default min(8, cores))")
    p.add_argument("--bench-workers", type=int, default=None, help="bench worker processes (default min(4, cores))")
    p.add_argument("--bench-epochs", type=int, default=None,
                   help="bench --epochs (default 3; with --quick, bench --quick's own 2)")
    p.add_argument("--allow-cpu", action="store_true",
                   help="internal (test suite): without CUDA, run everything with the device side on the CPU")
    return p


def _fmt_summary(rows: list[dict[str, Any]]) -> str:
    counts: dict[str, int] = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    return ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) or "nothing run"


@dataclass
class Plan:
    """What one run of the command does, from its options."""

    device: torch.device
    out: Path
    sections: list[str]
    models: list[str]
    datasets: list[str]
    quick: bool
    batch: int
    compare_steps: int | None
    steps: int | None
    samples: int | None
    threads: int
    workers: int
    bench_epochs: int | None
    bench_models: str
    bench_datasets: str | None
    timeout: float


def _plan(args: argparse.Namespace, parser: argparse.ArgumentParser, device: torch.device) -> Plan:
    from benchmarks.common import RESULTS
    from tactile_zoo.registry import list_models

    for opt in ("batch", "samples", "threads", "bench_workers", "steps"):
        if getattr(args, opt) is not None and getattr(args, opt) < 1:
            parser.error(f"--{opt.replace('_', '-')} must be >= 1")
    if args.bench_epochs is not None and args.bench_epochs < 1:
        parser.error("--bench-epochs must be >= 1")
    only = _names(args.only, list(SECTIONS), "section", parser)
    skip = _names(args.skip, list(SECTIONS), "section", parser) if args.skip else []
    models = _names(args.models, list_models(), "model", parser)
    datasets = _names(args.datasets, simulated_datasets(), "simulated dataset", parser)
    if not datasets:
        parser.error("no simulated dataset is registered")
    batch, max_steps = COMPARE_SIZES[args.quick]
    cores = os.cpu_count() or 1
    if args.out is not None:
        out = args.out
    elif device.type == "cuda":
        out = RESULTS / "cuda"
    else:  # a self-test never writes into the committed results
        out = Path(tempfile.mkdtemp(prefix="tz-gpu-check-"))
    return Plan(device=device, out=out, sections=[s for s in only if s not in skip], models=models,
                datasets=datasets, quick=args.quick, batch=args.batch or batch, compare_steps=args.steps or max_steps,
                steps=args.steps, samples=args.samples or (64 if args.quick else None),
                threads=args.threads or min(8, cores), workers=args.bench_workers or min(4, cores),
                bench_epochs=args.bench_epochs if args.bench_epochs is not None else (None if args.quick else 3),
                bench_models="all" if args.models is None else ",".join(models),
                bench_datasets=None if args.datasets is None else ",".join(datasets), timeout=args.timeout)


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    if not args.device.startswith("cuda"):
        parser.error("--device must be a CUDA device (cuda, cuda:N); --allow-cpu runs on the CPU")
    # torch first, to ask for CUDA; the rest only where the check will run (so the skip stays quick)
    missing = missing_package(("torch",), checkout=False)
    if missing is None:
        import torch

        if not torch.cuda.is_available() and not args.allow_cpu:
            print("gpu_check: CUDA is not available here; skipped (nothing written)", flush=True)
            return 0
        missing = missing_package()
    if missing:
        print(f"gpu_check: missing package {missing!r}: torch (with CUDA), torch_geometric and snntorch must already "
              f"be installed on this machine (this command installs nothing)", file=sys.stderr, flush=True)
        return 2
    import torch

    budget = Budget(args.timeout)
    plan = _plan(args, parser, torch.device(args.device) if torch.cuda.is_available() else torch.device("cpu"))
    threads_before = torch.get_num_threads()
    torch.set_num_threads(plan.threads)
    try:
        return run_check(plan, budget, sys.argv[1:] if argv is None else list(argv))
    finally:
        torch.set_num_threads(threads_before)


def _section(name: str, plan: Plan, ctx: Context, budget: Budget) -> list[dict[str, Any]]:
    import torch

    reference = torch.device("cpu")
    if name == "compare":
        rows = section_compare(ctx, budget, plan.models, plan.datasets, plan.batch, plan.compare_steps, reference)
        for row in rows:
            row.setdefault("case", f"{row['model']}/{row['dataset']}/{row['check']}")
    elif name == "timing":
        rows = section_timing(ctx, budget, plan.models, plan.datasets[0], plan.samples, plan.steps, reference)
        for row in rows:
            row.setdefault("case", row["model"])
    else:
        rows = section_bench(ctx, budget, plan.workers, plan.bench_epochs, plan.bench_models, plan.bench_datasets)
    return rows


def run_check(plan: Plan, budget: Budget, argv: list[str]) -> int:
    """Run the sections of ``plan``, writing each one's CSV as it ends and the JSON at the end; the exit status."""
    from benchmarks.common import Context, write_csv
    from tactile_zoo.engine.runtime import flush_denormals

    columns = {"compare": COMPARE_COLUMNS, "timing": TIMING_COLUMNS, "bench": BENCH_COLUMNS}
    results: dict[str, list[dict[str, Any]]] = {}
    with flush_denormals() as flushing:
        ctx = Context(device=plan.device, threads=plan.threads, quick=plan.quick, out=plan.out,
                      flush_denormals=flushing)
        gpu = ctx.env["gpu"] or "no GPU: --allow-cpu, both sides on the CPU"
        print(f"gpu_check on {plan.device} ({gpu}){' (quick)' if plan.quick else ''}: {len(plan.models)} models, "
              f"{len(plan.datasets)} simulated datasets, sections {', '.join(plan.sections) or 'none'}, budget "
              f"{plan.timeout:.0f} s, torch {ctx.env['torch']}, commit {ctx.env['git_commit'] or '?'}; results in "
              f"{plan.out}", flush=True)
        for section in plan.sections:
            print(f"[{section}] ({budget.spent():.0f} s spent)", flush=True)
            try:
                rows = _section(section, plan, ctx, budget)
            except Exception as exc:  # noqa: BLE001 - the next sections still run
                traceback.print_exc()
                rows = [{"case": section, "status": "error", "note": _first_line(exc)}]
            results[section] = rows
            path = write_csv(ctx, f"{NAME}_{section}", columns[section], rows)
            print(f"[{section}] {_fmt_summary(rows)}; wrote {path}", flush=True)
        failed = [r["case"] for rows in results.values() for r in rows if r["status"] in ("FAIL", "error")]
        skipped = [r["case"] for rows in results.values() for r in rows if r["status"] in ("skipped", "timeout")]
        summary = {"passed": not failed, "failed": failed, "skipped": skipped, "elapsed_s": budget.spent(),
                   "budget_s": plan.timeout, "device": str(plan.device), "quick": plan.quick, "argv": argv,
                   "logit_tol": LOGIT_TOL, "grad_tol": GRAD_TOL, "flush_denormals": flushing, "env": ctx.env,
                   "sections": results}
        plan.out.mkdir(parents=True, exist_ok=True)
        (plan.out / f"{NAME}.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
    verdict = ("FAILED: " + ", ".join(failed[:20]) + (" ..." if len(failed) > 20 else "")) if failed \
        else "all checks passed"
    note = f" ({len(skipped)} item(s) skipped or stopped for the time budget)" if skipped else ""
    print(f"gpu_check: {verdict}{note}; {budget.spent():.0f} s; {plan.out / (NAME + '.json')}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
