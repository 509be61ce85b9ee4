"""The recipe audit: were the zoo recipes chosen on validation only, frozen before the final cells, and was every
final cell's test split read exactly once? A script checks it from committed files and the git history.

    python -m tools.audit                     # tuning trials, the frozen recipes, the final zoo cells
    python -m tools.audit --final DIR --recipe zoo --tuning DIR
    python -m tools.audit --freeze zoo-biotac zoo-ev   # write tuning/freeze.json from the registered recipes
    python -m tools.audit --plan DIR --plan-recipe full  # only the planned round in DIR (PLAN.md)
    python -m tools.audit --plan DIR --plan-recipe zoo --plan-file OTHER/PLAN.md  # a plan kept beside its cells

What it reads:

- **Trials**: every cell record under ``--tuning`` (default ``benchmarks/results/tuning``, searched recursively for
  ``cells/*.json``). A trial is one configuration (one config hash) of a model on a dataset; its cells are its folds
  and seeds. Each must have run under ``--evaluation tuning`` (the test split unreadable, ``test_reads == 0``).
- **The freeze**: ``--tuning``/``freeze.json``, ``{"recipe": "zoo", "models": {model: recipe, ...}}``, committed in
  the commit that froze the recipes. That commit is found in the git history (the last one that changed the file).
- **Final cells**: the ok cells of ``--recipe`` under ``--final`` (default: study ``table1-zoo``'s folder,
  ``benchmarks/results/paper-table1-zoo``).

What it prints: the trials per model and dataset (with the best validation score), the freeze commit and, per
model, what its frozen recipe changes against ``source``, then every final cell's test reads and commit.

What it checks (each failure is one line; the exit status is 1 if there is any):

1. every trial cell ran in tuning mode and read no test split;
2. at most ``--max-trials`` (8) trials per model and dataset, all on seed 0. Every trial under ``--tuning`` counts
   towards the budget; the seed rule binds the zoo's own trial folders, which the freeze lists (``"trial_folders"``).
   A trial elsewhere (an earlier issue's tuning of the ``source`` recipe, with its own rules) off seed 0 is printed
   as a note, not a failure;
3. the registered recipe of every frozen model equals its frozen recipe (nothing changed after the freeze);
4. every final cell: its recipe name is ``--recipe``, its resolved recipe is the frozen one, it read its test split
   exactly once (``test_reads == 1``), and its recorded ``commit`` is clean and is the freeze commit or a descendant
   (``git merge-base --is-ancestor``): it was computed after the recipes were frozen.

**A planned round** (``--plan``, default study ``table1-full-r3``'s folder, ``benchmarks/results/paper-table1-full``,
with recipe ``full``): its ``PLAN.md`` declares the recipe before any cell ran, so the commit that first added
``PLAN.md`` plays the freeze's part. Every ok cell of the round's recipe there must have trained with the registered
recipe as the harness resolves it, under the evaluation the recipe declares, read its test split once, carry a clean
commit that descends from the plan's, and share one CPU type (the processor's name and ``cpu_isa.capability``:
:func:`tactile_zoo.study.audit.cpu_type_clash`, the check a study's audit makes) with every other cell of the round.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

from tactile_zoo import registry
from tactile_zoo.bench.records import (
    InvalidCell,
    InvalidCellsError,
    cell_files,
    read_record,
    recipe_name_of,
    run_records,
)
from tactile_zoo.engine.config import resolve_cell
from tactile_zoo.study.audit import cpu_type, cpu_type_clash
from tactile_zoo.study.publish import study_folder

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
STUDIES = REPO / "benchmarks" / "studies"
#: the tuning trials' folder: every tuning study's folder lies under it, beside the freeze (``freeze.json``), which
#: no one study owns
TUNING = RESULTS / "tuning"


def _git(repo: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=False)


def _records(folder: Path) -> list[dict[str, Any]]:
    return run_records(folder, recursive=True)


def trials(tuning: Path) -> dict[tuple[str, str], dict[str, list[dict[str, Any]]]]:
    """(model, dataset) -> config hash -> the trial's cells; each record gains ``_folder``, its trial folder relative
    to ``tuning`` (``""`` for cells directly under it)."""
    out: dict[tuple[str, str], dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for path in cell_files(tuning, recursive=True):
        rec = read_record(path)
        if isinstance(rec, InvalidCell):
            raise InvalidCellsError([rec], tuning, "the audit reads every trial")
        folder = path.parent.parent.relative_to(tuning).as_posix()
        rec["_folder"] = "" if folder == "." else folder
        out[(rec["model"], rec["dataset"])][rec["config_hash"]].append(rec)
    return out


def freeze_commit(path: Path, repo: Path = REPO) -> str | None:
    """The commit that last changed the freeze file, or ``None`` if it is not committed."""
    rel = path.resolve().relative_to(repo.resolve())
    done = _git(repo, "log", "-1", "--format=%H", "--", str(rel))
    return done.stdout.strip() or None


def recipe_changes(model: str, frozen: dict[str, Any], base: str = "source") -> str:
    """What ``model``'s frozen recipe changes against its registered ``base`` recipe: the training keys, ``hparams``
    and ``dataset_kwargs`` that resolve differently everywhere, then on each dataset either recipe has a section for
    (what that dataset changes beyond the general ones)."""
    from tactile_zoo.recipe import named_recipe_for

    reference = registry.get_model_entry(model).meta.get("recipes", {}).get(base) or {}

    def changes(dataset: str | None) -> dict[str, tuple[Any, Any]]:
        new, old = named_recipe_for(frozen, dataset), named_recipe_for(reference, dataset)
        return {f"{part}{key}": (old[i].get(key), value)
                for i, part in enumerate(("", "hparams.", "dataset_kwargs.")) for key, value in new[i].items()
                if old[i].get(key) != value}

    def said(diff: dict[str, tuple[Any, Any]]) -> str:
        return ", ".join(f"{key} {old!r} -> {new!r}" for key, (old, new) in sorted(diff.items()))

    everywhere = changes(None)
    parts = [f"everywhere: {said(everywhere)}"] if everywhere else []
    for dataset in sorted({*(frozen.get("datasets") or {}), *(reference.get("datasets") or {})}):
        own = {k: v for k, v in changes(dataset).items() if everywhere.get(k) != v}
        if own:
            parts.append(f"{dataset}: {said(own)}")
    return "; ".join(parts) or f"the {base} recipe"


def descends(commit: str, ancestor: str, repo: Path = REPO) -> bool:
    return _git(repo, "merge-base", "--is-ancestor", ancestor, commit).returncode == 0


def audit(tuning: Path, final: Path, recipe: str, max_trials: int = 8, repo: Path = REPO
          ) -> tuple[list[str], list[str]]:
    """``(report lines, failures)``."""
    lines, failures, notes = ["## Trials (validation only)", ""], [], []
    freeze_file = tuning / "freeze.json"
    frozen = json.loads(freeze_file.read_text()) if freeze_file.is_file() else {}
    zoo_folders = frozen.get("trial_folders")  # None: every folder is the zoo's
    for (model, dataset), configs in sorted(trials(tuning).items()):
        best = max(configs.items(), key=lambda kv: sum(r["metrics"]["val"]["accuracy"] for r in kv[1]) / len(kv[1]))
        lines.append(f"- {model} on {dataset}: {len(configs)} trial(s); best validation accuracy "
                     f"{sum(r['metrics']['val']['accuracy'] for r in best[1]) / len(best[1]):.4f} (`{best[0]}`)")
        if len(configs) > max_trials:
            failures.append(f"{model} on {dataset}: {len(configs)} trials, more than the budget of {max_trials}")
        for recs in configs.values():
            for rec in recs:
                where = f"trial {rec['cell_id']}"
                if (rec.get("config") or {}).get("evaluation") != "tuning" or rec.get("test_reads", 0) != 0:
                    failures.append(f"{where}: not a tuning-mode cell (evaluation "
                                    f"{(rec.get('config') or {}).get('evaluation', 'validation')}, test_reads "
                                    f"{rec.get('test_reads')})")
                if rec["seed"] != 0:
                    if zoo_folders is None or rec["_folder"] in zoo_folders:
                        failures.append(f"{where}: seed {rec['seed']}; trials tune on seed 0 only")
                    else:
                        notes.append(f"{where} (in {rec['_folder']}/, not a zoo trial folder): seed {rec['seed']}")
    if notes:
        lines += ["", "Notes (trials of earlier issues, outside the zoo's trial folders, counted in the budget):", ""]
        lines += [f"- {n}" for n in notes]
    lines += ["", "## The freeze", ""]
    if not freeze_file.is_file():
        failures.append(f"{freeze_file}: missing; the recipes were never frozen")
        return lines, failures
    commit = freeze_commit(freeze_file, repo)
    lines.append(f"`{frozen.get('recipe')}` recipes frozen in commit {commit or '(not committed)'} for "
                 f"{', '.join(sorted(frozen.get('models', {})))}; zoo trial folders: "
                 f"{', '.join(zoo_folders) if zoo_folders is not None else 'all'}")
    if commit is None:
        failures.append(f"{freeze_file}: not committed; a freeze is a commit")
    if frozen.get("recipe") != recipe:
        failures.append(f"{freeze_file}: freezes recipe {frozen.get('recipe')!r}, the audit checks {recipe!r}")
    # the simulators' sections (sized for a first run, added later) are no part of the freeze: real data never reads
    # them (tests/models/test_simulator_sizing.py)
    simulated = {d for d in registry.list_datasets() if registry.get_dataset_entry(d).meta.get("simulated")}
    for model, frozen_recipe in sorted(frozen.get("models", {}).items()):
        registered = json.loads(json.dumps(registry.get_model_entry(model).meta.get("recipes", {}).get(recipe)))
        if isinstance(registered, dict) and isinstance(registered.get("datasets"), dict):
            registered["datasets"] = {d: s for d, s in registered["datasets"].items() if d not in simulated}
        if registered != frozen_recipe:  # as JSON: a tuple and a list are one recipe
            failures.append(f"{model}: the registered {recipe!r} recipe differs from the frozen one")
        lines.append(f"- {model} against `source`: {recipe_changes(model, frozen_recipe)}")
    lines += ["", f"## Final `{recipe}` cells", "", "| cell | test reads | commit | after the freeze |",
              "|---|---|---|---|"]
    for rec in _records(final):
        if rec.get("status") != "ok" or recipe_name_of(rec.get("config") or {}) != recipe:
            continue
        cell_commit = str(rec.get("commit") or "")
        after = bool(commit) and bool(cell_commit) and not cell_commit.endswith("+dirty") \
            and descends(cell_commit, commit, repo)
        lines.append(f"| {rec['cell_id']} | {rec.get('test_reads')} | {cell_commit[:12] or '-'} | "
                     f"{'yes' if after else 'NO'} |")
        if rec.get("test_reads") != 1:
            failures.append(f"{rec['cell_id']}: test split read {rec.get('test_reads')} time(s), not once")
        if not after:
            failures.append(f"{rec['cell_id']}: commit {cell_commit or 'unrecorded'} is not a clean descendant of "
                            f"the freeze commit {commit}")
        if rec["model"] not in frozen.get("models", {}):
            failures.append(f"{rec['cell_id']}: model {rec['model']} has no frozen recipe")
            continue
        cfg = rec["config"]
        # the frozen recipe resolved as the harness resolves it (the dataset's epoch budget included): a final cell
        # must have trained with exactly that, no --set override on top
        want = resolve_cell(rec["model"], rec["dataset"], recipe_name=recipe, hparams=cfg.get("hparams"),
                            dataset_kwargs=cfg.get("dataset_kwargs")).recipe.to_dict()
        if cfg["recipe"] != want:
            failures.append(f"{rec['cell_id']}: trained with another recipe than the frozen one")
    return lines, failures


def plan_commit(plan: Path, repo: Path = REPO) -> str | None:
    """The commit that first added ``plan``: later commits only append outcomes to it."""
    out = _git(repo, "log", "--diff-filter=A", "--format=%H", "--", str(plan.resolve())).stdout.split()
    return out[-1] if out else None


def audit_plan(folder: Path, recipe: str, repo: Path = REPO, plan: Path | None = None) -> tuple[list[str], list[str]]:
    """``(report lines, failures)`` of a planned round: ``folder/PLAN.md`` (or ``plan``, a round's cells kept apart
    from its plan, as DeepTactile's of round 4) committed before every cell of ``recipe`` in ``folder``, each cell
    trained as planned, its test split read once, all on one CPU type."""
    plan = plan or folder / "PLAN.md"
    lines, failures = [f"## Planned `{recipe}` cells ({folder.name})", ""], []
    commit = plan_commit(plan, repo) if plan.is_file() else None
    if commit is None:
        failures.append(f"{plan}: {'not committed' if plan.is_file() else 'missing'}; a plan is declared by a commit")
        return lines, failures
    records = [r for r in _records(folder) if r.get("status") == "ok"
               and recipe_name_of(r.get("config") or {}) == recipe]
    lines.append(f"Plan committed in {commit[:12]}; {len(records)} cell(s) so far.")
    for rec in records:
        cfg, cell_commit = rec["config"], str(rec.get("commit") or "")
        where = rec["cell_id"]
        planned = resolve_cell(rec["model"], rec["dataset"], recipe_name=recipe, hparams=cfg.get("hparams"),
                               dataset_kwargs=cfg.get("dataset_kwargs"))
        if cfg["recipe"] != planned.recipe.to_dict():
            failures.append(f"{where}: trained with another recipe than the planned {recipe!r}")
        if cfg.get("evaluation", "validation") != planned.evaluation:
            failures.append(f"{where}: evaluation {cfg.get('evaluation', 'validation')}, the recipe declares "
                            f"{planned.evaluation}")
        if rec.get("test_reads") != 1:
            failures.append(f"{where}: test split read {rec.get('test_reads')} time(s), not once")
        if not cell_commit or cell_commit.endswith("+dirty") or not descends(cell_commit, commit, repo):
            failures.append(f"{where}: commit {cell_commit or 'unrecorded'} is not a clean descendant of the plan "
                            f"commit {commit[:12]}")
    cpus = Counter(cpu_type(rec) for rec in records)
    lines += [f"- {n} cell(s) on {cpu}" for cpu, n in sorted(cpus.items())]
    if clash := cpu_type_clash(records):
        failures.append(f"{folder.name}: cells on {clash}; a round runs on one")
    return lines, failures


def write_freeze(tuning: Path, recipe: str, trial_folders: list[str]) -> Path:
    """Write ``tuning/freeze.json``: every built-in model's registered ``recipe`` as it stands, and the zoo's trial
    folders. Committing the file is the freeze."""
    missing = [f for f in trial_folders if not (tuning / f).is_dir()]
    if missing:
        raise SystemExit(f"--freeze: no trial folder {', '.join(missing)} under {tuning}")
    recipes = {name: registry.get_model_entry(name).meta.get("recipes") or {} for name in registry.model_names()}
    models = {name: entry[recipe] for name, entry in recipes.items() if recipe in entry}
    path = tuning / "freeze.json"
    path.write_text(json.dumps({"recipe": recipe, "trial_folders": sorted(trial_folders), "models": models},
                               indent=1, sort_keys=True) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.audit", description=__doc__.split("\n")[0])
    p.add_argument("--tuning", type=Path, default=TUNING)
    p.add_argument("--final", type=Path, default=study_folder(STUDIES, "table1-zoo"))
    p.add_argument("--recipe", default="zoo")
    p.add_argument("--max-trials", type=int, default=8)
    p.add_argument("--plan", type=Path, default=study_folder(STUDIES, "table1-full-r3"),
                   help="a planned round's folder (its PLAN.md declares the recipe before any cell)")
    p.add_argument("--plan-recipe", default="full")
    p.add_argument("--plan-file", type=Path, default=None,
                   help="the plan when it lives outside --plan's folder (default: --plan/PLAN.md)")
    p.add_argument("--freeze", nargs="+", metavar="FOLDER", default=None,
                   help="write --tuning/freeze.json from the registered --recipe recipes, naming the zoo's trial "
                        "folders (relative to --tuning), and stop; commit the file to freeze")
    args = p.parse_args(argv)
    if args.freeze is not None:
        print(f"wrote {write_freeze(args.tuning, args.recipe, args.freeze)}; commit it to freeze the recipes")
        return 0
    lines, failures = audit(args.tuning, args.final, args.recipe, args.max_trials)
    plan_lines, plan_failures = audit_plan(args.plan, args.plan_recipe, plan=args.plan_file)
    lines, failures = [*lines, "", *plan_lines], [*failures, *plan_failures]
    print("\n".join(lines))
    print("\n## Verdict\n")
    print("\n".join(f"- FAIL {f}" for f in failures) if failures else "every check holds")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
