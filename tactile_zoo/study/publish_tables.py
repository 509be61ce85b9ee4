"""The published tables' shared parts, and Table I's first block (``docs/table1.md``, block ``table1``).

:class:`Context` holds the studies a generated page reads (every study file of a folder) and answers what each table
needs: which studies feed a block in which part (their ``publishes`` entries), each part's cells (the ``ok`` cells of
the current model revisions, under the grid's recipe and evaluation: :func:`tactile_zoo.bench.records.
qualifying_cells`), the external figures (the paper's Table I, held once, in one study's ``compares_with``) and the
declared reads (recorded once, :mod:`.reads`). Nothing here trains or records anything.

Figures are the mean ± sample std over runs (seeds, or folds where a dataset's validation rotates) with the 95 %
interval of the expected accuracy (:func:`tactile_zoo.bench.intervals.records_interval`: one draw of the test units
per resample shared by the runs, plus the runs' spread).
"""

from __future__ import annotations

import csv
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import registry
from ..bench.intervals import records_interval
from ..bench.paired import holm, records_paired
from ..bench.records import recipe_name_of, revision_gaps, run_records
from ..errors import ResultsError
from .audit import cpu_type_clash, cpu_types, study_records
from .checks import plans
from .reads import compute_reads
from .schema import GridSpec, Publication, Study

__all__ = ["Context", "TITLES", "SPLITS", "figure", "group", "where", "mean_std", "one_cpu_type", "cost_table",
           "table1_block", "paper_figures"]

#: each Table I dataset's title and the split its comparisons read (BioTac-DoS: textures, the paper's column)
TITLES = {"ev_objects": "Ev-Objects", "ev_containers": "Ev-Containers", "biotac_dos": "BioTac-DoS (textures)"}
SPLITS = {"ev_objects": "test", "ev_containers": "test", "biotac_dos": "test_textures"}
EV = {"ev_objects": "144 test recordings, 36 classes", "ev_containers": "60 test recordings, 20 classes"}
BIOTAC_SETS = ("test_textures", "test_solids", "test_small")
PAPER_TABLE = "xtacformer-table1"  # the ``compares_with`` name of the paper's Table I
READING = ("Figures: mean ± sample std over runs. The 95 % interval is a confidence interval for the expected "
           "accuracy of this training procedure on this task (over training seeds, on the population the test set "
           "was drawn from): one draw of the test units (samples; recordings on BioTac-DoS) per resample, shared by "
           "all runs, since they share the test set, plus the runs' spread with its small-sample t quantile. In "
           "simulated experiments like these it covered the truth 93-96 % of the time "
           "(`benchmarks/results/interval_coverage.md`). A paper figure above the interval is one these runs do not "
           "reproduce, and two models whose intervals overlap widely are not told apart.")


def registered_revision(model: str) -> int:
    """The revision ``create_model(model)`` builds: the one a published row of ``model`` reads."""
    return registry.revision_of(registry.get_model_entry(model))


def one_cpu_type(records: Sequence[dict[str, Any]], what: str) -> str:
    """The one CPU type of ``records`` (pooled seeds must share it: the same seed can train differently on
    another); two types are a :class:`ResultsError` naming them."""
    if clash := cpu_type_clash(records):
        raise ResultsError(f"{what}: cells of {clash}; seeds pool within one CPU type only")
    types = cpu_types(list(records))
    return types[0] if types else "no cells yet"


