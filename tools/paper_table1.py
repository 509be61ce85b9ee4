"""Table I (``docs/table1.md``): one table per dataset, the X-Tacformer paper's figure next to ours with a 95 %
interval, and the README's headline of it.

    python -m tools.paper_table1 [DIR]      # print it (default DIR: benchmarks/results/paper-table1)
    python -m tools.paper_table1 --readme   # rewrite docs/table1.md's tables and the README's headline block
    python -m tools.paper_table1 --check    # exit 1 if either block is not what the cells give, or if a headline row
                                            # reads another recipe than its model's registered default

Reads the cell files of ``DIR/cells`` (nothing is trained) and prints Markdown: for Ev-Objects, Ev-Containers and
BioTac-DoS, per model the paper's figure, our mean ± sample std of test accuracy over the finished runs (seeds, or
folds where a dataset's validation rotates), the 95 % confidence interval of the expected accuracy
(:func:`tactile_zoo.bench.intervals.records_interval`: one draw of the test units per resample shared by the runs,
plus the runs' spread; a unit is a test sample on the Ev datasets and a recording on BioTac-DoS), the number of
runs and the mean training time of a cell; then the Augment8000 table, whose only figure is the D-CNN released
weights' (``benchmarks/results/dcnn_released.csv``). The README's headline reads each model's registered default
recipe alone (:mod:`tools.headline`).

Only ok cells of the ``source`` recipe computed by the current revision of their model's and dataset's code count
(the filter of :func:`tools.fidelity.cells`); the others are counted in a footnote. A model whose cells on one
dataset hold more than one configuration is an error: one table row must be one configuration.

The paper's figures are its Table I (test accuracy; how the epoch was selected is not stated). Its BioTac-DoS column
is the textures set (X-Tacformer 0.8833 minus ConvLSTM 0.7380 is the 0.1453 gain the paper states for textures);
the other two unseen sets are shown beside it. It gives no SGnet BioTac-DoS figure and no D-CNN Ev figure.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from pathlib import Path
from typing import Any

from tactile_zoo.bench.intervals import bootstrap_accuracy, records_interval
from tactile_zoo.bench.paired import holm, records_paired
from tactile_zoo.bench.records import run_records
from tools.headline import README, block, problems, render_headline
from tools.table1_common import EV, MODELS, NAMES, PAPER, RESULTS, _figure, _group, _where, paper_column

BIOTAC_SETS = ("test_textures", "test_solids", "test_small")
READING = ("Figures: mean ± sample std over runs. The 95 % interval is a confidence interval for the expected "
           "accuracy of this training procedure on this task (over training seeds, on the population the test set "
           "was drawn from): one draw of the test units (samples; recordings on BioTac-DoS) per resample, shared by "
           "all runs, since they share the test set, plus the runs' spread with its small-sample t quantile. In "
           "simulated experiments like these it covered the truth 93-96 % of the time "
           "(`benchmarks/results/interval_coverage.md`). A paper figure above the interval is one these runs do not "
           "reproduce, and two models whose intervals overlap widely are not told apart.")


def _mean_std(values: list[float]) -> str:
    return f"{statistics.fmean(values):.4f}" + (f" ± {statistics.stdev(values):.4f}" if len(values) > 1 else "")


def _interval(recs: list[dict[str, Any]], split: str = "test") -> str:
    low_high = records_interval(recs, split)
    return "-" if low_high is None else f"[{low_high[0]:.3f}, {low_high[1]:.3f}]"


def _runs(recs: list[dict[str, Any]]) -> str:
    folds, seeds = sorted({r["fold"] for r in recs}), sorted({r["seed"] for r in recs})
    what = f"{len(recs)} ({len(folds)} folds x {len(seeds)} seed{'s' if len(seeds) > 1 else ''})" if len(folds) > 1 \
        else f"{len(recs)} seed{'s' if len(recs) > 1 else ''}"
    return what


def _minutes(recs: list[dict[str, Any]]) -> str:
    return f"{statistics.fmean(r['train_seconds'] for r in recs) / 60:.0f}"


def ev_table(records: list[dict[str, Any]], dataset: str) -> list[str]:
    title, column, what = EV[dataset]
    lines = [f"**{title}** ({what})", "", "| model | paper | ours: mean ± std | 95 % interval | runs | min per cell |",
             "|---|---|---|---|---|---|"]
    for model in MODELS:
        paper = PAPER[model][column]
        recs = _group(records, model, dataset)
        figures = [_mean_std([r["metrics"]["test"]["accuracy"] for r in recs]), _interval(recs), _runs(recs),
                   _minutes(recs)] if recs else ["not run yet", "-", "0", "-"]
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | " + " | ".join(figures) + " |")
    return lines


def biotac_table(records: list[dict[str, Any]]) -> list[str]:
    lines = ["**BioTac-DoS** (trained on the 4 basic objects, tested on the 7 unseen ones; the paper's column is "
             "textures)", "",
             "| model | paper (textures) | ours: textures | 95 % interval | solids | small | mean of the 3 sets | runs "
             "| min per cell |", "|---|---|---|---|---|---|---|---|---|"]
    for model in MODELS:
        paper = PAPER[model][2]
        recs = _group(records, model, "biotac_dos")
        if recs:
            per_set = {s: [r["metrics"][s]["accuracy"] for r in recs] for s in BIOTAC_SETS}
            mean3 = [statistics.fmean(values) for values in zip(*per_set.values())]
            figures = [_mean_std(per_set["test_textures"]), _interval(recs, "test_textures"),
                       f"{_mean_std(per_set['test_solids'])} {_interval(recs, 'test_solids')}",
                       f"{_mean_std(per_set['test_small'])} {_interval(recs, 'test_small')}", _mean_std(mean3),
                       _runs(recs), _minutes(recs)]
        else:
            figures = ["not run yet", "-", "-", "-", "-", "0", "-"]
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | " + " | ".join(figures) + " |")
    return lines


def augment8000_table(released: Path = RESULTS / "dcnn_released.csv") -> list[str]:
    lines = ["**Augment8000** (the 120 real-life samples; the 2000-sample training file is not released, so nothing "
             "is trained on it)", "", "| model | paper | ours |", "|---|---|---|"]
    rows = list(csv.DictReader(released.open())) if released.is_file() else []
    models = [r for r in rows if r["case"] == "model"]
    total = [r for r in rows if r["case"] == "total"]
    for model in MODELS:
        paper = PAPER[model][3]
        if model == "dcnn" and total:
            correct, n = int(total[0]["correct"]), int(total[0]["n"])
            per_model = [int(r["correct"]) / int(r["n"]) for r in models]
            ours = (f"{correct}/{n} = {correct / n:.4f} ± {statistics.stdev(per_model):.4f} over the "
                    f"{len(models)} released models (released weights, evaluation only)")
        else:
            ours = "needs the training file (not released)"
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | {ours} |")
    return lines


#: the split each dataset's comparison reads: the declared column (BioTac-DoS: textures, as the paper)
ZOO_SPLITS = {"ev_objects": "test", "ev_containers": "test", "biotac_dos": "test_textures"}


def zoo_table(source: list[dict[str, Any]], zoo: list[dict[str, Any]], dataset: str) -> list[str]:
    """The ``zoo`` recipe beside ``source`` and the paper on one dataset: a paired bootstrap of ``zoo - source`` over
    the runs both have (same fold and seed) and their test units, one-sided, Holm-corrected across the models."""
    split = ZOO_SPLITS[dataset]
    title = EV[dataset][0] if dataset in EV else "BioTac-DoS (textures)"
    column = paper_column(dataset)
    paired, same, rows = {}, set(), {}
    for model in MODELS:
        src, new = _group(source, model, dataset), _group(zoo, model, dataset)
        rows[model] = (src, new)
        if src and new and {r["config_hash"] for r in src} == {r["config_hash"] for r in new}:
            same.add(model)
        if src and new and {(r["fold"], r["seed"]) for r in src} & {(r["fold"], r["seed"]) for r in new}:
            paired[model] = records_paired(src, new, split)
    adjusted = holm({m: r.p_value for m, r in paired.items() if m not in same})
    lines = [f"**`zoo` against `source` on {title}** (accuracy [95 % interval] (runs); the difference is paired over "
             "the runs both recipes have, one-sided p Holm-corrected across the models)", "",
             "| model | paper | `source` | `zoo` | `zoo - source`, paired [95 %] (pairs) | Holm p | reading |",
             "|---|---|---|---|---|---|---|"]
    verdicts: dict[str, list[str]] = {"better": [], "noise": [], "worse": [], "same": [], "pending": []}
    for model in MODELS:
        src, new = rows[model]
        paper = PAPER[model][column]
        result = paired.get(model)
        new_interval = records_interval(new, split) if new else None
        if result is None:
            diff, p_text, reading = "-", "-", "not run yet"
            verdicts["pending"].append(NAMES[model])
        else:
            diff = f"{result.difference:+.4f} [{result.low:+.3f}, {result.high:+.3f}] ({result.n_cells})"
            if model in same:
                p_text, reading = "-", "the same configuration"
                verdicts["same"].append(NAMES[model])
            else:
                p_text = f"{adjusted[model]:.3f}"
                if adjusted[model] < 0.05:
                    reading = "`zoo` better"
                    verdicts["better"].append(NAMES[model])
                elif result.high < 0:
                    reading = "`zoo` worse"
                    verdicts["worse"].append(NAMES[model])
                else:
                    reading = "within noise"
                    verdicts["noise"].append(NAMES[model])
            if paper is not None and new_interval is not None:
                reading += f"; paper {_where(paper, new_interval)} the `zoo` interval"
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | {_figure(src, split)} | "
                     f"{_figure(new, split, new_interval)} | {diff} | {p_text} | {reading} |")
    said = [f"{what}: {', '.join(names)}" for what, names in (
        ("`zoo` better (Holm p < 0.05)", verdicts["better"]), ("within noise", verdicts["noise"]),
        ("`zoo` worse", verdicts["worse"]), ("trained identically", verdicts["same"]),
        ("not run yet", verdicts["pending"])) if names]
    lines += ["", f"On {title}: " + "; ".join(said) + "."]
    return lines


ENSEMBLE_SEEDS = (0, 1, 2, 3, 4)  # declared in paper-table1-zoo/README.md: every one of the five zoo seeds


def seed_ensemble(recs: list[dict[str, Any]], split: str = "test") -> tuple[float, float, float] | None:
    """The seed ensemble of ``recs`` on ``split``: the class of highest mean stored probability per test sample, its
    accuracy and a 95 % interval over the test units (recordings where the records list them). ``None`` when a record
    stores no probabilities for ``split``; a record scored on another test set is an error."""
    import numpy as np

    stored = [(r.get("predictions") or {}).get(split) or {} for r in recs]
    if not recs or any("probabilities" not in pred for pred in stored):
        return None
    targets = np.asarray(stored[0]["targets"])
    for r, pred in zip(recs[1:], stored[1:]):
        if not np.array_equal(np.asarray(pred["targets"]), targets):
            raise SystemExit(f"{r['cell_id']}: another {split} set than {recs[0]['cell_id']}")
    mean = np.mean([np.asarray(pred["probabilities"]) for pred in stored], axis=0)  # (S, K)
    predictions = mean.argmax(1)
    groups = stored[0].get("groups")
    low_high = bootstrap_accuracy([(targets, predictions)], groups=None if groups is None else [groups])
    assert low_high is not None
    return float((predictions == targets).mean()), *low_high


def ensemble_table(records: list[dict[str, Any]], dataset: str, recipe: str = "zoo") -> list[str]:
    """The declared seed ensembles of ``recipe`` on ``dataset`` (``<model>_ens5`` for ``zoo``,
    ``<model>_<recipe>_ens5`` otherwise): the mean of the five seeds' stored test probabilities (:func:`seed_ensemble`)
    on the dataset's declared split (:data:`ZOO_SPLITS`)."""
    split = ZOO_SPLITS[dataset]
    title = EV[dataset][0] if dataset in EV else "BioTac-DoS (textures)"
    column = paper_column(dataset)
    name = "<model>_ens5" if recipe == "zoo" else f"<model>_{recipe}_ens5"
    what = "Declared seed ensembles" if recipe == "zoo" else f"Declared `{recipe}` seed ensembles"
    units = "test samples" if dataset in EV else "test recordings"
    lines = [f"**{what} on {title}** (`{name}`: the five `{recipe}` seeds' test probabilities averaged; one run, the "
             f"interval resamples the {units})", "",
             f"| model | paper | `{recipe}`, mean of the five seeds | `{name}` | 95 % interval |",
             "|---|---|---|---|---|"]
    for model in MODELS:
        recs = [r for r in _group(records, model, dataset) if r["seed"] in ENSEMBLE_SEEDS and r["fold"] == 0]
        paper = PAPER[model][column]
        if sorted(r["seed"] for r in recs) != list(ENSEMBLE_SEEDS):
            figures = ["-", f"{len(recs)} of 5 seeds so far", "-"]
        elif (ensemble := seed_ensemble(recs, split)) is None:
            figures = [f"{statistics.fmean(r['metrics'][split]['accuracy'] for r in recs):.4f}",
                       f"no stored probabilities for `{split}`", "-"]
        else:
            accuracy, low, high = ensemble
            figures = [f"{statistics.fmean(r['metrics'][split]['accuracy'] for r in recs):.4f}", f"{accuracy:.4f}",
                       f"[{low:.3f}, {high:.3f}]"]
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | " + " | ".join(figures) + " |")
    return lines


