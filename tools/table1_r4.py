"""Table I, round 4 (``benchmarks/results/paper-table1-full-r4/PLAN.md``): seeds 5-9 of the registered ``full``
recipes beside round 3's seeds 0-4, the ten seeds pooled, the ensembles the plan declared (each read once), and what
the round cost against its budget.

    python -m tools.table1_r4             # print the block
    python -m tools.table1_r4 --readme    # rewrite docs/table1.md's round-4 block
    python -m tools.table1_r4 --check     # exit 1 if the block is not what the cells give

Nothing is trained here. The ensembles average stored test probabilities; a folder without cells reads as "not run
yet". Seeds 0-4 are never part of a round-4 ensemble: their test split had already been read when the plan declared
them. Pooling needs one CPU type across both rounds (the plan's rule): cells of two types stop the tool.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

from tools.fidelity import cells, replace_block, update_page
from tools.paper_table1 import ZOO_SPLITS, seed_ensemble
from tools.table1_common import MODELS, NAMES, PAPER, RESULTS, _figure, _group, cpu_types, paper_column
from tools.table1_full import DATASETS, TITLES

R3, R4 = RESULTS / "paper-table1-full", RESULTS / "paper-table1-full-r4"
R3_SEEDS, R4_SEEDS = (0, 1, 2, 3, 4), (5, 6, 7, 8, 9)
CROSS_SEED = 5  #: the seed of every member of the declared cross-model ensemble ``all6_full_seed5``
BUDGET = 16.0  #: CPU-hours, declared in the plan
#: the plan's ambitions: a declared ensemble at or above these (Ev-Objects, Ev-Containers), X-Tacformer's honest mean
TARGETS = {"ev_objects": 0.93, "ev_containers": 0.80}
PAGE = RESULTS.parents[1] / "docs" / "table1.md"
BEGIN, END = "<!-- table1 round 4: begin (python -m tools.table1_r4 --readme) -->", "<!-- table1 round 4: end -->"


def load(r3: Path = R3, r4: Path = R4) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The ok, current ``full`` cells (``--evaluation final``) of each round; a folder without cells is empty."""
    def read(folder: Path) -> list[dict[str, Any]]:
        return cells(folder, "final", "full") if (folder / "cells").is_dir() else []

    return read(r3), read(r4)


def one_cpu(records: list[dict[str, Any]]) -> str:
    """The one CPU type (name and instruction-set capability) of ``records``; two types are an error, since the plan
    pools seeds only within one type."""
    types = cpu_types(records)
    if len(types) > 1:
        raise SystemExit(f"cells of {len(types)} CPU types ({'; '.join(types)}): the plan pools one type only; move "
                         f"the other type's cells to a sibling folder")
    return types[0] if types else "no cells yet"


def _seeds(recs: list[dict[str, Any]], seeds: tuple[int, ...]) -> list[dict[str, Any]]:
    return [r for r in recs if r["seed"] in seeds and r["fold"] == 0]


def _ensemble(recs: list[dict[str, Any]], split: str, members: int) -> tuple[str, float | None]:
    """The ensemble figure ``accuracy [interval]`` of ``recs`` and its accuracy, or why there is none yet."""
    if len(recs) < members:
        return f"{len(recs)} of {members} members so far", None
    found = seed_ensemble(recs, split)
    if found is None:
        return f"no stored probabilities for `{split}`", None
    accuracy, low, high = found
    return f"{accuracy:.4f} [{low:.3f}, {high:.3f}]", accuracy


def seeds_table(r3: list[dict[str, Any]], r4: list[dict[str, Any]], dataset: str) -> tuple[list[str], dict]:
    """Per model on ``dataset``: the paper, seeds 0-4, seeds 5-9, the ten pooled and ``<model>_full_r4_ens5``; with
    the ensembles' accuracies (model -> accuracy) for the targets' sentence."""
    split = ZOO_SPLITS[dataset]
    lines = [f"**Seeds 5-9 of `full` on {TITLES[dataset]}** (accuracy on `{split}`: mean ± std [95 % interval] (runs); "
             "the interval resamples the seeds, then one test draw shared by every run; the ensemble is one run, its "
             "interval resamples the test units)", "",
             "| model | paper | seeds 0-4 (round 3) | seeds 5-9 (round 4) | seeds 0-9 pooled | "
             "`<model>_full_r4_ens5` [95 %] |", "|---|---|---|---|---|---|"]
    ensembles = {}
    for model in MODELS:
        paper = PAPER[model][paper_column(dataset)]
        old = _seeds(_group(r3, model, dataset), R3_SEEDS)
        new = _seeds(_group(r4, model, dataset), R4_SEEDS)
        if old and new and old[0]["config_hash"] != new[0]["config_hash"]:
            raise SystemExit(f"{model} on {dataset}: round 4's configuration {new[0]['config_hash']} is not round 3's "
                             f"{old[0]['config_hash']}; the plan pools one configuration only")
        text, ensembles[model] = _ensemble(new, split, len(R4_SEEDS))
        pooled = _figure(old + new, split, std=True) if len(new) == len(R4_SEEDS) else "when seeds 5-9 are in"
        figures = [_figure(old, split, std=True), _figure(new, split, std=True), pooled, text]
        lines.append(f"| {NAMES[model]} | {'-' if paper is None else f'{paper:.4f}'} | " + " | ".join(figures) + " |")
    return lines, ensembles


