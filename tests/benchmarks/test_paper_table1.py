"""The Table I generator (docs/table1.md and the README's headline): per dataset, paper figures next to mean ± std
and a 95 % interval over the current, finished runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from seed_probabilities import one_wrong_each

from tactile_zoo import registry
from tactile_zoo.bench.intervals import records_interval
from tools.paper_table1 import main, table

#: the generators run several times over the same committed cells (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("cells_checked_once")


def _predictions(accuracy: float, n: int, groups: list[int] | None = None) -> dict:
    right = round(accuracy * n)
    out = {"targets": [0] * n, "predictions": [0] * right + [1] * (n - right)}
    return out if groups is None else {**out, "groups": groups}


def _cell(folder: Path, model: str, dataset: str, seed: int, status: str = "ok", accuracy: float = 0.5,
          seconds: float = 60.0, revision: int | None = None, fold: int = 0, config_hash: str = "h",
          extra: dict | None = None) -> dict:
    current = registry.revision_of(registry.get_model_entry(model))
    record = {"cell_id": f"{model}__{dataset}__f{fold}__s{seed}__{status}__{revision}__{config_hash}",
              "model": model, "dataset": dataset, "fold": fold, "seed": seed, "status": status,
              "config_hash": config_hash, "train_seconds": seconds, "epochs_run": 1, "best_epoch": 1,
              "metrics": {"test": {"accuracy": accuracy}},
              "predictions": {"test": _predictions(accuracy, 20)},
              "config": {"model_revision": current if revision is None else revision, "dataset_revision": 1,
                         "recipe_name": "source"}}
    for split, (acc, groups) in (extra or {}).items():
        record["metrics"][split] = {"accuracy": acc}
        record["predictions"][split] = _predictions(acc, len(groups), groups)
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    name = f"{model}__{dataset}__f{fold}__s{seed}__{status}__{revision}__{config_hash}.json"
    (folder / "cells" / name).write_text(json.dumps(record))
    return record


def _rows(text: str, title: str) -> dict[str, str]:
    block = text.split(f"**{title}**")[1].split("\n\n**")[0]
    return {line.split(" | ")[0].lstrip("| "): line for line in block.splitlines() if line.startswith("| ")}


def test_ev_tables_average_current_ok_seeds_with_the_shared_interval(tmp_path: Path) -> None:
    a = _cell(tmp_path, "x_tacformer", "ev_objects", 0, accuracy=0.90, seconds=360)
    b = _cell(tmp_path, "x_tacformer", "ev_objects", 1, accuracy=0.95, seconds=480)
    _cell(tmp_path, "x_tacformer", "ev_objects", 2, status="failed")
    _cell(tmp_path, "sgnet", "ev_containers", 0, accuracy=0.65, seconds=600)
    _cell(tmp_path, "sgnet", "ev_objects", 0, accuracy=0.99, seconds=600, revision=1)  # older code: left out
    text = table(tmp_path)
    low, high = records_interval([a, b])
    # mean 0.925, sample std 0.0354 over the two ok seeds; the failed and the stale cells are left out and counted
    objects = _rows(text, "Ev-Objects")
    interval = f"[{low:.3f}, {high:.3f}]"
    assert objects["X-Tacformer"] == f"| X-Tacformer | 0.9167 | 0.9250 ± 0.0354 | {interval} | 2 seeds | 7 |"
    assert objects["SGnet"] == "| SGnet | 0.8944 | not run yet | - | 0 | - |"
    assert _rows(text, "Ev-Containers")["SGnet"].startswith("| SGnet | 0.6417 | 0.6500 | [")
    assert "2 cell file(s) are left out" in text
    assert "D-CNN | 0.7258 |" in _rows(text, "Augment8000")["D-CNN"]  # the released-weights figure, from its CSV
    assert _rows(text, "Augment8000")["SGnet"].endswith("| needs the training file (not released) |")


def test_biotac_declares_textures_and_resamples_recordings(tmp_path: Path) -> None:
    windows = [g for g in range(4) for _ in range(5)]  # 4 recordings of 5 windows
    recs = [_cell(tmp_path, "cnn_lstm", "biotac_dos", 0, fold=fold,
                  extra={"test_textures": (acc, windows), "test_solids": (0.6, windows), "test_small": (0.4, windows)})
            for fold, acc in enumerate((0.8, 0.6))]
    row = _rows(table(tmp_path), "BioTac-DoS")["CNN-LSTM"]
    low, high = records_interval(recs, "test_textures")
    assert row.startswith(f"| CNN-LSTM | 0.8182 | 0.7000 ± 0.1414 | [{low:.3f}, {high:.3f}] | 0.6000 ± 0.0000 [")
    assert "| 0.5667 ± 0.0471 | 2 (2 folds x 1 seed) |" in row  # mean of the three sets per run: 0.6 and 0.533


def test_two_configurations_in_one_row_is_an_error(tmp_path: Path) -> None:
    _cell(tmp_path, "tacformer", "ev_objects", 0, config_hash="aaa")
    _cell(tmp_path, "tacformer", "ev_objects", 1, config_hash="bbb")
    with pytest.raises(SystemExit, match="tacformer on ev_objects: cells of 2 configurations"):
        table(tmp_path)


def test_a_missing_cells_folder_is_one_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([str(tmp_path)]) == 2
    assert "cells not found" in capsys.readouterr().err


def test_the_table_page_and_the_readme_headline_are_regenerated_from_the_committed_cells() -> None:
    assert main(["--check"]) == 0, "run python -m tools.paper_table1 --readme and commit docs/table1.md, README.md"


def test_the_check_fails_when_either_block_is_stale(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tools.paper_table1 as pt

    committed = {"PAGE": pt.PAGE.read_text(), "README": pt.README.read_text()}
    for name in ("PAGE", "README"):
        page, readme = tmp_path / "table1.md", tmp_path / "README.md"
        page.write_text(committed["PAGE"])
        readme.write_text(committed["README"])
        monkeypatch.setattr(pt, "PAGE", page)
        monkeypatch.setattr(pt, "README", readme)
        assert main(["--check"]) == 0
        stale = getattr(pt, name)
        stale.write_text(stale.read_text().replace("| Ev-Objects", "| Ev-Objectz", 1))
        assert main(["--check"]) == 1, name


def test_render_replaces_only_the_marked_block(tmp_path: Path) -> None:
    from tools.paper_table1 import BEGIN, END, render

    _cell(tmp_path, "sgnet", "ev_objects", 0, accuracy=0.9)
    text = f"intro\n{BEGIN}\nold table\n{END}\noutro\n"
    out = render(text, tmp_path)
    assert out.startswith(f"intro\n{BEGIN}\n**Ev-Objects**") and out.endswith(f"{END}\noutro\n")
    assert "old table" not in out and render(out, tmp_path) == out
    with pytest.raises(SystemExit, match="lacks the markers"):
        render("no markers", tmp_path)


def test_the_readme_holds_the_headline_not_the_tables() -> None:
    from tools.headline import HEADLINE_BEGIN, HEADLINE_END, README
    from tools.paper_table1 import BEGIN, PAGE

    readme, page = README.read_text(), PAGE.read_text()
    assert BEGIN not in readme and BEGIN in page and page.startswith("# Reproducing Table I\n")
    block = readme.split(HEADLINE_BEGIN)[1].split(HEADLINE_END)[0]
    assert len(block.strip().splitlines()) <= 20 and "(docs/table1.md)" in readme


def _headline_folders(tmp_path: Path) -> Path:
    """Three recipes beside one another on Ev-Objects, three seeds each: ``full`` scores below ``source`` for
    X-Tacformer and below ``zoo`` for SGnet, so a headline that picks per row on test reads another recipe."""
    source, zoo, full = tmp_path / "t1", tmp_path / "t1-zoo", tmp_path / "t1-full"
    for seed in (0, 1, 2):
        x = _cell(source, "x_tacformer", "ev_objects", seed, accuracy=0.95)
        _zoo(x, zoo, 0.60)
        _full(x, full, 0.50)
        sgnet = _cell(source, "sgnet", "ev_objects", seed, accuracy=0.50)
        _zoo(sgnet, zoo, 0.95)
        _full(sgnet, full, 0.90)
    return source


def test_the_headline_reads_the_registered_default_recipe_whatever_the_others_score(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tools.headline as hl

    source = _headline_folders(tmp_path)
    monkeypatch.setattr(hl, "registered_default", lambda model: "zoo" if model == "sgnet" else "full")
    text = hl.headline(source)
    rows = {line.split(" | ")[1]: line for line in text.splitlines() if line.startswith("| Ev-Objects |")}
    # X-Tacformer reads `full` (0.50), not `source` (0.95); SGnet its `zoo`; the others stand in their own columns
    assert rows["X-Tacformer"].startswith("| Ev-Objects | X-Tacformer | 0.9167 | `full` | 0.5000 [")
    assert "| above | 0.9500 [" in rows["X-Tacformer"] and rows["X-Tacformer"].endswith("| (the headline) |")
    assert rows["SGnet"].startswith("| Ev-Objects | SGnet | 0.8944 | `zoo` | 0.9500 [")
    assert "| inside | 0.5000 [" in rows["SGnet"] and "| (the headline) | 0.9000 [" in rows["SGnet"]
    assert rows["Tacformer"].startswith("| Ev-Objects | Tacformer | 0.9027 | `full` | not run yet | - |")
    assert "D-CNN" not in rows  # no paper figure on Ev
    header = next(line for line in text.splitlines() if line.startswith("| dataset"))
    assert header.endswith("| ours | paper against our interval | `source`, for reference | `zoo`, for reference | "
                           "`full`, for reference |")
    assert "registered default recipe (the recipe column)" in text and "best" not in text
    assert text.endswith("Of the 10 rows, the paper's figure lies above our interval in 1 (X-Tacformer on Ev-Objects), "
                         "inside it in 1 and 8 not run yet.")


def test_the_headline_check_names_a_row_that_reads_another_recipe(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import tools.headline as hl

    source = _headline_folders(tmp_path)
    registered = {"x_tacformer": "full", "sgnet": "full"}
    monkeypatch.setattr(hl, "registered_default", lambda model: registered.get(model, "full"))
    honest = hl.headline(source)
    assert hl.problems(honest, source) == []
    # code that picks per row the recipe with the best test mean: X-Tacformer's `source`, SGnet's `zoo`
    picked = honest.replace("| `full` | 0.5000 [", "| `source` | 0.9500 [", 1).replace("| `full` | 0.9000 [",
                                                                                     "| `zoo` | 0.9500 [", 1)
    assert picked != honest and hl.problems(picked, source) == [
        "headline: SGnet on Ev-Objects reads `zoo`, not the registered default `full` (`default:` in "
        "tactile_zoo/recipes/sgnet.yaml): no recipe is chosen on test",
        "headline: X-Tacformer on Ev-Objects reads `source`, not the registered default `full` (`default:` in "
        "tactile_zoo/recipes/x_tacformer.yaml): no recipe is chosen on test"]
    # the right label on another recipe's figure, and a row left out
    relabelled = honest.replace("| `full` | 0.5000 [", "| `full` | 0.9500 [", 1)
    wrong = hl.problems("\n".join(line for line in relabelled.splitlines()
                                  if not line.startswith("| Ev-Objects | Tacformer |")), source)
    assert len(wrong) == 2 and wrong[0] == "headline: no row for Tacformer on Ev-Objects", wrong
    assert wrong[1].startswith("headline: X-Tacformer on Ev-Objects shows 0.9500 [") and "(3), but its `full` cells " \
        "give 0.5000 [" in wrong[1], wrong
    # the generator follows the registry: with `zoo` registered for SGnet, its row reads `zoo` and passes
    registered["sgnet"] = "zoo"
    assert hl.problems(hl.headline(source), source) == []
    with pytest.raises(SystemExit, match="recipe 'ema': no Table I folder holds its cells"):
        hl.recipe_cells(source, "ema")


def test_the_committed_headline_reads_each_models_registered_default(capsys: pytest.CaptureFixture,
                                                                     tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import tools.paper_table1 as pt
    from tools.headline import HEADLINE_BEGIN, HEADLINE_END, registered_default

    block = pt.README.read_text().split(HEADLINE_BEGIN)[1].split(HEADLINE_END)[0]
    rows = [line.split(" | ") for line in block.splitlines() if line.startswith("| Ev-")]
    names = {name: model for model, name in pt.NAMES.items()}
    assert len(rows) == 10 and all(row[3] == f"`{registered_default(names[row[1]])}`" for row in rows), block
    assert "flatters" not in block and "best" not in block
    # a planted headline whose ConvLSTM row reads `source` (as round 3's did) fails --check, named as such
    planted = tmp_path / "README.md"
    old = next(" | ".join(row) for row in rows if row[:2] == ["| Ev-Containers", "ConvLSTM"])
    planted.write_text(pt.README.read_text().replace(old, old.replace(f"| `{registered_default('convlstm')}` |",
                                                                      "| `source` |")))
    monkeypatch.setattr(pt, "README", planted)
    monkeypatch.setattr(pt, "render", lambda text, folder: text)  # the page is another test's: not rebuilt here
    assert pt.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert "headline: ConvLSTM on Ev-Containers reads `source`, not the registered default" in err, err
    # code that picks a recipe per row: --readme refuses to write its headline, and writes nothing
    picked = planted.read_text()
    monkeypatch.setattr(pt, "render_headline", lambda text, folder: picked)
    monkeypatch.setattr(pt, "PAGE", tmp_path / "table1.md")
    planted.write_text("the committed README")
    assert pt.main(["--readme"]) == 1 and not pt.PAGE.exists() and planted.read_text() == "the committed README"
    assert "reads `source`, not the registered default" in capsys.readouterr().err


def _zoo(record: dict, folder: Path, accuracy: float, config_hash: str = "z") -> dict:
    """``record`` retrained with the ``zoo`` recipe: the same test set, another accuracy."""
    zoo = {**record, "config_hash": config_hash, "metrics": {"test": {"accuracy": accuracy}},
           "predictions": {"test": _predictions(accuracy, 20)}, "config": {**record["config"], "recipe_name": "zoo"}}
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    name = f"{record['model']}__{record['dataset']}__f{record['fold']}__s{record['seed']}__{config_hash}.json"
    (folder / "cells" / name).write_text(json.dumps(zoo))
    return zoo


def _full(record: dict, folder: Path, accuracy: float) -> dict:
    """``record`` retrained with the ``full`` recipe (every training recording, test read once at the end)."""
    full = _zoo(record, folder, accuracy, config_hash="f")
    full["config"] = {**full["config"], "recipe_name": "full", "evaluation": "final"}
    name = f"{record['model']}__{record['dataset']}__f{record['fold']}__s{record['seed']}__f.json"
    (folder / "cells" / name).write_text(json.dumps(full))
    return full


def test_the_zoo_comparison_pairs_runs_corrects_across_models_and_reads_each_row(tmp_path: Path) -> None:
    source, zoo = tmp_path / "t1", tmp_path / "t1-zoo"
    for seed in (0, 1, 2):
        _zoo(_cell(source, "x_tacformer", "ev_objects", seed, accuracy=0.50), zoo, 1.0)  # every sample fixed
        _zoo(_cell(source, "tacformer", "ev_objects", seed, accuracy=0.50), zoo, 0.55)  # one sample of 20
        same = _cell(source, "cnn_lstm", "ev_objects", seed, accuracy=0.60)
        _zoo(same, zoo, 0.60, config_hash="h")  # the zoo recipe trains exactly as the source one here
    _zoo(_cell(source, "x_tacformer", "ev_objects", 3, accuracy=0.5) | {"seed": 3}, zoo, 1.0)
    (source / "cells" / "x_tacformer__ev_objects__f0__s3__ok__None__h.json").unlink()  # a zoo-only seed: unpaired
    rows = _rows(table(source), "`zoo` against `source` on Ev-Objects")
    assert rows["X-Tacformer"].startswith("| X-Tacformer | 0.9167 | 0.5000 [")
    # four zoo seeds in its row, three pairs in the difference. The pairs agree (no seed part) and share one test set
    # of 20 samples, half of them fixed: 0.5 +- t_19 * sqrt(0.25 / 20), a p-value far below 0.05 even x2 by Holm
    assert "| 1.0000 [1.000, 1.000] (4) | +0.5000 [+0.2" in rows["X-Tacformer"]
    assert rows["X-Tacformer"].endswith("(3) | 0.000 | `zoo` better; paper below the `zoo` interval |")
    assert rows["Tacformer"].endswith("| within noise; paper above the `zoo` interval |")
    assert "| - | the same configuration; paper above" in rows["CNN-LSTM"] and "+0.0000" in rows["CNN-LSTM"]
    assert rows["SGnet"].endswith("| not run yet |")
    text = table(source)
    assert ("On Ev-Objects: `zoo` better (Holm p < 0.05): X-Tacformer; within noise: Tacformer; trained identically: "
            "CNN-LSTM; not run yet: SGnet, ConvLSTM, D-CNN.") in text
    assert "`zoo` against `source` on Ev-Containers" in text  # every dataset gets its block once zoo cells exist
    assert "`zoo` against" not in table(source, zoo_folder=tmp_path / "none")
    zoo_cost = _rows(text, "What the `zoo` cells in `t1-zoo/` cost")  # 60 s per cell in the fixture
    assert zoo_cost["X-Tacformer"] == "| X-Tacformer | 4 (4 runs) | - | - | 4 |"


def test_the_declared_ensemble_averages_all_five_seeds_probabilities(tmp_path: Path) -> None:
    source, zoo = tmp_path / "t1", tmp_path / "t1-zoo"
    targets = [0, 1, 2, 0, 1]
    for seed in range(5):  # every seed scores 4/5, the average of the probabilities is right on all five
        probabilities, predictions = one_wrong_each(targets, seed)
        record = _cell(source, "x_tacformer", "ev_objects", seed, accuracy=0.5)
        record["predictions"] = {"test": {"targets": targets, "predictions": [0] * 5}}  # the same test set
        (source / "cells" / f"x_tacformer__ev_objects__f0__s{seed}__ok__None__h.json").write_text(json.dumps(record))
        zoo_record = _zoo(record, zoo, 0.8)
        zoo_record["predictions"] = {"test": {"targets": targets, "predictions": predictions,
                                              "probabilities": probabilities}}
        zoo_record["metrics"] = {"test": {"accuracy": 0.8}}
        name = f"x_tacformer__ev_objects__f0__s{seed}__z.json"
        (zoo / "cells" / name).write_text(json.dumps(zoo_record))
    rows = _rows(table(source), "Declared seed ensembles on Ev-Objects")
    assert rows["X-Tacformer"].startswith("| X-Tacformer | 0.9167 | 0.8000 | 1.0000 | [1.000, 1.000] |")
    assert rows["SGnet"] == "| SGnet | 0.8944 | - | 0 of 5 seeds so far | - |"
    (zoo / "cells" / "x_tacformer__ev_objects__f0__s4__z.json").unlink()  # four seeds are not the declared model
    assert _rows(table(source), "Declared seed ensembles on Ev-Objects")["X-Tacformer"].endswith(
        "| - | 4 of 5 seeds so far | - |")


def test_the_fresh_cost_run_beside_the_table_is_summed_per_model_and_dataset(tmp_path: Path) -> None:
    table_folder, cost = tmp_path / "paper-table1", tmp_path / "table1-cost"
    _cell(table_folder, "sgnet", "ev_objects", 0)
    for seed, seconds in ((0, 600.0), (1, 1200.0)):
        _cell(cost, "dcnn", "ev_objects", seed, seconds=seconds)
    _cell(cost, "dcnn", "biotac_dos", 0, seconds=5400.0)
    for path in (cost / "cells").glob("*.json"):  # the fresh run trains the default recipe
        record = json.loads(path.read_text())
        path.write_text(json.dumps({**record, "seconds": record["train_seconds"], "cpu": "AMD EPYC",
                                    "config": {**record["config"], "recipe_name": "zoo"}}))
    text = table(table_folder)
    block = text.split("**What the fresh run in `table1-cost/` cost**")[1]
    assert "| D-CNN | 30 (2 runs) | - | 90 (1 run) | 120 |" in block
    assert "In all 2.0 CPU-hours for 3 of the 54 runs" in block and "one fresh run on AMD EPYC," in block