@dataclass
class Context:
    """The studies of one folder, as the published tables read them."""

    studies: dict[str, Study]
    repo: Path
    _cells: dict[tuple[str, str | None], list[dict[str, Any]]] = field(default_factory=dict)
    _reads: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    _folders: dict[Path, list[dict[str, Any]]] = field(default_factory=dict)
    rendered: dict[tuple[str, str], str] = field(default_factory=dict)  # (page, block) -> its body

    def parts(self, page: str, block: str, table: str | None = None) -> list[tuple[Study, Publication]]:
        """The (study, publication) pairs that feed ``block`` of ``page`` (in ``table``'s part), in study order."""
        return [(s, p) for s in self.studies.values() for p in s.spec.publishes
                if p.where == page and p.block == block and (table is None or p.table == table)]

    def part(self, page: str, block: str, table: str) -> tuple[Study, Publication] | None:
        """The one study feeding ``table``'s part of the block; ``None`` when none does, an error when two do."""
        found = self.parts(page, block, table)
        if len(found) > 1:
            raise ResultsError(f"{page}, block {block!r}: part {table!r} is published by {len(found)} studies "
                               f"({', '.join(s.name for s, _ in found)}); one only")
        return found[0] if found else None

    def records(self, folder: Path) -> list[dict[str, Any]]:
        """The cell records of ``folder`` (:func:`~tactile_zoo.bench.records.run_records`), read once per context:
        the blocks read the same folders several times over (the committed results, 3x), and decoding and checking
        the cell files was most of a page check's time. The records are shared, so nothing here may change one."""
        key = Path(folder).resolve()
        if key not in self._folders:
            self._folders[key] = run_records(key)  # [] where the folder has no cells/ folder
        return self._folders[key]

    def grids(self, study: Study, publication: Publication | None = None) -> list[GridSpec]:
        grids = [g for g in study.grids() if not g.superseded]
        return [study.grid(publication.grid)] if publication is not None and publication.grid else grids

    def cells(self, study: Study, publication: Publication | None = None) -> list[dict[str, Any]]:
        """The cells a table counts of the study's grids (of the publication's grid where it names one): ``ok``,
        computed by the current code, of a pair the grid plans, under the recipe and evaluation it plans."""
        key = (study.name, publication.grid if publication is not None else None)
        if key not in self._cells:
            out = []
            for grid in self.grids(study, publication):
                plan, folder = plans(study)[grid.name], study.folder(grid)
                protocol = ((grid.given().get("dataset_kwargs") or {}).get("biotac_dos") or {}).get("protocol")
                for rec in self.records(folder):
                    cfg, stored = plan.configs.get((rec["model"], rec["dataset"])), rec.get("config") or {}
                    if cfg is not None and rec.get("status") == "ok" and revision_gaps(rec) == [] \
                            and recipe_name_of(stored) == cfg.recipe_name \
                            and stored.get("evaluation", "validation") == cfg.evaluation \
                            and (protocol is None or rec.get("protocol") == protocol):
                        out.append(rec)
            self._cells[key] = out
        return self._cells[key]

    def claims(self, page: str, block: str, table: str) -> dict[str, Study]:
        """model -> the study whose cells alone stand for its rows in ``table``'s part of the block (at the model's
        registered revision, :meth:`claimed_cells`): the publications there that name ``models`` (a study that moved
        those models to a new revision and read that no row dropped). One model claimed by two studies is an
        error."""
        out: dict[str, Study] = {}
        for study, pub in self.parts(page, block, table):
            for model in pub.models:
                if model in out:
                    raise ResultsError(f"{page}, block {block!r}: {name(model)}'s rows are claimed by studies "
                                       f"{out[model].name} and {study.name}; one only")
                out[model] = study
        return out

    def claimed_cells(self, model: str, study: Study) -> list[dict[str, Any]]:
        """``model``'s cells in the study that claims its rows (:meth:`claims`), by :meth:`model_cells`."""
        return self.model_cells(model, [(study, None)], f"{name(model)} in study {study.name}")

    def model_cells(self, model: str, parts: Sequence[tuple[Study, Publication | None]], what: str
                    ) -> list[dict[str, Any]]:
        """``model``'s cells at its registered revision in the studies of ``parts`` (each of its publication's grid
        where it names one), pooled: one CPU type, or an error naming ``what``. The one filter behind every row a
        study claims, adds or puts on a card, so that a row never mixes revisions (a cell of the previous revision
        is the previous model's figure)."""
        revision = registered_revision(model)
        recs = [r for study, pub in parts for r in self.cells(study, pub) if r["model"] == model
                and int((r.get("config") or {}).get("model_revision") or 1) == revision]
        one_cpu_type(recs, what)
        return recs

    def left_out(self, study: Study) -> int:
        """How many cell files of the study's grids the tables leave out (not ok, another recipe, older code)."""
        return sum(len(self.records(study.folder(g))) for g in self.grids(study)) - len(self.cells(study))

    def reads(self, study: Study) -> dict[str, dict[str, Any]]:
        """The study's declared reads: the recorded values (computed, not recorded, where a read is not yet)."""
        if study.name not in self._reads:
            by_grid, _ = study_records(study, read=self.records)
            records = {r["cell_id"]: r for recs in by_grid.values() for r in recs}
            folders = {g.name: study.folder(g) for g in study.grids()}
            self._reads[study.name] = compute_reads(study, records, folders, record=False, by_grid=by_grid)
        return self._reads[study.name]

    def paper(self) -> dict[tuple[str, str], float]:
        """The paper's Table I (:func:`paper_figures`)."""
        return paper_figures(self.studies.values())

    def paper_text(self, model: str, dataset: str) -> str:
        value = self.paper().get((model, dataset))
        return "-" if value is None else f"{value:.4f}"

    def models(self) -> list[str]:
        """Table I's models, in its order: the models of the study that publishes its ``source`` part."""
        found = self.part("docs/table1.md", "table1", "source")
        if found is None:
            raise ResultsError("no study publishes the `source` part of docs/table1.md's table1 block: Table I's "
                               "models are its grid's")
        return list(self.grids(found[0])[0].given()["models"])