def cross_model(r4: list[dict[str, Any]]) -> tuple[list[str], dict]:
    """``all6_full_seed5`` per dataset: the six models' seed-5 cells, their test probabilities averaged with equal
    weights; with its accuracy per dataset."""
    lines = [f"**The cross-model ensemble `all6_full_seed5`** (the six models' `full` seed-{CROSS_SEED} cells, equal "
             "weights; one run, the interval resamples the test units)", "",
             "| dataset | best member | members' mean | `all6_full_seed5` [95 %] |", "|---|---|---|---|"]
    found = {}
    for dataset in DATASETS:
        split = ZOO_SPLITS[dataset]
        members = [r for model in MODELS for r in _seeds(_group(r4, model, dataset), (CROSS_SEED,))]
        text, found[dataset] = _ensemble(members, split, len(MODELS))
        scores = {NAMES[r["model"]]: r["metrics"][split]["accuracy"] for r in members}
        best = max(scores, key=scores.__getitem__) if scores else None
        best_text = "-" if best is None else f"{best} {scores[best]:.4f}"
        mean = f"{statistics.fmean(scores.values()):.4f}" if scores else "-"
        lines.append(f"| {TITLES[dataset]} | {best_text} | {mean} | {text} |")
    return lines, found


def targets(ensembles: dict[str, dict], cross: dict, r3: list[dict[str, Any]], r4: list[dict[str, Any]]) -> str:
    """Where the plan's ambitions stand: the best declared ensemble per Ev dataset, X-Tacformer's pooled mean."""
    said = []
    for dataset, target in TARGETS.items():
        scores = {f"`{m}_full_r4_ens5`": a for m, a in ensembles[dataset].items() if a is not None}
        if cross.get(dataset) is not None:
            scores["`all6_full_seed5`"] = cross[dataset]
        if not scores:
            said.append(f"on {TITLES[dataset]} no declared ensemble is in yet (target {target:.2f})")
            continue
        name = max(scores, key=scores.__getitem__)
        verdict = "met" if scores[name] >= target else "missed"
        said.append(f"on {TITLES[dataset]} the best declared ensemble is {name} at {scores[name]:.4f} (target "
                    f"{target:.2f}: {verdict})")
    xt = _seeds(_group(r3, "x_tacformer", "ev_objects"), R3_SEEDS) + _seeds(_group(r4, "x_tacformer", "ev_objects"),
                                                                             R4_SEEDS)
    paper = PAPER["x_tacformer"][0]
    if xt:
        mean = statistics.fmean(r["metrics"]["test"]["accuracy"] for r in xt)
        said.append(f"X-Tacformer's honest `full` mean on Ev-Objects over {len(xt)} seeds is {mean:.4f} (target "
                    f"{paper:.4f}: {'met' if mean >= paper else 'missed'})")
    return "The plan's ambitions: " + "; ".join(said) + "."


def cost(r4: list[dict[str, Any]]) -> str:
    """The round's seeds 5-9 in CPU-hours: the cells' own ``seconds`` (one torch thread each), against the budget."""
    per = {TITLES[d]: sum(r.get("seconds", r["train_seconds"]) for r in r4 if r["dataset"] == d) / 3600
           for d in DATASETS}
    hours = sum(per.values())
    return (f"Seeds 5-9 cost {hours:.2f} CPU-hours for {len(r4)} of the {len(MODELS) * len(DATASETS) * 5} planned runs "
            f"({', '.join(f'{t} {h:.2f}' for t, h in per.items())}; the cells' own times, one torch thread each, two "
            f"at a time), of the round's budget of {BUDGET:g}. CPU: {one_cpu(r4)}.")


def table(r3: list[dict[str, Any]], r4: list[dict[str, Any]]) -> str:
    """docs/table1.md's round-4 block."""
    one_cpu(r3 + r4)
    lines: list[str] = []
    ensembles = {}
    for dataset in DATASETS:
        rows, ensembles[dataset] = seeds_table(r3, r4, dataset)
        lines += rows + [""]
    rows, cross = cross_model(r4)
    lines += rows + ["", targets(ensembles, cross, r3, r4), "", cost(r4)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.table1_r4", description=__doc__.split("\n")[0])
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--readme", action="store_true", help="rewrite docs/table1.md's round-4 block")
    mode.add_argument("--check", action="store_true", help="exit 1 if the block is out of date")
    args = p.parse_args(argv)
    body = table(*load())
    if not (args.readme or args.check):
        print(body)
        return 0
    new = replace_block(PAGE.read_text(), BEGIN, END, body, PAGE)
    return update_page(PAGE, new, args.check, "python -m tools.table1_r4 --readme")


if __name__ == "__main__":
    sys.exit(main())
