"""E3 of EXPERIMENTS.md: the source's protocol as closely as our API allows: train on ALL basic-object windows (train +
val of the objects protocol, no held-out split), exactly 30 epochs, keep the LAST epoch, then evaluate each unseen set.

Run from the repository root: ``OMP_NUM_THREADS=1 .venv/bin/python -m tools.experiments.convlstm_biotac_e3 SEED``
(writes ``benchmarks/results/convlstm-biotac/e3_seed<SEED>.json``, the record it produced; kept in
``benchmarks/results/`` until it moved here, a script among results).
"""
import json
import sys
import time
from pathlib import Path

import torch

import tactile_zoo as tz
from tactile_zoo.engine import fit
from tactile_zoo.engine.tensors import concat

torch.set_num_threads(1)
seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
kw = dict(root="../shared/data", window=5, stride=5, normalize="none")
splits = {s: tz.load_dataset("biotac_dos", split=s, **kw)
          for s in ("train", "val", "test_solids", "test_small", "test_textures")}
train = concat(splits["train"], splits["val"])
recipe = {"max_epochs": 30, "patience": None, "batch_size": 32, "lr": 1e-3, "grad_clip": None}
t0 = time.time()
res = fit("convlstm", train, recipe, seed=seed, val_dataset=None, device="cpu",
          hparams={"frame_norm": "minmax", "init": "torch"})
out = {"seed": seed, "n_train": len(train), "best_epoch": res.best_epoch, "epochs_run": res.epochs_run,
       "train_seconds": res.train_seconds, "curve": res.curve, "recipe": res.recipe.to_dict()}
for s in ("test_solids", "test_small", "test_textures"):
    r = tz.evaluate(res.model, splits[s])
    out[s] = r.metrics["accuracy"]
out["train_accuracy_last_epoch_model"] = tz.evaluate(res.model, train).metrics["accuracy"]
out["mean3"] = sum(out[s] for s in ("test_solids", "test_small", "test_textures")) / 3
out["seconds"] = time.time() - t0
print(json.dumps({k: v for k, v in out.items() if k != "curve"}))
RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "convlstm-biotac"
dest = Path(sys.argv[2]) if len(sys.argv) > 2 else RESULTS / f"e3_seed{seed}.json"
dest.write_text(json.dumps(out, indent=1))
