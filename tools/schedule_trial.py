"""The schedule trial's outcome (``benchmarks/results/tuning/full-schedule/PLAN.md``), from its cell files.

The trial trains each model on each Ev dataset for ``full``'s declared N epochs in tuning mode (validation only), once
with the schedule as ``full`` registers it and once with the schedule scaled to N, seeds 0-2. ``full`` reads its last
epoch, so the rule compares the **validation accuracy at epoch N**, averaged over the seeds: the scaled schedule is
adopted for a model only if that mean rises by at least two validation recordings on both datasets.

Every cell is checked against its arm before a number is computed (its recorded schedule, epoch count, patience,
evaluation mode, test reads and CPU type), so a cell that trained something else stops the tool instead of entering
the comparison::

    python -m tools.schedule_trial            # the table and the verdicts, as appended to the plan
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tactile_zoo.bench.records import run_records
from tactile_zoo.errors import ResultsError

from .table1_common import cpu_types

FOLDER = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "tuning" / "full-schedule"
SEEDS = (0, 1, 2)
#: full's declared epoch counts (the registered recipes), Ev-Objects then Ev-Containers
EPOCHS = {"sgnet": {"ev_objects": 40, "ev_containers": 56},
          "tacformer": {"ev_objects": 15, "ev_containers": 25},
          "x_tacformer": {"ev_objects": 16, "ev_containers": 25}}
#: two validation recordings: 108 on Ev-Objects, 40 on Ev-Containers (the plan's thresholds)
THRESHOLD = {"ev_objects": 0.019, "ev_containers": 0.05}


class TrialError(ValueError):
    """A cell that does not belong to either arm, or an arm that is incomplete."""


def registered_schedule(model: str) -> dict[str, Any]:
    """The schedule ``full`` trains with: SGnet's source milestones, the transformers' cosine pinned to 30 epochs."""
    if model == "sgnet":
        return {"type": "multistep", "milestones": [41, 81], "gamma": 0.1}
    return {"type": "cosine", "eta_min": 0.0, "t_max": 30}


def scaled_schedule(model: str, epochs: int) -> dict[str, Any]:
    """The plan's scaled schedule: SGnet's drops at round(0.41 N) and round(0.81 N), the transformers' cosine over N."""
    if model == "sgnet":
        return {"type": "multistep", "milestones": [round(0.41 * epochs), round(0.81 * epochs)], "gamma": 0.1}
    return {"type": "cosine", "eta_min": 0.0, "t_max": epochs}


def _same_schedule(recorded: Mapping[str, Any], wanted: Mapping[str, Any]) -> bool:
    return all(recorded.get(key) == value for key, value in wanted.items())


@dataclass(frozen=True)
class Arm:
    """The seeds' validation accuracies at epoch N of one model x dataset x arm."""

    model: str
    dataset: str
    arm: str
    epochs: int
    accuracies: tuple[float, ...]
    cpu_hours: float

    @property
    def mean(self) -> float:
        return statistics.fmean(self.accuracies)


def _arm_of(record: Mapping[str, Any], where: str) -> str:
    config = record["config"]
    recipe = config["recipe"]
    model, dataset = record["model"], record["dataset"]
    epochs = EPOCHS[model][dataset]
    if record.get("status") != "ok":
        raise TrialError(f"{where}: status {record.get('status')!r}, not ok")
    if config.get("evaluation") != "tuning" or record.get("test_reads", 0) != 0:
        raise TrialError(f"{where}: not a tuning cell (evaluation {config.get('evaluation')!r}, "
                         f"{record.get('test_reads')} test reads)")
    if recipe.get("max_epochs") != epochs or recipe.get("patience") is not None:
        raise TrialError(f"{where}: max_epochs {recipe.get('max_epochs')}, patience {recipe.get('patience')}; the "
                         f"plan trains {epochs} epochs without early stopping")
    if len(record.get("curve") or []) != epochs:
        raise TrialError(f"{where}: {len(record.get('curve') or [])} epochs in its curve, not {epochs}")
    schedule = recipe.get("schedule") or {}
    for arm, wanted in (("registered", registered_schedule(model)), ("scaled", scaled_schedule(model, epochs))):
        if _same_schedule(schedule, wanted):
            return arm
    raise TrialError(f"{where}: schedule {schedule} is neither arm's")


