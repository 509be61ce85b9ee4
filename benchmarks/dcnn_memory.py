"""Peak memory of D-CNN training on Ev-Containers: its pools keeping only their argmax indices vs ``nn.MaxPool2d``.

The Table I cells of ``dcnn`` on Ev-Containers (325 x 78 images, batch 128) peaked at 3.4-3.5 GB, above the 3 GB
target. What a training step keeps for its backward pass dominates (measured: 2.3 GB of activations at batch 128),
and ``nn.MaxPool2d`` kept its input, the batch norm's output, which its CPU backward never reads: 870 MB over the
three blocks. The model's pools now keep only their indices (``tactile_zoo.models.dcnn._IndexOnlyMaxPool``: the same
ATen kernels, bit-identical outputs and gradients).

Side by side, each in a fresh child process (so neither inherits the other's heap), 1 thread as the bench cells run:
``index_only`` is the model as registered, ``maxpool2d`` the same model with the three pools swapped back to
``nn.MaxPool2d(2, ceil_mode=True)``. Each builds ``dcnn`` with seed 0, trains one epoch over Ev-Containers' 200
training samples at the recipe's batch size (128, then 72) through ``fit``, then scores the 60 test samples
(batch 256: one batch). ``peak_rss_mb`` is the resident-set high-water mark of the epoch (``VmHWM`` reset through
``/proc/self/clear_refs`` at its start, so it includes the interpreter, torch, the model and the dataset),
``eval_peak_rss_mb`` that of the test scoring, ``process_peak_rss_mb`` the child's peak over its whole life (the
largest of the three windows: loading, training, scoring);
``max_logit_diff`` compares each trained model's test logits with ``index_only``'s (0: the same computation).
Synthetic events of the same shape stand in where Ev-Containers is absent (``data`` says so; memory depends on the
shapes only).

The third case, ``index_only_tuned``, is ``index_only`` with the malloc settings training processes apply at start-up
(``tactile_zoo.engine.malloc.SETTINGS``, through ``mallopt``; ``malloc`` names them, ``default`` is glibc's own).
``train_page_faults`` (minor and major, from ``getrusage``) and ``train_sys_s`` (system CPU seconds) cover the
training epoch; on a loaded machine they move far less than ``epoch_s``. ``measure`` also takes any other settings and
an epoch count (docs/performance.md has the table they produced).

Run it alone: ``python -m benchmarks.dcnn_memory [--root DIR] [--quick]``; it writes ``results/dcnn_memory.csv``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import torch

from .common import REPO, Context, data_root, model_recipe, synthetic_events, write_csv

NAME = "dcnn_memory"
TITLE = "D-CNN training peak RSS and page faults on Ev-Containers: index-only pools vs nn.MaxPool2d, tuned malloc"
COLUMNS = ("pool", "malloc", "batch_size", "samples", "data", "peak_rss_mb", "eval_peak_rss_mb",
           "process_peak_rss_mb", "rss_source", "epoch_s", "train_page_faults", "train_sys_s", "max_logit_diff",
           "target")
VARIANTS = {"index_only": "_IndexOnlyMaxPool (keeps the argmax indices)",
            "maxpool2d": "nn.MaxPool2d(2, ceil_mode=True) (keeps its input too)"}
#: case -> (pool variant, malloc settings: None = glibc's defaults, "tuned" = what training processes apply)
CASES = {"index_only": ("index_only", None), "maxpool2d": ("maxpool2d", None),
         "index_only_tuned": ("index_only", "tuned")}


def _splits(root: Path | None) -> tuple[Any, Any, str]:
    """Ev-Containers' train and test splits, else synthetic events of their shapes."""
    from tactile_zoo.engine.build import load_splits
    from tactile_zoo.errors import TactileZooError

    try:
        splits = load_splits("ev_containers", root)
        return splits["train"], splits["test"], "ev_containers"
    except TactileZooError:
        from tactile_zoo.data.datasets.ev import EV_CONTAINERS_CLASSES
        from tactile_zoo.data.sensors import NEUTOUCH
        from tactile_zoo.data.spec import DatasetSpec

        spec = DatasetSpec("ev_containers", len(EV_CONTAINERS_CLASSES), EV_CONTAINERS_CLASSES, 325,
                           NEUTOUCH.num_nodes, 2, 0, NEUTOUCH)
        return synthetic_events(spec, 200, seed=0), synthetic_events(spec, 60, seed=1), "synthetic"


def _malloc(settings: str | dict[str, int] | None) -> str:
    """Apply ``settings`` (None: glibc's defaults, ``"tuned"``: tune_malloc's, or a dict for mallopt); its label."""
    from tactile_zoo.engine.malloc import SETTINGS, apply_mallopt

    if settings is None:
        return "default"
    chosen = SETTINGS if settings == "tuned" else settings
    applied = apply_mallopt(chosen)
    if applied is None:
        return "default (not glibc)"
    return " ".join(f"{name}={value}" for name, value in chosen.items())


