"""CPU/CUDA parity: run one model on two devices with the same weights and judge the difference.

Used by ``test_cuda_parity.py`` (CUDA against the CPU; skipped without CUDA) and tested on the CPU alone by
``test_parity_helpers.py``, so the judgement is checked where no GPU exists. ``python -m benchmarks.gpu_check`` runs
the CUDA tests on a lent GPU machine.

Three checks per model and dataset: ``forward`` (eval mode), ``stream`` (``init_state`` / ``step`` frame by frame,
for models registered with ``streaming=True``: the running scores after every frame) and ``backward`` (train mode
with dropout off: the loss of the model's recipe and every parameter's gradient). Logits must agree within
:data:`LOGIT_TOL` (max abs difference) and gradients within :data:`GRAD_TOL` of the largest gradient. Spiking models
(those with :class:`~tactile_zoo.nn.lif.MultiStepLIF` layers, whose output spikes are counted per neuron) must not
differ by more than one spike per neuron over a sequence of ``T`` steps of that layer: a spike-rate mismatch of at
most ``1/T`` (a stream calls a layer once per frame, re-reading an open frame bin, and is held to the same ``1/T``
of the layer's forward sequence). One membrane landing within rounding of the threshold on one device legitimately
flips a spike, and with it the logits downstream, so logits and gradients of a spiking model are judged only when
every spike agrees (the usual case); otherwise they are recorded and the row says so.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

#: logits: max abs difference CUDA vs CPU
LOGIT_TOL = 1e-4
#: gradients: max abs difference over all parameters / max abs gradient
GRAD_TOL = 1e-3
#: the simulated dataset checked first (event-based NeuTouch, like Ev-Objects), when registered
FIRST_DATASET = "sim_evtouch"
#: samples per comparison
BATCH = 4


@contextlib.contextmanager
def tf32_off() -> Iterator[None]:
    """TF32 off for matmuls and cuDNN inside the block (float32 on both devices), restored after it."""
    before = (torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = before


class SpikeRecorder:
    """Counts the output spikes of every :class:`~tactile_zoo.nn.lif.MultiStepLIF` of a model while active.

    The layer's ``forward`` is wrapped on the instance, so both ``layer(x)`` and ``layer.step(x_t)`` (which calls
    ``self.forward``) are seen. Per layer (by module name): ``counts`` the spikes of each neuron summed over time and
    calls (float64), ``steps`` the time steps it ran, ``calls`` how often it ran.
    """

    def __init__(self, model: nn.Module) -> None:
        from tactile_zoo.nn.lif import MultiStepLIF

        self.layers = {name: m for name, m in model.named_modules() if isinstance(m, MultiStepLIF)}
        self.counts: dict[str, torch.Tensor] = {}
        self.steps: dict[str, int] = {}
        self.calls: dict[str, int] = {}

    def _wrap(self, name: str, layer: nn.Module) -> Callable[..., Any]:
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
            layer.__dict__.pop("forward", None)  # the class's forward again
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


def max_abs(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest absolute difference in float64; ``inf`` for other shapes or a non-finite difference."""
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

    Returns the measurements, ``passed`` and ``why`` (the reasons it failed, or a note)."""
    out: dict[str, Any] = {"max_abs_diff": max_abs(ref.scores, dev.scores), "spike_rate_diff": None,
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
            worst_abs = max(worst_abs, max_abs(a, b))
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


def _dropout_off(model: nn.Module) -> None:
    """Train mode (batch statistics, cuDNN's training kernels) without the randomness of dropout."""
    model.train()
    for m in model.modules():
        if isinstance(m, (nn.Dropout, nn.Dropout1d, nn.Dropout2d, nn.Dropout3d, nn.AlphaDropout,
                          nn.FeatureAlphaDropout)):
            m.eval()


def run_forward(model: nn.Module, x: torch.Tensor, g: torch.Tensor | None) -> Run:
    """Eval-mode forward under ``inference_mode``, spikes counted."""
    model.eval()
    with torch.inference_mode(), SpikeRecorder(model) as rec:
        scores = model(x, g)
    return Run(scores.float().cpu(), rec.counts, rec.steps, {k: rec.steps[k] // rec.calls[k] for k in rec.steps})


def run_backward(model: nn.Module, x: torch.Tensor, g: torch.Tensor | None, y: torch.Tensor, recipe: Any) -> Run:
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


def run_stream(model: nn.Module, x: torch.Tensor, g: torch.Tensor | None, horizon: dict[str, int]) -> Run:
    """``init_state`` / ``step`` over every frame in eval mode: the running scores ``(T, B, K)``; ``horizon`` is the
    forward run's (a stream calls each layer once per frame)."""
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
    samples of ``split`` on both devices; one row per check (``stream`` only for streaming models), with ``status``
    ``pass`` or ``FAIL`` and ``note`` saying why. The train-mode ``backward`` comes last: a batch-norm layer updates
    its running statistics there."""
    from tactile_zoo.engine.build import build_model
    from tactile_zoo.engine.config import resolve_model_recipe
    from tactile_zoo.registry import get_model_entry

    reference = reference or torch.device("cpu")
    spec = split.spec
    x, y = split.x, split.y
    g = split.g if split.g.shape[-1] > 0 else None
    ref_model = build_model(name, spec, seed=0).to(reference)
    dev_model = copy.deepcopy(ref_model).to(device)
    entry = get_model_entry(name)
    recipe = resolve_model_recipe(entry.meta, owner=f"model {name!r}").recipe
    streaming = bool(entry.meta.get("streaming")) and callable(getattr(ref_model, "step", None))
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
        status = "pass" if verdict.pop("passed") else "FAIL"
        if check == "backward" and status == "FAIL":
            # a model that draws noise in training mode (the multi-barrel SNN, as released) differs from itself:
            # two devices' random streams cannot be compared, and saying so is the honest verdict
            model, xs, gs, ys = on["ref"]
            again = run_backward(model, xs, gs, ys, recipe)
            if not torch.equal(again.scores, runs["ref"].scores):
                status = "skip"
                verdict["why"] = (f"stochastic in training mode: two runs on {reference} differ by "
                                  f"{max_abs(again.scores, runs['ref'].scores):.3g} in the scores, so the devices' "
                                  f"random draws are not comparable ({verdict['why']})")
        row = {**base, "check": check, "status": status,
               "note": verdict.pop("why"), **verdict, "seconds": time.perf_counter() - start}
        if check == "stream":  # the device's last streamed scores against its own forward (recorded, not judged)
            row["stream_vs_forward_diff"] = max_abs(runs["dev"].scores[-1], forward["dev"].scores)
        rows.append(row)
    return rows


def simulated_datasets() -> list[str]:
    """The registered datasets generated by a simulator (no files needed), :data:`FIRST_DATASET` first."""
    from tactile_zoo.registry import get_dataset_entry, list_datasets

    names = [d for d in list_datasets() if get_dataset_entry(d).meta.get("simulated")]
    return sorted(names, key=lambda d: d != FIRST_DATASET)  # stable: the others keep the registry's order


def sim_split(name: str, batch: int = BATCH, steps: int | None = None) -> Any:
    """``batch`` seeded, class-balanced samples of the test split of simulated dataset ``name`` as tensors, with
    ``steps`` time steps (at least the simulator's minimum; ``None``: its default); only as many samples per class
    are generated as the batch needs."""
    from tactile_zoo.engine import as_split, take
    from tactile_zoo.registry import get_dataset_entry, load_dataset

    entry = get_dataset_entry(name)
    per_class = -(-batch // int(entry.meta.get("num_classes") or 1))
    kwargs: dict[str, Any] = {"n_train_per_class": max(2, per_class), "n_test_per_class": max(1, per_class)}
    if steps is not None:
        kwargs["num_steps"] = max(int(steps), int(getattr(entry.obj, "min_steps", 1)))
    return take(as_split(load_dataset(name, split="test", **kwargs)), batch, seed=0)
