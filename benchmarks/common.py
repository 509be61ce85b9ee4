"""What every benchmark shares: the run context, interleaved timing, Ev-Objects data and the CSV writer.

Timing protocol: each implementation runs once untimed (warm-up: lazy buffers, allocator, caches), then the
implementations take turns, one run each per round, for ``repeats`` rounds (the order rotates every round), so load
from other processes hits all of them alike. The CSVs report the median and the minimum of each, and the ratio of
the medians. On CUDA every timed call is bracketed by ``torch.cuda.synchronize``.

Every row of every CSV carries the environment (CPU model, cores, threads, device, GPU, library versions,
tactile-zoo version, git commit, date), so a CSV read alone says where its numbers come from.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import functools
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

__all__ = ["BenchmarkSkipped", "Context", "Timing", "time_interleaved", "time_calls", "EvData", "ev_objects",
           "synthetic_events", "write_csv", "RESULTS", "ENV_COLUMNS", "fmt", "loglog_slope"]

REPO = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results"
#: columns appended to every row of every CSV
ENV_COLUMNS = ("quick", "device", "threads", "flush_denormals", "gpu", "cpu_model", "cpu_cores", "python", "torch",
               "torch_geometric", "snntorch", "tactile_zoo", "git_commit", "date")
#: the number of Ev-Objects training samples (the released train folder: our train + val splits)
EV_TRAIN_SAMPLES = 576
#: fraction of (time bin, taxel, polarity) cells holding an event in Ev-Objects' train folder (measured: 1436943 of
#: 576 x 250 x 39 x 2), used for synthetic stand-in data
EV_EVENT_DENSITY = 0.128


class BenchmarkSkipped(Exception):
    """A benchmark cannot run here for a reason outside this code (e.g. ``sgnet_reference`` without a checkout of
    the public reference): ``benchmarks.run`` reports the message and goes on without counting it as a failure."""


@dataclass
class Context:
    """One run of the suite: where, how long and how hard to measure.

    Args:
        device: ``cpu`` or ``cuda``.
        threads: torch intra-op threads for training benchmarks (latency benchmarks use 1 as the issue asks).
        quick: smaller repeat counts and sample subsets, for a check that the suite works (not for reporting).
        repeats: overrides every benchmark's repeat count.
        out: folder of the CSVs.
        root: data home holding ``ev_objects/raw/Ev-Objects.zip``.
        slow: also run the slow optional measurements (the LIF ``x[t]`` anti-pattern).
    """

    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    threads: int = 2
    quick: bool = False
    repeats: int | None = None
    out: Path = RESULTS
    root: Path | None = None
    slow: bool = False
    flush_denormals: bool = True
    log: Callable[[str], None] = print

    def reps(self, full: int, quick: int) -> int:
        """Repeat count: ``--repeats`` if given, else ``quick`` in quick mode, else ``full``."""
        return self.repeats if self.repeats is not None else (quick if self.quick else full)

    def sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    @contextlib.contextmanager
    def threads_scope(self, threads: int) -> Iterator[int]:
        """Run a block with ``threads`` intra-op threads, restoring the previous count after it."""
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            yield threads
        finally:
            torch.set_num_threads(before)

    @functools.cached_property
    def env(self) -> dict[str, Any]:
        from tactile_zoo.bench.environment import environment

        env = environment()
        ver = env["versions"]
        gpu = ""
        if self.device.type == "cuda":
            gpu = torch.cuda.get_device_name(self.device)
        return {"gpu": gpu, "cpu_model": env["cpu_model"], "cpu_cores": env["cpu_cores"],
                "python": env["python"], "torch": ver.get("torch", ""),
                "torch_geometric": ver.get("torch_geometric", ""), "snntorch": ver.get("snntorch", ""),
                "tactile_zoo": ver.get("tactile_zoo", ""), "git_commit": env["git_commit"] or ""}


# --------------------------------------------------------------------------------------------------------- timing
def _median(values: Sequence[float]) -> float:
    s = sorted(values)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


@dataclass
class Timing:
    """Wall-clock seconds of each timed run of one implementation, and the process CPU seconds of each (all threads;
    steadier than wall time when other processes compete for the cores)."""

    times: list[float]
    cpu: list[float] = field(default_factory=list)

    @property
    def median(self) -> float:
        return _median(self.times)

    @property
    def min(self) -> float:
        return min(self.times)

    @property
    def cpu_median(self) -> float:
        return _median(self.cpu) if self.cpu else float("nan")

    def __len__(self) -> int:
        return len(self.times)


def time_interleaved(fns: dict[str, Callable[[], object]], repeats: int, ctx: Context, warmup: int = 1
                     ) -> dict[str, Timing]:
    """Time several implementations side by side: ``warmup`` untimed calls each, then ``repeats`` rounds in which
    every implementation runs once (rotating order). Returns each one's :class:`Timing`."""
    names = list(fns)
    for name in names:
        for _ in range(warmup):
            fns[name]()
    ctx.sync()
    out = {name: Timing([], []) for name in names}
    for r in range(repeats):
        order = names[r % len(names):] + names[:r % len(names)]
        for name in order:
            ctx.sync()
            cpu, start = time.process_time(), time.perf_counter()
            fns[name]()
            ctx.sync()
            out[name].times.append(time.perf_counter() - start)
            out[name].cpu.append(time.process_time() - cpu)
    return out


