"""The child process of :mod:`benchmarks.vs_pinned`: one timed Ev-Objects training epoch of one model.

Run by path, ``python -P benchmarks/pinned_child.py '<job json>'``, with ``PYTHONPATH`` set to the root of the version
to time; it imports nothing but torch and that version's ``tactile_zoo``, and only API the pinned commit has too, so
the pinned and the current version are timed by this same code. Prints one JSON line.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from typing import Any

# the version's package before torch, as the command line imports it: whatever it sets up before torch loads counts
# (torch itself is imported inside the functions, after it)
import tactile_zoo  # noqa: F401

#: the Ev-Objects training samples (the released train folder: train + val splits)
EV_TRAIN_SAMPLES = 576
EV_EVENT_DENSITY = 0.128  # as benchmarks.common: synthetic stand-in events when the zip is absent


def _train_split(root: str | None) -> tuple[Any, str]:
    import torch

    from tactile_zoo.engine import TensorSplit
    from tactile_zoo.engine.cell import load_splits
    from tactile_zoo.engine.tensors import concat
    from tactile_zoo.errors import TactileZooError

    try:
        splits = load_splits("ev_objects", root)
        return concat(splits["train"], splits["val"]), "ev_objects"
    except TactileZooError:
        from tactile_zoo.data.datasets.ev import EV_OBJECTS_CLASSES
        from tactile_zoo.data.sensors import NEUTOUCH
        from tactile_zoo.data.spec import DatasetSpec

        spec = DatasetSpec("ev_objects", len(EV_OBJECTS_CLASSES), EV_OBJECTS_CLASSES, 250, NEUTOUCH.num_nodes, 2, 0,
                           NEUTOUCH)
        gen = torch.Generator().manual_seed(0)
        x = (torch.rand(EV_TRAIN_SAMPLES, 250, spec.num_nodes, 2, generator=gen) < EV_EVENT_DENSITY).float()
        g = torch.zeros(EV_TRAIN_SAMPLES, 250, 0)  # (S, T, G = 0)
        y = torch.arange(EV_TRAIN_SAMPLES) % spec.num_classes
        return TensorSplit(x, g, y, spec, "synthetic"), "synthetic"


def _model_and_recipe(name: str, spec: Any, hparams: dict[str, Any]) -> tuple[Any, Any]:
    """The model and its default recipe (no dataset section), through whichever API the timed version has."""
    from tactile_zoo import registry

    meta = registry.get_model_entry(name).meta
    build = getattr(registry, "instantiate_model", None) or registry.create_model  # renamed by issue 39
    try:  # since issue 39: the one resolution of the configuration room
        from tactile_zoo.engine.config import resolve_model_recipe

        recipe = resolve_model_recipe(meta).recipe
    except ImportError:  # the pinned commit
        from tactile_zoo.engine import resolve_recipe
        from tactile_zoo.recipe import named_recipe_for

        recipe = resolve_recipe(named_recipe_for(meta.get("recipe"), None)[0])
    return (lambda: build(name, spec, **hparams)), recipe


def measure(job: dict[str, Any]) -> dict[str, Any]:
    import dataclasses

    import torch

    from tactile_zoo.engine import fit, seed_everything, take
    from tactile_zoo.engine.runtime import flush_denormals

    try:  # the current version tunes glibc's malloc where bench and train start (issue 40); the pinned one has none
        from tactile_zoo.engine.malloc import tune_malloc

        tuned = bool(tune_malloc())
    except ImportError:
        tuned = False
    torch.set_num_threads(job["threads"])
    name, device = job["model"], torch.device(job["device"])
    train, data = _train_split(job["root"])
    build, recipe = _model_and_recipe(name, train.spec, job.get("hparams") or {})
    if job.get("batch_size"):  # both versions time the same batches, whatever their recipes say
        recipe = dataclasses.replace(recipe, batch_size=job["batch_size"])
    bs = recipe.batch_size
    timed = take(train, bs * job["batches"], seed=0) if job["batches"] else train
    with flush_denormals():  # on before the first fit, as benchmarks.run does for the whole suite
        seed_everything(0)
        model = build().to(device)
        fit(model, take(train, bs, seed=1), recipe=recipe, device=device, epochs=1)  # warm-up: lazy buffers
        loadavg = os.getloadavg()
        before, start = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        fit(model, timed, recipe=recipe, device=device, epochs=1)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    scale = EV_TRAIN_SAMPLES / len(timed)
    return {"epoch_s": wall * scale, "epoch_cpu_s": cpu * scale, "batch_size": bs, "samples_timed": len(timed),
            "loadavg": loadavg, "cpu_capability": torch.backends.cpu.get_cpu_capability(), "data": data,
            "peak_rss_mb": after.ru_maxrss / 1024, "malloc_tuned": tuned}


if __name__ == "__main__":
    print(json.dumps(measure(json.loads(sys.argv[1]))))
