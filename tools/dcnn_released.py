"""D-CNN with the published weights: the ten Keras models released with Augment8000 on its 120 real-life samples.

``python -m tools.dcnn_released --root ../shared/data`` reads
``<root>/augment8000/released_models/VGG16_scaling_time_warp{1..10}.h5`` (the file name says VGG16; the model inside
is the D-CNN) through :func:`tactile_zoo.models.dcnn.from_keras`, and ``<root>/augment8000/raw/000_real_life_data.csv``
through our ``augment8000`` loader with the release's preprocessing: the object-weight compensation and the
published normalisation constants (``stats="source"``). It writes ``benchmarks/results/dcnn_released.csv``: one row
per model (``file, correct, n, accuracy``) and a ``total`` row over the 1200 predictions, with the environment
columns every benchmark CSV carries.

Target: 871 of 1200 correct (0.7258, the mean of the ten, the D-CNN figure the X-Tacformer paper quotes), +-5.
Evaluation only: the release's 2000-sample training file is not available, so nothing here is trained.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

import torch

from benchmarks.common import RESULTS, Context, write_csv

NAME = "dcnn_released"
MODELS = tuple(f"VGG16_scaling_time_warp{i}.h5" for i in range(1, 11))
TARGET, TOLERANCE = 871, 5  # of 10 x 120 predictions: the X-Tacformer paper's D-CNN accuracy 0.7258
COLUMNS = ("file", "correct", "n", "accuracy")


def real_life(root: Path) -> Any:
    """The 120 real-life samples, preprocessed as the release does: ``test`` when the training file is present (the
    paper's protocol), else every sample (with the real-life file alone, ``test`` is one fold of a k-fold)."""
    import tactile_zoo as tz

    both = (root / "augment8000" / "raw" / "000_training_data.csv").is_file()
    with warnings.catch_warnings():  # the loader warns that the training file is missing; expected here
        warnings.simplefilter("ignore", UserWarning)
        split = tz.load_dataset("augment8000", root=root, split="test" if both else None, stats="source")
    if len(split) != 120:
        raise RuntimeError(f"expected the 120 real-life samples under {root}, got {len(split)}")
    return split


def run(ctx: Context, root: Path) -> tuple[Path, int]:
    """Evaluate the ten models; returns the CSV's path and the total number correct."""
    from tactile_zoo.engine import evaluate
    from tactile_zoo.models.dcnn import from_keras

    split = real_life(root)
    folder = root / "augment8000" / "released_models"
    rows: list[dict[str, Any]] = []
    for file in MODELS:
        model = from_keras(folder / file, split.spec)
        result = evaluate(model, split, device="cpu")
        correct = sum(p == t for p, t in zip(result.predictions, result.targets))
        rows.append({"case": "model", "file": file, "correct": correct, "n": len(result.targets),
                     "accuracy": correct / len(result.targets)})
        ctx.log(f"{file}: {correct}/{len(result.targets)} = {correct / len(result.targets):.4f}")
    correct, n = sum(r["correct"] for r in rows), sum(r["n"] for r in rows)
    rows.append({"case": "total", "file": "all ten", "correct": correct, "n": n, "accuracy": correct / n,
                 "note": f"target {TARGET} +- {TOLERANCE} of {n} (0.7258, X-Tacformer paper's D-CNN figure)"})
    ctx.log(f"total: {correct}/{n} = {correct / n:.4f} (target {TARGET} +- {TOLERANCE})")
    return write_csv(ctx, NAME, COLUMNS, rows), correct


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.dcnn_released", description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, default=Path("../shared/data"),
                   help="data home with augment8000/raw/ and augment8000/released_models/ (default ../shared/data)")
    p.add_argument("--out", type=Path, default=RESULTS, help="folder of the CSV (default benchmarks/results)")
    args = p.parse_args(argv)
    torch.set_num_threads(1)  # 120 small images per model: threads buy nothing
    path, correct = run(Context(threads=1, out=args.out, root=args.root), args.root)
    print(f"wrote {path}")
    return 0 if abs(correct - TARGET) <= TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main())