def time_calls(fn: Callable[[], object], repeats: int, ctx: Context, warmup: int = 1) -> Timing:
    """Time one implementation (``warmup`` untimed calls, then ``repeats`` timed ones)."""
    return time_interleaved({"f": fn}, repeats, ctx, warmup)["f"]


def loglog_slope(xs: Sequence[float], ys: Sequence[float]) -> float:
    """Least-squares slope of ``log y`` against ``log x``: 1 for linear growth, 2 for quadratic."""
    lx, ly = [math.log(x) for x in xs], [math.log(y) for y in ys]
    mx, my = sum(lx) / len(lx), sum(ly) / len(ly)
    den = sum((a - mx) ** 2 for a in lx)
    return sum((a - mx) * (b - my) for a, b in zip(lx, ly)) / den if den else float("nan")


# ----------------------------------------------------------------------------------------------------------- data
@dataclass
class EvData:
    """Ev-Objects as the benchmarks use it: the 576 samples of the released train folder (our train + val splits),
    the 144 test samples, and where they came from (``"ev_objects"`` or ``"synthetic"``)."""

    train: Any  # tactile_zoo.engine.TensorSplit
    test: Any
    source: str


def synthetic_events(spec: Any, samples: int, seed: int = 0, density: float = EV_EVENT_DENSITY) -> Any:
    """A :class:`~tactile_zoo.engine.TensorSplit` of Bernoulli 0/1 events with Ev-Objects' event density, balanced
    labels: stand-in data of any shape, for timing only."""
    from tactile_zoo.engine import TensorSplit

    gen = torch.Generator().manual_seed(seed)
    shape = (samples, spec.num_steps, spec.num_nodes, spec.num_channels)
    x = (torch.rand(shape, generator=gen) < density).float()  # (S, T, N, C)
    g = torch.randn(samples, spec.num_steps, spec.num_globals, generator=gen)  # (S, T, G)
    y = torch.arange(samples) % spec.num_classes
    return TensorSplit(x, g, y, spec, "synthetic")


def ev_spec(num_steps: int = 250, copies: int = 1) -> Any:
    """Ev-Objects' :class:`DatasetSpec` (NeuTouch, 39 taxels, ON/OFF, 36 classes), optionally with another ``T`` or
    a sensor tiled ``copies`` times (``N = 39 * copies``) for scaling studies."""
    from tactile_zoo.data.datasets.ev import EV_OBJECTS_CLASSES
    from tactile_zoo.data.sensors import NEUTOUCH
    from tactile_zoo.data.spec import DatasetSpec

    sensor = NEUTOUCH if copies == 1 else NEUTOUCH.tiled(copies)
    return DatasetSpec("ev_objects" if (num_steps, copies) == (250, 1) else f"ev_objects_T{num_steps}_x{copies}",
                       len(EV_OBJECTS_CLASSES), EV_OBJECTS_CLASSES, num_steps, sensor.num_nodes, 2, 0, sensor)


def data_root(ctx: Context) -> Path | None:
    """``--root``, else ``$TACTILE_ZOO_DATA``, else ``$TACTILE_ZOO_SHARED_DATA`` or the ``../shared/data`` beside the
    checkout when it holds Ev-Objects (the project's shared data home), else tactile-zoo's default data home."""
    if ctx.root is not None:
        return ctx.root
    if os.environ.get("TACTILE_ZOO_DATA"):
        return Path(os.environ["TACTILE_ZOO_DATA"])
    shared = Path(os.environ.get("TACTILE_ZOO_SHARED_DATA", REPO.parent / "shared" / "data"))
    if (shared / "ev_objects" / "raw" / "Ev-Objects.zip").exists():
        return shared
    return None


_EV_CACHE: dict[Any, EvData] = {}