def measure(variant: str, root: Path | None, samples: int | None,
            malloc: str | dict[str, int] | None = None, epochs: int = 1,
            test_samples: int | None = None) -> dict[str, Any]:
    """Train ``dcnn`` one epoch with the ``variant``'s pools in this process; one CSV row plus its test logits (of at
    most ``test_samples`` test samples, class-balanced and seeded: the same ones in every case)."""
    import resource

    from torch import nn

    malloc_label = _malloc(malloc)

    from tactile_zoo.engine import PeakMemory, fit, predict_scores, seed_everything, take
    from tactile_zoo.engine.runtime import flush_denormals
    from tactile_zoo.registry import instantiate_model

    train, test, source = _splits(root)
    if samples is not None and samples < len(train):
        train = take(train, samples, seed=0)
    if test_samples is not None and test_samples < len(test):
        test = take(test, test_samples, seed=0)
    recipe = model_recipe("dcnn")
    seed_everything(0)
    model = instantiate_model("dcnn", train.spec)
    if variant == "maxpool2d":
        for block in model.features:
            block[-1] = nn.MaxPool2d(2, ceil_mode=True)
    before_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # the reset below clears ru_maxrss too
    usage = resource.getrusage(resource.RUSAGE_SELF)
    with PeakMemory() as peak:
        result = fit(model, train, recipe=recipe, epochs=epochs)
    after = resource.getrusage(resource.RUSAGE_SELF)
    with PeakMemory() as eval_peak, flush_denormals():
        logits = predict_scores(model, test.x, test.g, recipe.eval_batch_size)
    return {"pool": VARIANTS[variant], "malloc": malloc_label, "batch_size": recipe.batch_size, "samples": len(train),
            "data": source, "peak_rss_mb": peak.mb, "eval_peak_rss_mb": eval_peak.mb,
            "process_peak_rss_mb": round(max(before_mb, peak.mb or 0.0, eval_peak.mb or 0.0), 1),
            "rss_source": peak.source,
            "epoch_s": round(sum(float(row["seconds"]) for row in result.curve) / len(result.curve), 3),
            "train_page_faults": after.ru_minflt - usage.ru_minflt + after.ru_majflt - usage.ru_majflt,
            "train_sys_s": round(after.ru_stime - usage.ru_stime, 2), "logits": logits.tolist()}


def child(job: dict[str, Any], variant: str, malloc: str | dict[str, int] | None, env: dict[str, str]
          ) -> dict[str, Any]:
    """One measurement in a fresh child process (so that no case inherits another's heap or malloc settings)."""
    proc = subprocess.run([sys.executable, "-m", "benchmarks.dcnn_memory", "--child",
                           json.dumps({**job, "variant": variant, "malloc": malloc})],
                          cwd=REPO, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"measuring {variant} ({malloc}) failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(ctx: Context, samples: int | None = None, test_samples: int | None = None) -> Path:
    """The three cases, each in a fresh child; ``samples`` training samples (``--quick``: 32, else all 200), and the
    logits compared over ``test_samples`` test samples (all 60 unless given: the suite's test takes fewer)."""
    root = data_root(ctx)
    job = {"root": None if root is None else str(root), "threads": ctx.threads, "test_samples": test_samples,
           "samples": samples if samples is not None else (32 if ctx.quick else None)}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    rows = []
    for case, (variant, malloc) in CASES.items():
        rows.append({"case": case, **child(job, variant, malloc, env)})
    ref = torch.tensor(rows[0]["logits"])
    for row in rows:
        row["max_logit_diff"] = float((torch.tensor(row.pop("logits")) - ref).abs().max())
        row["target"] = "peak < 3 GB (issue 18), the same outputs"
        row["note"] = "one training epoch, then the test split in one batch; fresh child process, 1 thread" \
            if row["samples"] == 200 else f"{row['samples']} training samples (--quick)"
        if test_samples is not None:
            row["note"] += f"; logits of {test_samples} test samples"
        ctx.log(f"  {row['case']}: training peak {row['peak_rss_mb']} MB, eval peak {row['eval_peak_rss_mb']} MB, "
                f"process peak {row['process_peak_rss_mb']} MB, {row['train_page_faults']} page faults, "
                f"{row['train_sys_s']} s system time, logits differ by {row['max_logit_diff']:g}")
    return write_csv(ctx, NAME, COLUMNS, rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=TITLE)
    parser.add_argument("--quick", action="store_true", help="32 training samples: checks that it runs")
    parser.add_argument("--root", type=Path, default=None, help="data home with ev_containers/raw/Ev-Containers.zip")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)  # one variant, in a fresh process
    args = parser.parse_args(argv)
    torch.set_num_threads(1)  # as the bench cells run
    if args.child is not None:
        job = json.loads(args.child)
        torch.set_num_threads(job["threads"])
        root = None if job["root"] is None else Path(job["root"])
        print(json.dumps(measure(job["variant"], root, job["samples"], job.get("malloc"), job.get("epochs", 1),
                                 job.get("test_samples"))))
        return 0
    ctx = Context(quick=args.quick, threads=1, root=args.root, **({"out": args.out} if args.out else {}))
    path = run(ctx)
    print(path.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