def cost_table(records: list[dict[str, Any]], what: str = "this table", fresh: str | None = None,
               target: float = 5.0) -> list[str]:
    """What the table cost: per model and dataset the summed wall time of its cells (each ran on one torch thread,
    two cells at a time on two cores, so a cell's wall time is about its CPU time). ``fresh``: the folder name of one
    measured run of the default recipe (``table1-cost/``, ``table1-cost-r4/``), whose total is a performance issue's
    figure against ``target`` CPU-hours."""
    datasets = (*EV, "biotac_dos")
    lines = [f"**What {what} cost** (the cells' own recorded times, `seconds` in each cell file: CPU-minutes of one "
             "thread, summed over the runs)", "",
             "| model | " + " | ".join(EV[d][0] if d in EV else "BioTac-DoS" for d in datasets) + " | model total |",
             "|---|" + "---|" * (len(datasets) + 1)]
    grand, runs = 0.0, 0
    for model in MODELS:
        row, total = [], 0.0
        for dataset in datasets:
            recs = _group(records, model, dataset)
            minutes = sum(r.get("seconds", r["train_seconds"]) for r in recs) / 60
            total, runs = total + minutes, runs + len(recs)
            row.append(f"{minutes:.0f} ({len(recs)} run{'s' if len(recs) != 1 else ''})" if recs else "-")
        grand += total
        lines.append(f"| {NAMES[model]} | " + " | ".join(row) + f" | {total:.0f} |")
    if what == "this table":
        lines += ["", f"In all {grand / 60:.1f} CPU-hours, each cell computed from scratch in its own run (the target "
                  "of the performance issue was 5). The same configuration took up to twice as long when its cell "
                  "shared the machine with other work (Tacformer on Ev-Containers: 8 to 18 minutes over three seeds), "
                  "so these sums are upper bounds for a quiet pair of cores."]
    elif fresh:
        cpus = sorted({r.get("cpu", "unknown CPU") for r in records})
        planned = len(MODELS) * len(datasets) * 3  # seeds 0-2
        lines += ["", f"In all {grand / 60:.1f} CPU-hours for {runs} of the {planned} runs (the performance issue's "
                  f"target: {target:g}), one fresh run on {' and '.join(cpus)}, two cells at a time, one torch thread "
                  f"each (how it ran: `benchmarks/results/{fresh}/README.md`)."]
    else:
        lines += ["", f"In all {grand / 60:.1f} CPU-hours for {runs} runs, each run computed from scratch."]
    return lines