def ev_objects(ctx: Context) -> EvData:
    """Real Ev-Objects when its zip is in the data home, else synthetic events of the same shape (said in the CSVs'
    ``data`` column and in the log)."""
    root = data_root(ctx)
    if root in _EV_CACHE:
        return _EV_CACHE[root]
    from tactile_zoo.engine import as_split, concat
    from tactile_zoo.engine.build import load_splits
    from tactile_zoo.errors import TactileZooError

    try:
        splits = load_splits("ev_objects", root)
        train = concat(splits["train"], splits["val"])  # the released train folder, 576
        test = as_split(splits["test"])
        data = EvData(train, test, "ev_objects")
    except TactileZooError as exc:
        ctx.log(f"  Ev-Objects not found ({str(exc).splitlines()[0][:160]}...); using synthetic events of its "
                f"shape (timings only; the CSV's data column says so)")
        spec = ev_spec()
        data = EvData(synthetic_events(spec, EV_TRAIN_SAMPLES, seed=0), synthetic_events(spec, 144, seed=1),
                      "synthetic")
    _EV_CACHE[root] = data
    return data


# ------------------------------------------------------------------------------------------------------------ CSV
def fmt(value: Any) -> Any:
    """Floats to 4 significant digits (timings on shared machines carry no more); other values unchanged."""
    if isinstance(value, float):
        if value != value or value in (math.inf, -math.inf):
            return str(value)
        return float(f"{value:.4g}")
    return value


def write_csv(ctx: Context, name: str, columns: Sequence[str], rows: Sequence[dict[str, Any]]) -> Path:
    """Write ``<out>/<name>.csv``: ``benchmark, case, *columns, note`` then :data:`ENV_COLUMNS`, one line per row.

    A row's own ``threads`` (e.g. 1 for latency rows) wins over the context's."""
    header = ["benchmark", "case", *columns, "note", *ENV_COLUMNS]
    run = {"quick": ctx.quick, "device": str(ctx.device), "threads": ctx.threads,
           "flush_denormals": ctx.flush_denormals,
           "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"), **ctx.env}
    ctx.out.mkdir(parents=True, exist_ok=True)
    path = ctx.out / f"{name}.csv"
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=header, extrasaction="raise")
        writer.writeheader()
        for row in rows:
            unknown = set(row) - set(header)
            if unknown:
                raise KeyError(f"benchmark {name}: row has columns {sorted(unknown)} not declared in {header}")
            full = {**run, "benchmark": name, "note": "", **row}
            writer.writerow({k: fmt(full.get(k, "")) for k in header})
    tmp.replace(path)
    return path


# ------------------------------------------------------------------------------------------------ shared pieces
#: the columns of a side-by-side comparison (fast path vs naive counterpart)
PAIR_COLUMNS = ("fast", "naive", "fast_median_s", "fast_min_s", "naive_median_s", "naive_min_s", "ratio", "repeats",
                "fast_cpu_s", "naive_cpu_s", "ratio_cpu")


def pair_row(case: str, fast: str, naive: str, t_fast: Timing, t_naive: Timing, **extra: Any) -> dict[str, Any]:
    """One CSV row comparing two timings: ``ratio`` = naive median / fast median (how many times faster), and the
    same for the medians of process CPU seconds (``ratio_cpu``)."""
    return {"case": case, "fast": fast, "naive": naive, "fast_median_s": t_fast.median, "fast_min_s": t_fast.min,
            "naive_median_s": t_naive.median, "naive_min_s": t_naive.min, "ratio": t_naive.median / t_fast.median,
            "repeats": min(len(t_fast), len(t_naive)), "fast_cpu_s": t_fast.cpu_median,
            "naive_cpu_s": t_naive.cpu_median, "ratio_cpu": t_naive.cpu_median / t_fast.cpu_median, **extra}


def model_recipe(name: str) -> Any:
    """The registered training recipe of model ``name`` as a :class:`~tactile_zoo.engine.Recipe`."""
    from tactile_zoo.engine.config import resolve_model_recipe
    from tactile_zoo.registry import get_model_entry

    return resolve_model_recipe(get_model_entry(name).meta, owner=f"model {name!r}").recipe


def epoch_seconds(model: torch.nn.Module, split: Any, recipe: Any, ctx: Context, seed: int = 0) -> float:
    """Seconds of one training epoch of ``model`` on ``split`` through the engine's own loop (``fit``, one epoch, no
    validation): the time of the epoch alone, as ``fit`` records it."""
    from tactile_zoo.engine import fit

    result = fit(model, split, recipe=recipe, seed=seed, device=ctx.device, epochs=1)
    return float(result.curve[0]["seconds"])