def paper_figures(studies: Iterable[Study]) -> dict[tuple[str, str], float]:
    """The X-Tacformer paper's Table I: (model, dataset) -> figure (BioTac-DoS: its textures figure), from the one
    study of ``studies`` that holds it in ``compares_with`` (the figures live there once)."""
    found = [(s, e) for s in studies for e in s.spec.compares_with if e.name == PAPER_TABLE]
    if len(found) != 1:
        raise ResultsError(f"the paper's Table I ({PAPER_TABLE!r} in compares_with) is held by {len(found)} "
                           f"studies ({', '.join(s.name for s, _ in found) or 'none'}); one must hold it")
    return {(f.model, f.dataset): f.value for f in found[0][1].figures}


def name(model: str) -> str:
    """A model's display name (``display_name`` in its registry entry)."""
    return str(registry.get_model_entry(model).meta.get("display_name") or model)


def group(records: Sequence[dict[str, Any]], model: str, dataset: str) -> list[dict[str, Any]]:
    """One row's records, sorted by fold and seed; cells of two configurations in one row are an error."""
    recs = sorted((r for r in records if r["model"] == model and r["dataset"] == dataset),
                  key=lambda r: (r["fold"], r["seed"]))
    hashes = sorted({r["config_hash"] for r in recs})
    if len(hashes) > 1:
        raise ResultsError(f"{model} on {dataset}: cells of {len(hashes)} configurations ({', '.join(hashes)}); one "
                           f"table row must be one configuration")
    return recs


def figure(recs: Sequence[dict[str, Any]], split: str, low_high: tuple[float, float] | None = None,
           std: bool = False) -> str:
    """``mean [95 % interval] (runs)``; with ``std``, ``mean ± std [95 % interval] (runs)``."""
    if not recs:
        return "not run yet"
    values = [r["metrics"][split]["accuracy"] for r in recs]
    low_high = low_high or records_interval(list(recs), split)
    interval = "-" if low_high is None else f"[{low_high[0]:.3f}, {low_high[1]:.3f}]"
    spread = f" ± {statistics.stdev(values):.3f}" if std and len(values) > 1 else ""
    return f"{statistics.fmean(values):.4f}{spread} {interval} ({len(recs)})"


def where(paper: float, low_high: tuple[float, float]) -> str:
    """Where a paper figure lies against one of our intervals: "above", "inside" or "below"."""
    return "above" if paper > low_high[1] else "below" if paper < low_high[0] else "inside"


def mean_std(values: Sequence[float]) -> str:
    return f"{statistics.fmean(values):.4f}" + (f" ± {statistics.stdev(values):.4f}" if len(values) > 1 else "")


def _interval(recs: list[dict[str, Any]], split: str = "test") -> str:
    low_high = records_interval(recs, split)
    return "-" if low_high is None else f"[{low_high[0]:.3f}, {low_high[1]:.3f}]"


def _runs(recs: list[dict[str, Any]]) -> str:
    folds, seeds = sorted({r["fold"] for r in recs}), sorted({r["seed"] for r in recs})
    if len(folds) > 1:
        return f"{len(recs)} ({len(folds)} folds x {len(seeds)} seed{'s' if len(seeds) > 1 else ''})"
    return f"{len(recs)} seed{'s' if len(recs) > 1 else ''}"