def table(folder: Path, zoo_folder: Path | None = None) -> str:
    """The tables of ``folder``'s ``source`` cells; where ``zoo_folder`` (default: the sibling ``<folder>-zoo``, as
    ``paper-table1-zoo`` beside ``paper-table1``) holds ``zoo`` cells, each dataset's comparison follows its table."""
    from tools.fidelity import cells

    current = cells(folder)
    zoo_folder = folder.parent / f"{folder.name}-zoo" if zoo_folder is None else zoo_folder
    zoo = cells(zoo_folder, recipe="zoo") if (zoo_folder / "cells").is_dir() else []
    lines: list[str] = []
    for dataset in EV:
        lines += ev_table(current, dataset) + [""]
        if zoo:
            lines += zoo_table(current, zoo, dataset) + [""] + ensemble_table(zoo, dataset) + [""]
    lines += biotac_table(current) + [""]
    if zoo:
        lines += zoo_table(current, zoo, "biotac_dos") + [""]
    lines += augment8000_table() + ["", READING, ""] + cost_table(current)
    if zoo:
        lines += [""] + cost_table(zoo, f"the `zoo` cells in `{zoo_folder.name}/`")
    # the measured fresh runs of the default recipe, when there are: round 3's (`zoo`, then the default) and round 4's
    for name, evaluation, recipe, target in (("table1-cost", "validation", "zoo", 5.0),
                                             ("table1-cost-r4", "final", "full", 1.5)):
        cost_folder = folder.parent / name
        if (cost_folder / "cells").is_dir():
            lines += [""] + cost_table(cells(cost_folder, evaluation, recipe), f"the fresh run in `{name}/`",
                                       fresh=name, target=target)
    left_out = len(run_records(folder)) - len(current)
    if left_out:
        lines.append(f"\n{left_out} cell file(s) are left out: not ok, another recipe, or computed by an older "
                     f"revision of their model's code (to be rerun).")
    return "\n".join(lines)


