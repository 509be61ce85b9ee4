"""``tactile-zoo study compare``: a plugin model set against a small published set made here (the tiny zoo's
``tiny_mlp`` on ``tiny_blobs``, three seeds, and one tuning trial), never retraining the baseline; the report's paired
differences recomputed from the raw cells; each refusal (split, dataset revision, protocol, seeds) before any cell
trains; the same from a subprocess."""

from __future__ import annotations

import csv
import gzip
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import tiny_zoo
from forked_bench import run_python
from study_helpers import tz

from tactile_zoo.bench.paired import paired_bootstrap
from tactile_zoo.bench.records import cell_files, read_record
from tactile_zoo.study.audit import study_records
from tactile_zoo.study.compare import check_finished, load_comparison, plan_comparison, seed_list
from tactile_zoo.study.compare_report import comparison_tables, user_tuning
from tactile_zoo.study.published import build_set, encode_set, load_set, split_identity


@pytest.fixture(autouse=True)
def tiny() -> Iterator[None]:
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()


def _write_set(data: dict, path: Path) -> Path:
    path.write_bytes(gzip.compress(encode_set(data), mtime=0))
    return path


@pytest.fixture(scope="module")
def published(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The baseline's cells (tiny_mlp, seeds 0-2), one tuning trial of it, and the set built from them."""
    folder = tmp_path_factory.mktemp("published")
    tiny_zoo.register()
    try:
        common = ["--plugin-module", "tiny_zoo", "--datasets", "tiny_blobs", "--no-plots", "-q"]
        assert tz("bench", "--models", "tiny_mlp", "--seeds", "0,1,2", "--out", str(folder / "base"), *common)[0] == 0
        assert tz("bench", "--models", "tiny_mlp", "--seeds", "0", "--evaluation", "tuning",
                  "--out", str(folder / "tuning" / "trial"), *common)[0] == 0
    finally:
        tiny_zoo.unregister()
    data = build_set([folder / "base"], "tiny", 1, tuning=[folder / "tuning" / "trial"], root=folder)
    return _write_set(data, folder / "tiny-v1.json.gz")


def _study(folder: Path, published: Path, settings: str = "", against: str = "", seeds: str = "[0, 1]") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "mine.yaml"
    path.write_text(f"""study: mine
question: Does tiny_rate beat tiny_mlp on tiny_blobs?
grids:
  - name: mine
    settings: {{models: [tiny_rate], datasets: tiny_blobs, seeds: {seeds}, plugin_modules: [tiny_zoo]{settings}}}
against: {{set: {published}{against}}}
""")
    return path


@pytest.fixture(scope="module")
def compared(published: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``study compare`` of tiny_rate (seeds 0-1) against the set; returns the study file."""
    path = _study(tmp_path_factory.mktemp("compare"), published)
    tiny_zoo.register()
    try:
        code, out, err = tz("study", "compare", str(path), "-q")
    finally:
        tiny_zoo.unregister()
    assert code == 0, err
    return path


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as stream:
        return list(csv.DictReader(stream))


def _raw(folder: Path) -> dict[int, dict]:
    return {rec["seed"]: rec for rec in map(read_record, cell_files(folder))}


def test_the_paired_differences_are_those_of_the_raw_predictions(compared: Path, published: Path) -> None:
    mine, base = _raw(compared.parent / "mine-results" / "mine"), _raw(published.parent / "base")
    assert sorted(mine) == [0, 1]  # only the user's model was trained; the baseline's cells are the set's
    cells = [(np.asarray(base[s]["predictions"]["test"]["targets"]), base[s]["predictions"]["test"]["predictions"],
              mine[s]["predictions"]["test"]["predictions"]) for s in (0, 1)]
    for (targets, _, _), s in zip(cells, (0, 1), strict=True):
        assert mine[s]["predictions"]["test"]["targets"] == targets.tolist()
    by_hand = np.mean([(np.asarray(b) == t).mean() - (np.asarray(a) == t).mean() for t, a, b in cells])
    expected = paired_bootstrap(cells)
    [row] = _rows(compared.parent / "mine-results" / "compare" / "paired.csv")
    assert (row["model"], row["baseline"], row["pairs"], row["paired"]) == ("tiny_rate", "tiny_mlp", "2", "True")
    assert float(row["difference"]) == pytest.approx(by_hand, abs=1e-12)
    assert (float(row["low"]), float(row["high"]), float(row["p_value"])) == pytest.approx(
        (expected.low, expected.high, expected.p_value), abs=1e-12)


def test_the_means_curves_and_tuning_of_both_sides(compared: Path, published: Path) -> None:
    results = compared.parent / "mine-results" / "compare"
    means = {row["model"]: row for row in _rows(results / "means.csv")}
    base = _raw(published.parent / "base")
    # the baseline on the user's seeds only (0-1 of its 0-2), each figure its raw cells'
    assert means["tiny_mlp"]["seeds"] == "0-1" and means["tiny_mlp"]["side"] == "published default"
    assert float(means["tiny_mlp"]["accuracy"]) == pytest.approx(
        np.mean([base[s]["metrics"]["test"]["accuracy"] for s in (0, 1)]))
    low, accuracy, high = (float(means["tiny_mlp"][k]) for k in ("low", "accuracy", "high"))
    assert low <= accuracy <= high
    curves = {row["model"]: row for row in _rows(results / "curves.csv")}
    assert float(curves["tiny_mlp"]["accuracy_at_25"]) == pytest.approx(
        np.mean([base[s]["prefix"]["accuracy"][1] for s in (0, 1)]))
    assert means["tiny_rate"]["tuning"] == "not tuned: no tuning study was given (against.tuning)"
    assert means["tiny_mlp"]["tuning"] == "1 configuration(s) in 1 cell(s): tuning/trial (1/1)"
    report = (results / "report.md").read_text()
    assert f"Published set: **tiny-v1** (sha256 {load_set(published).sha256[:16]}, 3 cells" in report
    assert "### Paired differences per test recording" in report and "### Early classification" in report


def test_a_tuning_study_is_counted(compared: Path, published: Path, tmp_path: Path) -> None:
    tuning = tmp_path / "tuning.yaml"
    tuning.write_text("study: mine-tuning\nquestion: which lr?\nresults: tuned\nrules: {test_split: never}\n"
                      "grids:\n  - name: lr\n    settings: {models: [tiny_rate], datasets: tiny_blobs, seeds: [0],"
                      " evaluation: tuning, plugin_modules: [tiny_zoo]}\n")
    assert tz("study", "run", str(tuning), "-q")[0] == 0
    path = _study(tmp_path, published, against=", tuning: tuning.yaml")
    comparison = plan_comparison(*load_comparison(path))
    assert user_tuning(comparison) == {("tiny_rate", "tiny_blobs"): "1 configuration(s) in 1 cell(s) of the tuning "
                                                                     "study mine-tuning"}


@pytest.mark.parametrize(("settings", "against", "seeds", "said"), [
    (", dataset_kwargs: {tiny_blobs: {n_test: 6}}", "", "[0, 1]",
     "refused, a mismatched split: grid mine's cells of tiny_rate on tiny_blobs: with the dataset keywords "
     "{'n_test': 6} the test split (fold 0) holds 18 samples of 18 recordings"),
    (", evaluation: final", "", "[0, 1]", "refused, a different protocol: grid mine's cells of tiny_rate on "
                                          "tiny_blobs: evaluation 'final'; the published `default` cells of tiny_mlp"),
    (", quick: true", "", "[0, 1]", "refused, a different protocol: grid mine's cells of tiny_rate on tiny_blobs: "
                                    "subset {'train': 64, 'val': 32, 'test': 64}"),
    ("", "", "[0, 3, 4]", "refused, missing seeds: grid mine's cells of tiny_rate on tiny_blobs would run seed(s) "
                          "3-4 at fold(s) 0, which the published `default` cells of tiny_mlp on tiny_blobs (tiny-v1) "
                          "do not hold (they hold seeds 0-2)"),
    ("", ", seeds: equal", "[0, 1]", "refused, missing seeds: grid mine's cells of tiny_rate on tiny_blobs lack "
                                     "seed(s) 2 that the published `default` cells of tiny_mlp"),
])
def test_each_refusal_names_the_difference_before_any_cell_trains(published: Path, tmp_path: Path, settings: str,
                                                                   against: str, seeds: str, said: str) -> None:
    path = _study(tmp_path, published, settings, against, seeds)
    code, _, err = tz("study", "compare", str(path), "-q")
    assert code == 2 and said in err, err
    assert "Nothing was trained; nothing is compared." in err
    assert not (tmp_path / "mine-results").exists()


def test_another_dataset_revision_is_refused(published: Path, tmp_path: Path) -> None:
    data = json.loads(gzip.decompress(published.read_bytes()))
    for cell in data["cells"]:
        cell["dataset_revision"] = 2
    other = _write_set(data, tmp_path / "tiny-v2.json.gz")
    code, _, err = tz("study", "compare", str(_study(tmp_path, other)), "-q")
    assert code == 2 and ("refused, another dataset revision: grid mine's cells of tiny_rate on tiny_blobs would use "
                          "dataset revision 1; the published `default` cells of tiny_mlp on tiny_blobs (tiny-v1) use "
                          "revision 2") in err, err
    assert not (tmp_path / "mine-results").exists()


@pytest.mark.parametrize(("against", "said"), [
    ("", "against is required by study compare"),
    ("against: {set: nowhere.json.gz}", "against.set: 'nowhere.json.gz' is neither a published set packaged"),
    ("against: {set: SET, recipe: zoo}", "against.recipe: 'zoo' is not a recipe of the set tiny-v1 (default)"),
    ("against: {set: SET, baselines: [tiny_rate]}", "against.baselines: tiny_rate has no `default` cells"),
    ("against: {set: SET, seeds: some}", "against.seeds: Input should be 'subset' or 'equal'"),
])
def test_a_bad_against_section_is_named(published: Path, tmp_path: Path, against: str, said: str) -> None:
    path = _study(tmp_path, published)
    text = path.read_text()
    path.write_text(text[:text.index("against:")] + against.replace("SET", str(published)) + "\n")
    code, _, err = tz("study", "compare", str(path))
    assert code == 2 and said in err, err


def test_the_other_study_commands_read_a_comparison_study(published: Path, tmp_path: Path) -> None:
    code, out, err = tz("study", "check", str(_study(tmp_path, published)), "--history", str(tmp_path / "none"))
    assert code == 0, err
    assert "tiny_rate__tiny_blobs__f0__s0__" in out


def test_a_set_is_what_its_cells_give(published: Path) -> None:
    pset = load_set(published)
    assert (pset.set_id, len(pset.cells)) == ("tiny-v1", 3)
    raw = _raw(published.parent / "base")
    for record in pset.records():
        cell = raw[record["seed"]]
        assert record["config_hash"] == cell["config_hash"]
        assert record["predictions"]["test"]["predictions"] == cell["predictions"]["test"]["predictions"]
        assert record["predictions"]["test"]["targets"] == cell["predictions"]["test"]["targets"]
        assert np.allclose(record["predictions"]["test"]["probabilities"], cell["predictions"]["test"]["probabilities"],
                           atol=5e-4)
        assert record["metrics"]["test"]["accuracy"] == cell["metrics"]["test"]["accuracy"]
    assert seed_list([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


# ``tactile-zoo ARGV`` in a child forked from the warm server of tests/forked_bench.py, with the tiny zoo as a new
# interpreter has it: not registered, not imported (the server imported it: forgotten here, so the grid imports it)
_COMPARE = """
import os, sys
import tiny_zoo
from tactile_zoo import registry
tiny_zoo.unregister()
del sys.modules["tiny_zoo"]
assert "tiny_rate" not in registry.model_names() and "tiny_blobs" not in registry.list_datasets()
os.chdir(sys.argv[1])
from tactile_zoo.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_compare_from_a_subprocess(published: Path, tmp_path: Path) -> None:
    """The command in a process of its own (forked: an interpreter's start-up, torch and the package, is what the
    test would otherwise spend most on), the plugin model imported by the study's grid."""
    path = _study(tmp_path, published, seeds="[2]")
    run_python(_COMPARE, [str(tmp_path), "study", "compare", str(path), "-q"], tmp_path / "compare")
    [row] = _rows(tmp_path / "mine-results" / "compare" / "paired.csv")
    assert (row["model"], row["baseline"], row["pairs"]) == ("tiny_rate", "tiny_mlp", "1")


def test_a_quick_grid_compares_with_a_quick_set_whatever_the_order_of_its_subset_keys(published: Path,
                                                                                     tmp_path: Path) -> None:
    data = json.loads(gzip.decompress(published.read_bytes()))
    for cell in data["cells"]:
        cell["subset"] = {"test": 64, "train": 64, "val": 32}  # as a set stores it: sorted keys
    quick = _write_set(data, tmp_path / "quick-v1.json.gz")
    comparison = plan_comparison(*load_comparison(_study(tmp_path, quick, ", quick: true")))
    assert [(p.model, sorted(p.baselines), p.paired) for p in comparison.pairings] == [
        ("tiny_rate", ["tiny_mlp"], {"tiny_mlp": True})]


def test_the_against_section_is_frozen_with_the_grids(compared: Path, published: Path, tmp_path: Path) -> None:
    """Switching the set (or recipe, or baselines) after the cells ran is refused, as a changed grid is."""
    path = _study(compared.parent, published, against=", baselines: [tiny_mlp]")
    tiny_zoo.register()
    try:
        code, out, err = tz("study", "compare", str(path), "-q")
    finally:
        tiny_zoo.unregister()
        _study(compared.parent, published)  # the module's other tests read the file as it was
    assert code == 2 and "changed after cells exist" in err and "against" in err, err


def test_a_baseline_on_the_same_recordings_cut_otherwise_is_shown_not_paired(compared: Path, published: Path
                                                                              ) -> None:
    """Each test recording as two samples for the baseline (as BioTac-DoS's sliding windows are for SGnet): its mean
    stands beside yours, its row says why it is not paired, and no difference is computed."""
    data = json.loads(gzip.decompress(published.read_bytes()))
    renamed = {}
    for ident, test_set in data["test_sets"].items():
        test_set.update(targets=[t for t in test_set["targets"] for _ in (0, 1)],
                        groups=[i for i in range(test_set["n"]) for _ in (0, 1)], n=2 * test_set["n"])
        renamed[ident] = split_identity(test_set["dataset"], test_set["split"], test_set["targets"],
                                        test_set["groups"])
    data["test_sets"] = {renamed[k]: v for k, v in data["test_sets"].items()}
    for cell in data["cells"]:
        for entry in cell["splits"].values():
            entry.update(test_set=renamed[entry["test_set"]],
                         predictions=[p for p in entry["predictions"] for _ in (0, 1)])
            entry.pop("probabilities", None)
    windows = _write_set(data, compared.parent / "windows-v1.json.gz")
    path = compared.parent / "windows.yaml"
    text = compared.read_text().replace(str(published), str(windows))
    path.write_text(text.replace("study: mine", "study: mine\nresults: mine-results"))
    study, against = load_comparison(path)
    comparison = plan_comparison(study, against)
    assert comparison.pairings[0].paired == {"tiny_mlp": False}
    tables = comparison_tables(comparison, check_finished(comparison, study_records(study)[0]))
    [row] = tables["paired"]
    assert row["difference"] is None and row["why"].startswith("not paired: the same test recordings cut into 48 "
                                                               "samples (theirs) and 24 (yours)")
    assert {r["model"] for r in tables["means"]} == {"tiny_rate", "tiny_mlp"}


def test_a_damaged_set_is_refused_when_it_is_read(published: Path, tmp_path: Path) -> None:
    data = json.loads(gzip.decompress(published.read_bytes()))
    test_set = next(iter(data["test_sets"].values()))
    test_set["targets"][0] = (test_set["targets"][0] + 1) % 3  # the targets no longer those its identity names
    code, _, err = tz("study", "compare", str(_study(tmp_path, _write_set(data, tmp_path / "bad-v1.json.gz"))))
    assert code == 2 and "is not the test set its split identity names: the set is damaged" in err, err