def _minutes(recs: list[dict[str, Any]]) -> str:
    return f"{statistics.fmean(r['train_seconds'] for r in recs) / 60:.0f}"


def ev_table(ctx: Context, records: list[dict[str, Any]], dataset: str, study: str) -> list[str]:
    lines = [f"**{TITLES[dataset]}** ({EV[dataset]}; study `{study}`)", "",
             "| model | paper | ours: mean ± std | 95 % interval | runs | min per cell |", "|---|---|---|---|---|---|"]
    for model in ctx.models():
        recs = group(records, model, dataset)
        figures = [mean_std([r["metrics"]["test"]["accuracy"] for r in recs]), _interval(recs), _runs(recs),
                   _minutes(recs)] if recs else ["not run yet", "-", "0", "-"]
        lines.append(f"| {name(model)} | {ctx.paper_text(model, dataset)} | " + " | ".join(figures) + " |")
    return lines


def biotac_table(ctx: Context, records: list[dict[str, Any]], study: str) -> list[str]:
    lines = ["**BioTac-DoS** (trained on the 4 basic objects, tested on the 7 unseen ones; the paper's column is "
             f"textures; study `{study}`)", "",
             "| model | paper (textures) | ours: textures | 95 % interval | solids | small | mean of the 3 sets | runs "
             "| min per cell |", "|---|---|---|---|---|---|---|---|---|"]
    for model in ctx.models():
        recs = group(records, model, "biotac_dos")
        if recs:
            per_set = {s: [r["metrics"][s]["accuracy"] for r in recs] for s in BIOTAC_SETS}
            mean3 = [statistics.fmean(values) for values in zip(*per_set.values(), strict=True)]
            figures = [mean_std(per_set["test_textures"]), _interval(recs, "test_textures"),
                       f"{mean_std(per_set['test_solids'])} {_interval(recs, 'test_solids')}",
                       f"{mean_std(per_set['test_small'])} {_interval(recs, 'test_small')}", mean_std(mean3),
                       _runs(recs), _minutes(recs)]
        else:
            figures = ["not run yet", "-", "-", "-", "-", "0", "-"]
        lines.append(f"| {name(model)} | {ctx.paper_text(model, 'biotac_dos')} | " + " | ".join(figures) + " |")
    return lines


def augment8000_table(ctx: Context) -> list[str]:
    """The Augment8000 rows: the only figure is the D-CNN released weights' (``benchmarks/results/
    dcnn_released.csv``, a fidelity check), nothing is trained."""
    released = ctx.repo / "benchmarks" / "results" / "dcnn_released.csv"
    lines = ["**Augment8000** (the 120 real-life samples; the 2000-sample training file is not released, so nothing "
             "is trained on it)", "", "| model | paper | ours |", "|---|---|---|"]
    rows = list(csv.DictReader(released.open())) if released.is_file() else []
    models = [r for r in rows if r["case"] == "model"]
    total = [r for r in rows if r["case"] == "total"]
    for model in ctx.models():
        if model == "dcnn" and total:
            correct, n = int(total[0]["correct"]), int(total[0]["n"])
            per_model = [int(r["correct"]) / int(r["n"]) for r in models]
            ours = (f"{correct}/{n} = {correct / n:.4f} ± {statistics.stdev(per_model):.4f} over the "
                    f"{len(models)} released models (released weights, evaluation only)")
        else:
            ours = "needs the training file (not released)"
        lines.append(f"| {name(model)} | {ctx.paper_text(model, 'augment8000')} | {ours} |")
    return lines