PAGE = RESULTS.parents[1] / "docs" / "table1.md"
BEGIN, END = "<!-- table1: begin (python -m tools.paper_table1 --readme) -->", "<!-- table1: end -->"


def render(text: str, folder: Path) -> str:
    """``text`` (docs/table1.md) with the block between the markers replaced by the current tables."""
    from tools.fidelity import replace_block

    return replace_block(text, BEGIN, END, table(folder), PAGE)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.paper_table1", description=__doc__.split("\n")[0])
    p.add_argument("folder", nargs="?", type=Path, default=RESULTS / "paper-table1")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--readme", action="store_true",
                      help="rewrite docs/table1.md's tables and the README's headline block")
    mode.add_argument("--check", action="store_true", help="exit 1 if either block is out of date, or if a headline "
                      "row reads another recipe than its model's registered default")
    args = p.parse_args(argv)
    if not (args.folder / "cells").is_dir():
        print(f"error: {args.folder / 'cells'} not found", file=sys.stderr)
        return 2
    if not (args.readme or args.check):
        print(table(args.folder))
        return 0
    from tools.fidelity import update_page

    command = "python -m tools.paper_table1 --readme"
    headline = render_headline(README.read_text(), args.folder)
    # the generated block and, under --check, the committed one: each row must read its model's registered default
    # recipe, whether the block was edited by hand or generated by code that picks a recipe per row
    texts = dict.fromkeys(block(t) for t in [headline, *([README.read_text()] if args.check else [])])
    wrong = [line for text in texts for line in problems(text, args.folder)]
    for line in dict.fromkeys(wrong):
        print(f"{README}: {line}", file=sys.stderr)
    if wrong and args.readme:
        return 1  # nothing written: a headline that chooses its recipe is not one to commit
    page = update_page(PAGE, render(PAGE.read_text(), args.folder), args.check, command)
    readme = update_page(README, headline, args.check, command)
    return max(page, readme, int(bool(wrong)))


if __name__ == "__main__":
    sys.exit(main())
