"""The fidelity ledger's tables (``docs/fidelity.md``), regenerated from committed results only.

    python -m tools.fidelity            # rewrite the tables between the ledger's markers
    python -m tools.fidelity --check    # exit 1 if docs/fidelity.md is not what the results give

Sources read (nothing is trained here):

- ``benchmarks/results/paper-table1/cells``: the zoo's honest protocol (epoch selected on validation, test read
  once), ``source`` recipe;
- ``benchmarks/results/reference-protocol/cells``: SGnet under TactileSGNet's own protocol (``--evaluation
  reference``: final epoch, and the best test epoch the source publishes);
- ``benchmarks/results/convlstm-biotac/e2-source/cells``: ConvLSTM on BioTac-DoS, its source's data, source setup;
- ``benchmarks/results/dcnn_released.csv``: the ten released D-CNN models on the 120 Augment8000 real-life samples.

A cell computed by an older revision of its model's or dataset's code is left out (``report.md`` flags it), as is a
cell of another recipe than ``source``. Intervals are 95 % confidence intervals of the expected accuracy, the test
units (samples, or recordings for BioTac-DoS) drawn once per resample for all seeds
(:func:`tactile_zoo.bench.intervals.records_interval`).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from tactile_zoo._files import replace_block, update_pages
from tactile_zoo.bench.intervals import records_interval
from tactile_zoo.bench.records import qualifying_cells
from tactile_zoo.study.publish import study_files, study_folder
from tactile_zoo.study.publish_tables import paper_figures
from tactile_zoo.study.schema import parse_study
from tools.model_pages import display, zoo_models

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
LEDGER = REPO / "docs" / "fidelity.md"
BEGIN, END = "<!-- ledger tables: begin (python -m tools.fidelity) -->", "<!-- ledger tables: end -->"
EV = ("ev_objects", "ev_containers")
STUDIES = REPO / "benchmarks" / "studies"
#: TactileSGNet (Gu et al., IROS 2020): mean over runs of each run's best test epoch.
SGNET_SOURCE = {"ev_objects": 0.8944, "ev_containers": 0.6417}
SGNET_TARGET = {"ev_objects": 0.02, "ev_containers": 0.03}
CONVLSTM_SOURCE = 0.8256  # Zapata-Impata, Gil and Torres, Sensors 2019: unseen objects with familiar properties
DCNN_SOURCE = (871, 1200)  # 0.7258: the mean of the ten released models, the X-Tacformer paper's D-CNN figure


def xtac_paper() -> dict[tuple[str, str], float]:
    """Table I of the X-Tacformer paper, (model, dataset) -> test accuracy, as the studies hold it once
    (``compares_with`` in ``benchmarks/studies/table1-source.yaml``)."""
    return paper_figures(parse_study(path) for path in study_files(STUDIES))


def cells(folder: Path, evaluation: str = "validation", recipe: str = "source") -> list[dict[str, Any]]:
    """The ok, current cells of ``folder`` that trained with the named ``recipe`` under ``evaluation``
    (:func:`tactile_zoo.bench.records.qualifying_cells`)."""
    return qualifying_cells(folder, recipe=recipe, evaluation=evaluation)


def _pick(records: Iterable[dict[str, Any]], model: str, dataset: str) -> list[dict[str, Any]]:
    return sorted((r for r in records if r["model"] == model and r["dataset"] == dataset), key=lambda r: r["seed"])


def figure(records: list[dict[str, Any]], split: str = "test", key: str | None = None) -> str:
    """``mean +- std [95 % interval] (n seeds)`` of the test accuracy (or of ``reference[key]``, without interval)."""
    if not records:
        return "not run yet"
    if key is not None:
        values = [r["reference"][key] for r in records]
        interval = ""
    else:
        values = [r["metrics"][split]["accuracy"] for r in records]
        low_high = records_interval(records, split)
        interval = f" [{low_high[0]:.3f}, {low_high[1]:.3f}]" if low_high else ""
    std = f" ± {statistics.stdev(values):.3f}" if len(values) > 1 else ""
    return f"{statistics.fmean(values):.3f}{std}{interval} ({len(values)} seed{'s' if len(values) > 1 else ''})"


def _dcnn_released() -> tuple[int, int] | None:
    path = RESULTS / "dcnn_released.csv"
    if not path.is_file():
        return None
    total = [r for r in csv.DictReader(path.open()) if r["case"] == "total"]
    return (int(total[0]["correct"]), int(total[0]["n"])) if total else None


def tables() -> str:
    honest = cells(study_folder(STUDIES, "table1-source"))
    reference = cells(study_folder(STUDIES, "table1-reference", "sgnet"), "reference")
    biotac = cells(RESULTS / "convlstm-biotac" / "e2-source")  # the source setup (EXPERIMENTS.md, E2)
    lines = ["### The sources' own protocols", "",
             "| model | source's figure (its protocol) | ours, same protocol | target | met |", "|---|---|---|---|---|"]
    for dataset in EV:
        recs = _pick(reference, "sgnet", dataset)
        best = [r["reference"]["best_test_epoch_accuracy"] for r in recs]
        met = "-" if len(best) < 3 else ("yes" if abs(statistics.fmean(best) - SGNET_SOURCE[dataset])
                                         <= SGNET_TARGET[dataset] else "no")
        lines.append(f"| SGnet, {dataset} | {SGNET_SOURCE[dataset]:.4f} (mean best test epoch; batch 1, 100 epochs, "
                     f"all training recordings) | best test epoch {figure(recs, key='best_test_epoch_accuracy')}; "
                     f"final epoch, honest: {figure(recs)} | within {SGNET_TARGET[dataset]} | {met} |")
    released = _dcnn_released()
    if released is not None:
        correct, n = released
        lines.append(f"| D-CNN, Augment8000 real-life | {DCNN_SOURCE[0]}/{DCNN_SOURCE[1]} = "
                     f"{DCNN_SOURCE[0] / DCNN_SOURCE[1]:.4f} (ten released models, 120 samples each) | {correct}/{n} = "
                     f"{correct / n:.4f} (released weights, evaluation only) | ±5 of 871 | "
                     f"{'yes' if abs(correct - DCNN_SOURCE[0]) <= 5 else 'no'} |")
    sets = ("test_solids", "test_small", "test_textures")
    recs = _pick(biotac, "convlstm", "biotac_dos")
    per_set = "; ".join(f"{s[5:]} {figure(recs, s)}" for s in sets) if recs else "not run yet"
    solids = [r["metrics"]["test_solids"]["accuracy"] for r in recs]
    met = "-" if len(solids) < 3 else ("yes" if abs(statistics.fmean(solids) - CONVLSTM_SOURCE) <= 0.05 else "no")
    lines.append(f"| ConvLSTM, BioTac-DoS unseen objects | {CONVLSTM_SOURCE:.4f} (unseen objects with familiar "
                 f"properties: compared on solids) | {per_set} | within 0.05 on solids | {met} |")
    lines += ["", "### The zoo's honest protocol (epoch selected on validation, test read once)", "",
              "| model | X-Tacformer paper, Ev-Objects | ours, Ev-Objects | X-Tacformer paper, Ev-Containers | "
              "ours, Ev-Containers |", "|---|---|---|---|---|"]
    paper = xtac_paper()
    for model in zoo_models():  # every built-in model, from the registry (tools.model_pages)
        row = [display(model)]
        for dataset in EV:
            value = paper.get((model, dataset))
            row += ["-" if value is None else f"{value:.4f}", figure(_pick(honest, model, dataset))]
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", "Figures: mean ± sample std over seeds [95 % confidence interval of the expected accuracy: one "
                  "draw of the test samples per resample shared by the seeds, plus the seeds' spread with its t "
                  "quantile] (seeds). \"not run yet\": no current cell (a cell of an older code revision does not "
                  "count). BioTac-DoS intervals resample recordings (about 27 windows each), not windows."]
    return "\n".join(lines)


def render(text: str) -> str:
    return replace_block(text, BEGIN, END, tables(), LEDGER, error=SystemExit)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.fidelity", description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/fidelity.md is out of date")
    args = parser.parse_args(argv)
    return update_pages({LEDGER: render(LEDGER.read_text(encoding="utf-8"))}, args.check, "python -m tools.fidelity")


if __name__ == "__main__":
    sys.exit(main())