def zoo_table(ctx: Context, source: list[dict[str, Any]], zoo: list[dict[str, Any]], dataset: str,
              studies: tuple[str, str]) -> list[str]:
    """``zoo`` beside ``source`` and the paper on one dataset: a paired bootstrap of ``zoo - source`` over the runs
    both have (same fold and seed) and their test units, one-sided, Holm-corrected across the models."""
    split, title = SPLITS[dataset], TITLES[dataset]
    paired, same, rows = {}, set(), {}
    for model in ctx.models():
        src, new = group(source, model, dataset), group(zoo, model, dataset)
        rows[model] = (src, new)
        if src and new and {r["config_hash"] for r in src} == {r["config_hash"] for r in new}:
            same.add(model)
        if src and new and {(r["fold"], r["seed"]) for r in src} & {(r["fold"], r["seed"]) for r in new}:
            paired[model] = records_paired(src, new, split)
    adjusted = holm({m: r.p_value for m, r in paired.items() if m not in same})
    lines = [f"**`zoo` against `source` on {title}** (accuracy [95 % interval] (runs); the difference is paired over "
             "the runs both recipes have, one-sided p Holm-corrected across the models; studies "
             f"`{studies[0]}` and `{studies[1]}`)", "",
             "| model | paper | `source` | `zoo` | `zoo - source`, paired [95 %] (pairs) | Holm p | reading |",
             "|---|---|---|---|---|---|---|"]
    verdicts: dict[str, list[str]] = {"better": [], "noise": [], "worse": [], "same": [], "pending": []}
    for model in ctx.models():
        src, new = rows[model]
        paper = ctx.paper().get((model, dataset))
        result = paired.get(model)
        new_interval = records_interval(new, split) if new else None
        if result is None:
            diff, p_text, reading = "-", "-", "not run yet"
            verdicts["pending"].append(name(model))
        else:
            diff = f"{result.difference:+.4f} [{result.low:+.3f}, {result.high:+.3f}] ({result.n_cells})"
            if model in same:
                p_text, reading = "-", "the same configuration"
                verdicts["same"].append(name(model))
            else:
                p_text = f"{adjusted[model]:.3f}"
                kind = "better" if adjusted[model] < 0.05 else "worse" if result.high < 0 else "noise"
                reading = {"better": "`zoo` better", "worse": "`zoo` worse", "noise": "within noise"}[kind]
                verdicts[kind].append(name(model))
            if paper is not None and new_interval is not None:
                reading += f"; paper {where(paper, new_interval)} the `zoo` interval"
        lines.append(f"| {name(model)} | {ctx.paper_text(model, dataset)} | {figure(src, split)} | "
                     f"{figure(new, split, new_interval)} | {diff} | {p_text} | {reading} |")
    said = [f"{what}: {', '.join(names)}" for what, names in (
        ("`zoo` better (Holm p < 0.05)", verdicts["better"]), ("within noise", verdicts["noise"]),
        ("`zoo` worse", verdicts["worse"]), ("trained identically", verdicts["same"]),
        ("not run yet", verdicts["pending"])) if names]
    return [*lines, "", f"On {title}: " + "; ".join(said) + "."]


def ensemble_table(ctx: Context, study: Study, dataset: str, recipe: str, pattern: str) -> list[str]:
    """A study's declared seed ensembles on ``dataset`` (reads named ``pattern.format(model=...)`` + ``.dataset``):
    the members' mean and the ensemble's accuracy with its interval, as recorded."""
    reads = ctx.reads(study)
    shown = pattern.format(model="<model>")
    units = "test recordings" if dataset == "biotac_dos" else "test samples"
    what = "Declared seed ensembles" if recipe == "zoo" else f"Declared `{recipe}` seed ensembles"
    lines = [f"**{what} on {TITLES[dataset]}** (`{shown}`: the five "
             f"`{recipe}` seeds' test probabilities averaged; one run, the interval resamples the {units}; declared "
             f"reads of study `{study.name}`)", "",
             f"| model | paper | `{recipe}`, mean of the five seeds | `{shown}` | 95 % interval |",
             "|---|---|---|---|---|"]
    for model in ctx.models():
        entry = reads.get(f"{pattern.format(model=model)}.{dataset}") or {}
        value = entry.get("value") or {}
        if entry.get("missing"):
            figures = ["-", f"{5 - len(entry['missing'])} of 5 seeds so far", "-"]
        elif "unreadable" in value:
            figures = [f"{value['members_mean']:.4f}", f"no stored probabilities for `{SPLITS[dataset]}`", "-"]
        elif value:
            figures = [f"{value['members_mean']:.4f}", f"{value['accuracy']:.4f}",
                       f"[{value['low']:.3f}, {value['high']:.3f}]"]
        else:
            figures = ["-", "not declared", "-"]
        lines.append(f"| {name(model)} | {ctx.paper_text(model, dataset)} | " + " | ".join(figures) + " |")
    return lines


