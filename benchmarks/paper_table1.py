"""The README's Table I: the X-Tacformer paper's test accuracies next to ours, from the committed leaderboard.

``python -m benchmarks.paper_table1 [DIR]`` (default ``benchmarks/results/paper-table1``) reads ``DIR/leaderboard.csv``
(``tactile-zoo report DIR`` regenerates it from the cell files) and prints a Markdown table: for each model and
dataset the paper's figure, our mean +- std of test accuracy over the finished seeds (with their count), and the mean
training time per cell. Cells that are not ``ok`` are left out and counted in a footnote; a model with no finished
cell reads "not run yet".

The paper's figures are Table I of "X-Tacformer: Spatio-temporal Attention Model for Tactile Recognition" (test
accuracy on the fixed released splits of Ev-Objects and Ev-Containers); it reports no D-CNN row.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from pathlib import Path

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


def _ours(rows: list[dict[str, str]]) -> str:
    accs = [float(r["accuracy"]) for r in rows]
    if not accs:
        return "not run yet"
    std = f" +- {statistics.stdev(accs):.4f}" if len(accs) > 1 else ""
    minutes = statistics.fmean(float(r["train_seconds"]) for r in rows) / 60
    return f"{statistics.fmean(accs):.4f}{std} ({len(accs)} seed{'s' if len(accs) > 1 else ''}, {minutes:.0f} min)"


def table(leaderboard: Path) -> str:
    with leaderboard.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    ok = [r for r in rows if r["status"] == "ok"]
    lines = ["| model | paper Ev-Objects | ours Ev-Objects | paper Ev-Containers | ours Ev-Containers |",
             "|---|---|---|---|---|"]
    for model, paper in PAPER.items():
        cells = []
        for dataset, figure in zip(DATASETS, paper):
            mine = [r for r in ok if r["model"] == model and r["dataset"] == dataset]
            cells += ["-" if figure is None else f"{figure:.4f}", _ours(mine)]
        lines.append(f"| {NAMES[model]} | " + " | ".join(cells) + " |")
    not_ok = len(rows) - len(ok)
    if not_ok:
        lines.append(f"\n{not_ok} cell(s) of the leaderboard are not ok and are left out.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.paper_table1", description=__doc__.split("\n")[0])
    p.add_argument("folder", nargs="?", type=Path, default=Path("benchmarks/results/paper-table1"))
    args = p.parse_args(argv)
    leaderboard = args.folder / "leaderboard.csv"
    if not leaderboard.is_file():
        print(f"error: {leaderboard} not found; run `tactile-zoo report {args.folder}` first", file=sys.stderr)
        return 2
    print(table(leaderboard))
    return 0


if __name__ == "__main__":
    sys.exit(main())
