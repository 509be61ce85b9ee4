"""Training seconds per Ev-Objects epoch, this checkout against a pinned commit, side by side (issue 30, item 4).

``python -m benchmarks.vs_pinned [--commit b84155b | --pinned DIR] [--models ...] [--batches N] [--threads 2]``, or
``python -m benchmarks.run --only vs_pinned`` (defaults). The pinned copy is the commit's tree exported by
``git archive`` into a temporary folder (no worktree metadata left behind; removed at the end), or an existing
checkout given by ``--pinned``. For every model and repeat the two versions run in rotating order, each in a fresh
child process whose ``PYTHONPATH`` is that version's root: the child loads Ev-Objects (the 576 samples of the released
train folder), builds the model with seed 0, trains one untimed warm-up batch, then times one training epoch through
the engine's ``fit`` at the recipe's batch size (``--batches N``: the first ``N`` batches of a class-balanced subset,
scaled to 576 samples; the CSV's ``samples_timed`` says which). The child is one script of this checkout,
``benchmarks/pinned_child.py``, run by path (``python -P``): both versions are timed by the same code and only
``tactile_zoo`` differs.

``ratio`` = pinned median / current median (how many times faster this checkout is). Every row carries the load
averages before and after its measurements, the CPU model and torch's CPU capability (AVX2, AVX-512): on a shared
machine only ratios of interleaved runs mean anything, and a run under load favours neither version.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from .common import EV_TRAIN_SAMPLES, REPO, Context, data_root, write_csv

NAME = "vs_pinned"
TITLE = "Seconds per Ev-Objects training epoch, this checkout vs the pre-issue-30 commit, side by side"
#: the commit issue 30 started from
PINNED_COMMIT = "b84155b"
#: the script each child runs (by path, so that it comes from this checkout whichever version it times)
CHILD = Path(__file__).resolve().with_name("pinned_child.py")
#: issue 40's targets (issue 30's were 2x each)
TARGETS = {"convlstm": 1.4, "dcnn": 1.5, "sgnet": 2.5, "tacformer": 1.4, "x_tacformer": 1.4}
MODELS = ("convlstm", "dcnn", "sgnet", "tacformer", "x_tacformer", "cnn_lstm")
COLUMNS = ("model", "hparams", "batch_size", "samples_timed", "pinned_commit", "current_median_s", "pinned_median_s",
           "ratio", "current_min_s", "pinned_min_s", "current_cpu_s", "pinned_cpu_s", "ratio_cpu", "repeats", "target",
           "current_peak_rss_mb", "pinned_peak_rss_mb", "malloc_tuned", "loadavg_before", "loadavg_after",
           "cpu_capability")

__all__ = ["run", "compare", "pinned_tree", "child_env", "NAME", "TITLE"]


def pinned_tree(commit: str, dest: Path) -> Path:
    """Export ``commit``'s tree into ``dest`` (``git archive | tar -x``) and return it."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", commit], capture_output=True,
                             check=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    return dest


def child_env(root: Path, threads: int, extra: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a child timing the version under ``root``: this process's, plus ``extra`` (settings
    given to one version only, e.g. ``THP_MEM_ALLOC_ENABLE=1``: see ``--env-current``)."""
    env = {**os.environ, **(extra or {})}
    # OpenMP's pool must not outnumber the cores torch is given: more threads than that spin against each other;
    # no bytecode written: a --pinned checkout is read, never changed
    env.update(PYTHONPATH=str(root), OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads),
               PYTHONDONTWRITEBYTECODE="1")
    return env


def _run_child(root: Path, job: dict[str, Any], extra: dict[str, str] | None = None) -> dict[str, Any]:
    """One timed epoch of ``job["model"]`` with the ``tactile_zoo`` under ``root``, in a fresh process."""
    env = child_env(root, job["threads"], extra)
    # -P: the script's folder (benchmarks/) stays off sys.path, so only ``root``'s packages are importable
    proc = subprocess.run([sys.executable, "-P", str(CHILD), json.dumps(job)],
                          cwd=root, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{job['model']} under {root} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def parse_variant(text: str) -> tuple[str, dict[str, Any]]:
    """``"sgnet[compute=event]"`` -> ``("sgnet", {"compute": "event"})``: a model with constructor keywords (separated
    by ``;``) given to the current version only (an opt-in revision the pinned commit does not have); values are parsed
    as JSON where they can be (numbers, booleans), else kept as strings."""
    name, _, rest = text.partition("[")
    if rest and not rest.endswith("]"):
        raise ValueError(f"--models: {text!r} is not of the form model[key=value;...]")
    hparams: dict[str, Any] = {}
    for item in filter(None, rest[:-1].split(";")):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"--models: {item!r} in {text!r} is not key=value")
        try:
            hparams[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            hparams[key.strip()] = value.strip()
    return name.strip(), hparams


def current_batch_size(name: str) -> int:
    """The batch size of ``name``'s default recipe in this checkout: both versions time batches of this size."""
    from tactile_zoo.engine.config import resolve_model_recipe
    from tactile_zoo.registry import get_model_entry

    return resolve_model_recipe(get_model_entry(name).meta).recipe.batch_size