def cost_table(ctx: Context, records: list[dict[str, Any]], what: str, study: str, fresh: str | None = None,
               target: float | None = None) -> list[str]:
    """What the cells cost: per model and dataset the summed ``seconds`` of its cells (one torch thread each, so
    about CPU time). ``fresh``: the folder of one measured run, whose total is set against ``target`` CPU-hours."""
    datasets = ("ev_objects", "ev_containers", "biotac_dos")
    lines = [f"**What {what} cost** (the cells' own recorded times, `seconds` in each cell file: CPU-minutes of one "
             f"thread, summed over the runs; study `{study}`)", "",
             "| model | Ev-Objects | Ev-Containers | BioTac-DoS | model total |",
             "|---|" + "---|" * (len(datasets) + 1)]
    grand, runs = 0.0, 0
    for model in ctx.models():
        row, total = [], 0.0
        for dataset in datasets:
            recs = group(records, model, dataset)
            minutes = sum(r.get("seconds", r["train_seconds"]) for r in recs) / 60
            total, runs = total + minutes, runs + len(recs)
            row.append(f"{minutes:.0f} ({len(recs)} run{'s' if len(recs) != 1 else ''})" if recs else "-")
        grand += total
        lines.append(f"| {name(model)} | " + " | ".join(row) + f" | {total:.0f} |")
    if what == "this table":
        lines += ["", f"In all {grand / 60:.1f} CPU-hours, each cell computed from scratch in its own run (the target "
                  "of the performance issue was 5). The same configuration took up to twice as long when its cell "
                  "shared the machine with other work (Tacformer on Ev-Containers: 8 to 18 minutes over three seeds), "
                  "so these sums are upper bounds for a quiet pair of cores."]
    elif fresh:
        cpus = sorted({r.get("cpu", "unknown CPU") for r in records})
        planned = len(ctx.models()) * len(datasets) * 3  # seeds 0-2
        lines += ["", f"In all {grand / 60:.1f} CPU-hours for {runs} of the {planned} runs (the performance issue's "
                  f"target: {target:g}), one fresh run on {' and '.join(cpus)}, two cells at a time, one torch thread "
                  f"each (how it ran: `benchmarks/results/{fresh}/README.md`)."]
    else:
        lines += ["", f"In all {grand / 60:.1f} CPU-hours for {runs} runs, each run computed from scratch."]
    return lines


def table1_block(ctx: Context) -> str:
    """docs/table1.md's first block: per dataset the ``source`` table, then (where a study publishes the ``zoo``
    part) ``zoo`` against ``source`` and the declared ``zoo`` ensembles; Augment8000; the costs."""
    page, block = "docs/table1.md", "table1"
    source_study, _ = ctx.part(page, block, "source") or (None, None)
    if source_study is None:
        raise ResultsError(f"{page}: no study publishes the `source` part of block {block!r}")
    current = ctx.cells(source_study)
    zoo_part = ctx.part(page, block, "zoo")
    zoo = ctx.cells(zoo_part[0]) if zoo_part else []
    studies = (source_study.name, zoo_part[0].name if zoo_part else "")
    lines: list[str] = []
    for dataset in EV:
        lines += ev_table(ctx, current, dataset, source_study.name) + [""]
        if zoo_part:
            lines += zoo_table(ctx, current, zoo, dataset, studies) + [""]
            lines += ensemble_table(ctx, zoo_part[0], dataset, "zoo", "{model}_ens5") + [""]
    lines += biotac_table(ctx, current, source_study.name) + [""]
    if zoo_part:
        lines += zoo_table(ctx, current, zoo, "biotac_dos", studies) + [""]
    lines += augment8000_table(ctx) + ["", READING, ""] + cost_table(ctx, current, "this table", source_study.name)
    if zoo_part:
        folder = zoo_part[0].folder(ctx.grids(zoo_part[0])[0]).resolve().name
        lines += [""] + cost_table(ctx, zoo, f"the `zoo` cells in `{folder}/`", zoo_part[0].name)
    for study, publication in ctx.parts(page, block, "cost"):
        folder = study.folder(ctx.grids(study, publication)[0]).resolve().name
        lines += [""] + cost_table(ctx, ctx.cells(study, publication), f"the fresh run in `{folder}/`", study.name,
                                   fresh=folder, target=publication.target)
    left_out = ctx.left_out(source_study)
    if left_out:
        lines.append(f"\n{left_out} cell file(s) are left out: not ok, another recipe, or computed by an older "
                     f"revision of their model's code (to be rerun).")
    return "\n".join(lines)