def read_arms(folder: Path = FOLDER) -> list[Arm]:
    """Every arm of the trial, each checked complete (seeds 0-2) and on one CPU type."""
    found: dict[tuple[str, str, str], dict[int, dict[str, Any]]] = {}
    records = run_records(folder)  # a damaged cell file raises, naming it, before any arm loses a seed
    for record in records:
        name = f"{record['cell_id']}.json"
        key = (record["model"], record["dataset"], _arm_of(record, name))
        if record["seed"] in found.setdefault(key, {}):
            raise TrialError(f"{name}: a second cell for {key} seed {record['seed']}")
        found[key][record["seed"]] = record
    types = cpu_types(records)
    if len(types) > 1:
        raise TrialError(f"cells from {len(types)} CPU types ({', '.join(sorted(types))}); the plan runs one")
    arms = []
    for model, per_dataset in EPOCHS.items():
        for dataset, epochs in per_dataset.items():
            for arm in ("registered", "scaled"):
                cells = found.get((model, dataset, arm), {})
                missing = sorted(set(SEEDS) - set(cells))
                if missing:
                    raise TrialError(f"{model} x {dataset}, {arm}: seeds {missing} missing")
                accuracies = tuple(float(cells[s]["curve"][epochs - 1]["val_accuracy"]) for s in SEEDS)
                hours = sum(float(cells[s].get("train_seconds") or 0.0) for s in SEEDS) / 3600
                arms.append(Arm(model, dataset, arm, epochs, accuracies, hours))
    return arms


def verdicts(arms: Sequence[Arm]) -> dict[str, tuple[bool, dict[str, float]]]:
    """Per model: adopted?, and the scaled arm's gain over the registered one on each dataset."""
    by_key = {(a.model, a.dataset, a.arm): a for a in arms}
    out = {}
    for model, per_dataset in EPOCHS.items():
        gains = {d: by_key[model, d, "scaled"].mean - by_key[model, d, "registered"].mean for d in per_dataset}
        out[model] = (all(gains[d] >= THRESHOLD[d] - 1e-12 for d in gains), gains)
    return out


def render(arms: Sequence[Arm]) -> str:
    lines = ["| model | dataset | N | registered (seeds 0-2) | scaled (seeds 0-2) | gain | threshold |",
             "|---|---|---|---|---|---|---|"]
    by_key = {(a.model, a.dataset, a.arm): a for a in arms}
    for model, per_dataset in EPOCHS.items():
        for dataset, epochs in per_dataset.items():
            reg, sca = by_key[model, dataset, "registered"], by_key[model, dataset, "scaled"]
            fmt = lambda a: f"{a.mean:.4f} ({', '.join(f'{x:.3f}' for x in a.accuracies)})"  # noqa: E731
            lines.append(f"| {model} | {dataset} | {epochs} | {fmt(reg)} | {fmt(sca)} | {sca.mean - reg.mean:+.4f} "
                         f"| +{THRESHOLD[dataset]} |")
    lines.append("")
    for model, (adopted, _) in verdicts(arms).items():
        lines.append(f"- {model}: {'adopted for the next round' if adopted else 'not adopted'}")
    lines.append(f"- CPU-hours (training, 36 cells): {sum(a.cpu_hours for a in arms):.2f}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.schedule_trial", description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=FOLDER, help="the trial's run folder")
    args = parser.parse_args(argv)
    try:
        print(render(read_arms(args.folder)))
    except (TrialError, ResultsError) as exc:
        parser.exit(2, f"tools.schedule_trial: error: {exc}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
