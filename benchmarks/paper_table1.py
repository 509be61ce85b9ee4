"""The README's Table I: the X-Tacformer paper's test accuracies next to ours, from the committed leaderboard.

``python -m benchmarks.paper_table1 [DIR]`` (default ``benchmarks/results/paper-table1``) reads the cell files of
``DIR/cells`` and prints a Markdown table: for each model and dataset the paper's figure, our mean +- std of test
accuracy over the finished seeds (with their count), and the mean training time per cell. Only ok cells of the
``source`` recipe computed by the current revision of their model's and dataset's code count (the filter of
:func:`benchmarks.fidelity.cells`); the others are counted in a footnote; a model with no such cell reads "not run
yet".

The paper's figures are Table I of "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition" (test
accuracy on the fixed released splits of Ev-Objects and Ev-Containers); it reports no D-CNN row.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

DATASETS = ("ev_objects", "ev_containers")
PAPER = {  # model -> (Ev-Objects, Ev-Containers), Table I of the X-Tacformer paper
    "sgnet": (0.8944, 0.6417),
    "convlstm": (0.8611, 0.7333),
    "cnn_lstm": (0.8472, 0.7167),
    "tacformer": (0.9027, 0.7500),
    "x_tacformer": (0.9167, 0.7833),
    "dcnn": (None, None),
}
NAMES = {"sgnet": "SGnet", "convlstm": "ConvLSTM", "cnn_lstm": "CNN-LSTM", "tacformer": "Tacformer",
         "x_tacformer": "X-Tacformer", "dcnn": "D-CNN"}


def _ours(records: list[dict[str, Any]]) -> str:
    accs = [r["metrics"]["test"]["accuracy"] for r in records]
    if not accs:
        return "not run yet"
    std = f" +- {statistics.stdev(accs):.4f}" if len(accs) > 1 else ""
    minutes = statistics.fmean(r["train_seconds"] for r in records) / 60
    return f"{statistics.fmean(accs):.4f}{std} ({len(accs)} seed{'s' if len(accs) > 1 else ''}, {minutes:.0f} min)"


def table(folder: Path) -> str:
    from benchmarks.fidelity import cells

    current = cells(folder)
    lines = ["| model | paper Ev-Objects | ours Ev-Objects | paper Ev-Containers | ours Ev-Containers |",
             "|---|---|---|---|---|"]
    for model, paper in PAPER.items():
        row = []
        for dataset, figure in zip(DATASETS, paper):
            mine = [r for r in current if r["model"] == model and r["dataset"] == dataset]
            row += ["-" if figure is None else f"{figure:.4f}", _ours(mine)]
        lines.append(f"| {NAMES[model]} | " + " | ".join(row) + " |")
    left_out = len(list((folder / "cells").glob("*.json"))) - len(current)
    if left_out:
        lines.append(f"\n{left_out} cell file(s) are left out: not ok, another recipe, or computed by an older "
                     f"revision of their model's code (to be rerun).")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.paper_table1", description=__doc__.split("\n")[0])
    p.add_argument("folder", nargs="?", type=Path, default=Path("benchmarks/results/paper-table1"))
    args = p.parse_args(argv)
    if not (args.folder / "cells").is_dir():
        print(f"error: {args.folder / 'cells'} not found", file=sys.stderr)
        return 2
    print(table(args.folder))
    return 0


if __name__ == "__main__":
    sys.exit(main())