def compare(ctx: Context, pinned: Path, commit: str, models: tuple[str, ...] = MODELS, batches: int | None = None,
            repeats: int | None = None, env_current: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """The CSV rows: for each model, ``repeats`` rounds of (current, pinned) in rotating order."""
    root = data_root(ctx)
    reps = repeats or ctx.reps(3, 1)
    versions = {"current": REPO, "pinned": pinned}
    rows = []
    for case in models:
        name, hparams = parse_variant(case)
        job = {"model": name, "threads": ctx.threads, "batches": batches, "device": str(ctx.device),
               "root": None if root is None else str(root), "batch_size": current_batch_size(name)}
        load_before = os.getloadavg()
        got: dict[str, list[dict[str, Any]]] = {"current": [], "pinned": []}
        for r in range(reps):
            order = ["current", "pinned"] if r % 2 == 0 else ["pinned", "current"]
            for version in order:
                mine = {**job, "hparams": hparams} if version == "current" else job
                res = _run_child(versions[version], mine, env_current if version == "current" else None)
                got[version].append(res)
                ctx.log(f"  {case} [{version}] {res['epoch_s']:.2f} s/epoch (load {res['loadavg'][0]:.2f})")
        load_after = os.getloadavg()
        wall = {v: [g["epoch_s"] for g in got[v]] for v in got}
        cpu = {v: [g["epoch_cpu_s"] for g in got[v]] for v in got}
        cur, pin = statistics.median(wall["current"]), statistics.median(wall["pinned"])
        cur_cpu, pin_cpu = statistics.median(cpu["current"]), statistics.median(cpu["pinned"])
        first = got["current"][0]
        rows.append({"case": case, "model": name, "hparams": json.dumps(hparams, sort_keys=True) if hparams else "",
                     "batch_size": first["batch_size"],
                     "samples_timed": first["samples_timed"], "pinned_commit": commit, "current_median_s": cur,
                     "pinned_median_s": pin, "ratio": pin / cur, "current_min_s": min(wall["current"]),
                     "pinned_min_s": min(wall["pinned"]), "current_cpu_s": cur_cpu, "pinned_cpu_s": pin_cpu,
                     "ratio_cpu": pin_cpu / cur_cpu, "repeats": reps,
                     "target": f">= {TARGETS[name]}x" if name in TARGETS else "",
                     "current_peak_rss_mb": max(g.get("peak_rss_mb", 0.0) for g in got["current"]),
                     "pinned_peak_rss_mb": max(g.get("peak_rss_mb", 0.0) for g in got["pinned"]),
                     "malloc_tuned": first.get("malloc_tuned", False),
                     "loadavg_before": " ".join(f"{v:.2f}" for v in load_before),
                     "loadavg_after": " ".join(f"{v:.2f}" for v in load_after),
                     "cpu_capability": first["cpu_capability"],
                     "threads": ctx.threads,
                     "note": ("one whole epoch" if first["samples_timed"] == EV_TRAIN_SAMPLES else
                              f"{first['samples_timed']} samples timed, scaled to {EV_TRAIN_SAMPLES}")
                     + f"; data {first['data']}"
                     + (f"; current run with {' '.join(f'{k}={v}' for k, v in env_current.items())}"
                        if env_current else "")})
        ctx.log(f"  {case}: current {cur:.2f} s, pinned {pin:.2f} s per epoch: {pin / cur:.2f}x")
        write_csv(ctx, NAME, COLUMNS, rows)  # after every model: a long run stopped early keeps what it measured
    return rows


def run(ctx: Context, commit: str = PINNED_COMMIT, pinned: Path | None = None, models: tuple[str, ...] = MODELS,
        batches: int | None = None, repeats: int | None = None, env_current: dict[str, str] | None = None) -> Path:
    if ctx.quick and batches is None:
        batches = 2
    tmp = None
    try:
        if pinned is None:
            tmp = Path(tempfile.mkdtemp(prefix="tactile-zoo-pinned-"))
            pinned = pinned_tree(commit, tmp / "tree")
            ctx.log(f"  pinned copy of {commit} in {pinned}")
        rows = compare(ctx, pinned, commit, models, batches, repeats, env_current)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return write_csv(ctx, NAME, COLUMNS, rows)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.vs_pinned", description=TITLE)
    p.add_argument("--commit", default=PINNED_COMMIT, help=f"the commit to compare against (default {PINNED_COMMIT})")
    p.add_argument("--pinned", type=Path, default=None, help="an existing checkout of it (default: exported afresh)")
    p.add_argument("--models", default=",".join(MODELS),
                   help="comma list of models; model[key=value;...] gives the current version constructor keywords")
    p.add_argument("--batches", type=int, default=None, help="time this many batches, not a whole epoch")
    p.add_argument("--repeats", type=int, default=3, help="rounds of (current, pinned) per model (default 3)")
    p.add_argument("--threads", type=int, default=2, help="torch threads in the children (default 2)")
    p.add_argument("--root", type=Path, default=None, help="data home with ev_objects/raw/Ev-Objects.zip")
    p.add_argument("--out", type=Path, default=None, help="folder of the CSV (default benchmarks/results/)")
    p.add_argument("--env-current", action="append", default=[], metavar="VAR=VALUE",
                   help="set VAR for the current version's children only (repeatable), e.g. THP_MEM_ALLOC_ENABLE=1")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from tactile_zoo.engine.runtime import flush_denormals

    with flush_denormals() as flushing:
        ctx = Context(threads=args.threads, root=args.root, flush_denormals=flushing,
                      **({"out": args.out} if args.out else {}))
        env_current = dict(item.split("=", 1) for item in args.env_current)
        path = run(ctx, args.commit, args.pinned, tuple(m.strip() for m in args.models.split(",") if m.strip()),
                   args.batches, args.repeats, env_current or None)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
