"""The published result tables come from the study files (``benchmarks/studies/``) by one generator
(``python -m tools.published_tables``, :mod:`tactile_zoo.study.publish`), and ``study report`` reproduces every
number they publish: the README's headline, ``docs/table1.md`` (Table I, round 3's and round 4's ``full`` tables with
their declared ensembles), the fidelity ledger's decomposition and ``docs/published-results.md``."""

from __future__ import annotations

import re
import shutil
from collections import Counter
from pathlib import Path

import pytest

from tactile_zoo.bench.paired import records_paired
from tactile_zoo.errors import ResultsError
from tactile_zoo.study import load_study, write_report
from tactile_zoo.study.publish import FED, PAGES, check_pages, headline_problems, load_context, render_pages
from tactile_zoo.study.publish_rounds import Comparison, compare, default_recipes, gap_reading
from tactile_zoo.study.publish_tables import group, one_cpu_type
from tools.published_tables import main

#: one worker renders the published blocks from the committed cells once (the process's context, kept by
#: load_context) and checks each cell file once (cells_checked_once), for every test here and the published set's
pytestmark = pytest.mark.xdist_group("published_tables")

REPO = Path(__file__).resolve().parents[2]
STUDIES = REPO / "benchmarks" / "studies"
NUMBER = re.compile(r"[+-]?\d+(?:\.\d+)?")
#: the published pages whose every number ``study report`` must reproduce. The schedule trial's outcome is a tuning
#: study's (tests/benchmarks/test_tuning_studies.py); a page block a study starts to feed is added here.
REPRODUCED = [("README.md", "headline"), ("docs/table1.md", "table1"), ("docs/table1.md", "table1 full"),
              ("docs/table1.md", "table1 round 4"), ("docs/fidelity.md", "decomposition"),
              ("docs/published-results.md", "ours")]


def block_of(text: str, block: str) -> str:
    found = re.search(rf"<!-- {re.escape(block)}: begin[^>]*-->", text)
    assert found is not None, block
    return text[found.end():].split(f"<!-- {block}: end -->")[0]


def test_the_published_pages_are_what_the_studies_give(cells_checked_once: None,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--check"]) == 0, f"run python -m tools.published_tables and commit: {capsys.readouterr().err}"


def test_study_report_reproduces_every_published_number(tmp_path: Path, cells_checked_once: None) -> None:
    """Every number of each published block appears (as often) in the reports of the studies that feed it."""
    reports = Counter[str]()
    for path in sorted(STUDIES.glob("*.yaml")):
        study = load_study(path)
        if any(p.table for p in study.spec.publishes):
            written = write_report(study, out=tmp_path / study.name)
            text = written["report"].read_text(encoding="utf-8")
            assert ("**Not pre-registered**" in text) == (not study.spec.pre_registered), study.name
            reports |= Counter(NUMBER.findall(text))
    for page, block in REPRODUCED:
        published = Counter(NUMBER.findall(block_of((REPO / page).read_text(encoding="utf-8"), block)))
        assert published, (page, block)
        missing = published - reports
        assert not missing, f"{page}, block {block!r}: numbers no study report gives: {dict(missing)}"


def test_every_generated_block_is_fed_by_a_study() -> None:
    fed = {(p.where, p.block) for path in STUDIES.glob("*.yaml") for p in load_study(path).spec.publishes if p.table}
    assert set(REPRODUCED) <= fed and fed <= FED


def test_a_stale_page_fails_the_check_naming_it(tmp_path: Path, cells_checked_once: None) -> None:
    ctx = load_context(STUDIES)
    # the blocks are rendered from the checkout (its results folder, dcnn_released.csv) and kept by the context, so
    # render them there first, whatever ran before in this worker (that the checkout's pages pass is the first
    # test's); then check copies of the pages
    render_pages(ctx)
    for page in PAGES:
        (tmp_path / page).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / page, tmp_path / page)
    ctx.repo, original = tmp_path, ctx.repo
    try:
        assert check_pages(ctx) == []
        page = tmp_path / "docs" / "table1.md"
        text = page.read_text(encoding="utf-8")
        page.write_text(text.replace("| 0.8750 [0.822, 0.928] |", "| 0.8750 [0.822, 0.929] |", 1), encoding="utf-8")
        assert check_pages(ctx) == [f"{page} is out of date: run python -m tools.published_tables"]
    finally:
        ctx.repo = original


def test_a_headline_row_that_reads_another_recipe_is_named(cells_checked_once: None) -> None:
    ctx = load_context(STUDIES)
    committed = block_of((REPO / "README.md").read_text(encoding="utf-8"), "headline")
    assert headline_problems(committed, ctx) == []
    rows = committed.splitlines()
    sgnet = next(i for i, line in enumerate(rows) if line.startswith("| Ev-Objects | SGnet |"))
    picked = rows.copy()
    picked[sgnet] = picked[sgnet].replace("| `full` |", "| `zoo` |")
    assert headline_problems("\n".join(picked), ctx) == [
        "headline: SGnet on Ev-Objects reads `zoo`, not the registered default `full`: no recipe is chosen on test"]
    del picked[sgnet]
    assert headline_problems("\n".join(picked), ctx) == ["headline: no row for SGnet on Ev-Objects"]


def _cell(model: str, fold: int, seed: int, correct: list[int], hash_: str = "h", cpu: str = "AMD EPYC") -> dict:
    targets = [0] * len(correct)
    return {"model": model, "dataset": "biotac_dos", "fold": fold, "seed": seed, "config_hash": hash_, "cpu": cpu,
            "cpu_isa": {"capability": "AVX512"}, "cell_id": f"{model}-{fold}-{seed}",
            "metrics": {"test_textures": {"accuracy": sum(correct) / len(correct)}},
            "predictions": {"test_textures": {"targets": targets, "predictions": [0 if c else 1 for c in correct]}}}


def test_round_3_pairs_zoo_fold_k_with_full_seed_k_on_biotac() -> None:
    zoo = [_cell("tacformer", k, 0, [1] * (k + 1) + [0] * (9 - k)) for k in range(4)]
    # full seed k is one test unit better than zoo fold k; seed 4, with no zoo fold to pair, would drag the mean down
    full = [_cell("tacformer", 0, s, [1] * (s + 2) + [0] * (8 - s)) for s in range(4)] + \
        [_cell("tacformer", 0, 4, [0] * 10)]
    found = compare(["tacformer"], zoo, full, "biotac_dos")["tacformer"]
    assert found.pairs == 4 and found.difference == pytest.approx(0.1)
    assert records_paired(zoo, full, "test_textures").n_cells == 1  # by (fold, seed) alone only one pair meets


def _c(difference: float, pairs: int = 5, p_zoo: float = 0.5) -> Comparison:
    return Comparison(difference, difference - 0.1, difference + 0.1, pairs, 0.5, p_zoo)


def test_the_default_rule_of_round_3() -> None:
    models = ["sgnet", "convlstm", "cnn_lstm", "tacformer"]
    every = {d: {m: _c(0.02, 4 if d == "biotac_dos" else 5) for m in models}
             for d in ("ev_objects", "ev_containers", "biotac_dos")}
    every["ev_objects"]["convlstm"] = _c(-0.07)  # mean over the three -0.01: zoo, though nothing is significant
    every["ev_containers"]["cnn_lstm"] = _c(0.05, p_zoo=0.01)  # zoo significantly better on one dataset
    every["biotac_dos"]["tacformer"] = _c(0.02, pairs=3)  # a declared pair missing
    assert default_recipes(models, every) == {"sgnet": "full", "convlstm": "zoo", "cnn_lstm": "zoo",
                                              "tacformer": "pending"}


def test_the_gap_reading_splits_the_paper_lead() -> None:
    assert gap_reading(0.90, 0.88, ("full", 0.86)) == (
        "paper - default (`full`) +0.0400; best test epoch - default +0.0200: the optimistic protocol accounts for "
        "0.0200 of it")
    assert gap_reading(0.8611, 0.8426, ("full", 0.7847), (123 / 144, 144)).endswith(
        "accounts for 0.0579 of it; the best single run's best test epoch is 0.8542, 1 test sample below the paper")
    assert gap_reading(0.7167, 0.65, ("full", 0.5467), (43 / 60, 60)).endswith("is 0.7167, the paper's figure")
    assert gap_reading(0.90, 0.95, None) == "not run yet" and gap_reading(None, 0.9, ("zoo", 0.8)) == "no paper figure"


def test_two_cpu_types_or_two_configurations_in_one_row_are_errors() -> None:
    cells = [_cell("sgnet", 0, 0, [1, 0]), _cell("sgnet", 0, 1, [1, 1], cpu="Intel Xeon")]
    with pytest.raises(ResultsError, match="2 CPU types .*AMD EPYC.*Intel Xeon"):
        one_cpu_type(cells, "round 4")
    with pytest.raises(ResultsError, match="sgnet on biotac_dos: cells of 2 configurations"):
        group([cells[0], {**cells[1], "config_hash": "other"}], "sgnet", "biotac_dos")


def test_a_study_that_claims_a_model_moves_its_headline_rows_to_its_cells(cells_checked_once: None) -> None:
    """``table1-r5`` publishes ``{where: README.md, block: headline, table: recipe, models: [sgnet, ...]}``: SGnet's
    rows read that study's cells alone, at SGnet's registered revision (not its grid of the previous revision), and
    the sentence names the study; without the claim, only the claimed models' rows move back."""
    from tactile_zoo.registry import get_model_entry
    from tactile_zoo.study.publish import headline_block
    from tactile_zoo.study.publish_tables import figure

    ctx = load_context(STUDIES)
    study = ctx.studies["table1-r5"]
    claim = next(p for p in study.spec.publishes if p.models)
    assert claim.models == ["sgnet", "tacformer", "x_tacformer"]
    ctx.rendered.clear()
    after = headline_block(ctx).splitlines()
    study.spec.publishes.remove(claim)
    try:
        ctx.rendered.clear()
        before = headline_block(ctx).splitlines()
    finally:
        study.spec.publishes.append(claim)
        ctx.rendered.clear()
    revision = get_model_entry("sgnet").meta["revision"]
    cells = [r for r in ctx.cells(study) if r["model"] == "sgnet" and r["dataset"] == "ev_objects"]
    kept = [r for r in cells if r["config"]["model_revision"] == revision]
    assert len(kept) == 10 and len(cells) == 15, "the study's grid of the previous revision must be left out"
    row = next(line for line in after if line.startswith("| Ev-Objects | SGnet |"))
    assert f"| {figure(group(kept, 'sgnet', 'ev_objects'), 'test')} |" in row
    assert "`table1-r5` for SGnet, Tacformer and X-Tacformer, at their registered revisions" in after[0]
    assert "table1-r5" not in before[0]
    moved = [a for a, b in zip(after[2:], before[2:], strict=True) if a != b]
    assert moved and all(any(f"| {m} |" in line for m in ("SGnet", "Tacformer", "X-Tacformer")) for line in moved)


def test_a_claim_moves_the_published_results_rows_and_names_the_study(cells_checked_once: None) -> None:
    """``table1-r5`` also claims D-CNN, SGnet and both transformers in docs/published-results.md's honest column:
    those rows read its ten cells at the registered revision and name it; the others stay on the base study's."""
    from tactile_zoo.study.publish_rounds import ours_block
    from tactile_zoo.study.publish_tables import figure

    ctx = load_context(STUDIES)
    study = ctx.studies["table1-r5"]
    claim = next(p for p in study.spec.publishes if p.where == "docs/published-results.md")
    assert claim.models == ["dcnn", "sgnet", "tacformer", "x_tacformer"]
    after = ours_block(ctx).splitlines()
    study.spec.publishes.remove(claim)
    try:
        before = ours_block(ctx).splitlines()
    finally:
        study.spec.publishes.append(claim)
    kept = [r for r in ctx.cells(study) if r["model"] == "dcnn" and r["dataset"] == "ev_containers"
            and r["config"]["model_revision"] == 2]
    assert len(kept) == 10
    row = next(line for line in after if line.startswith("| D-CNN | Ev-Containers |"))
    assert f"| {figure(group(kept, 'dcnn', 'ev_containers'), 'test')} study `table1-r5`, revision 2 |" in row
    old = next(line for line in before if line.startswith("| D-CNN | Ev-Containers |"))
    assert "table1-r5" not in old and "(5) |" in old
    assert "or the one its row names" in after[0] and "or the one its row names" not in before[0]
    moved = [a for a, b in zip(after[2:], before[2:], strict=True) if a != b]
    assert len(moved) == 12 and not any(m in line for line in moved for m in ("| ConvLSTM |", "| CNN-LSTM |"))


def test_models_are_claimed_in_the_headline_only_and_from_the_studys_grids(tmp_path: Path) -> None:
    from tactile_zoo.errors import ConfigError

    text = (STUDIES / "table1-r5.yaml").read_text()
    for entry, message in [("{where: docs/table1.md, block: table1, table: cost, models: [sgnet]}",
                            "only the README headline's `recipe` part, docs/published-results.md's `ours` `full` "
                            "part and docs/models.md's `cards` take models"),
                           ("{where: README.md, block: headline, table: recipe, models: [deeptactile]}",
                            "'deeptactile' is not a model of the study's grids")]:
        path = tmp_path / "table1-r5.yaml"
        path.write_text(f"{text}publishes:\n  - {entry}\n")
        with pytest.raises(ConfigError, match=re.escape(message)):
            load_study(path)


def test_model_cards_show_each_publishing_studys_cells_at_the_registered_revision(cells_checked_once: None) -> None:
    """docs/models.md's card blocks: SGnet's row is table1-r5's ten cells at revision 3 (not its grids of the previous
    revision), ConvLSTM's pools rounds 3 and 4 under one label, and a model without a publishing study says so."""
    from tactile_zoo.study.publish_cards import card_block, card_models
    from tactile_zoo.study.publish_tables import figure

    ctx = load_context(STUDIES)
    assert {"sgnet", "convlstm", "multibarrel", "deeptactile"} <= set(card_models())
    sgnet = card_block(ctx, "sgnet").splitlines()
    kept = [r for r in ctx.cells(ctx.studies["table1-r5"]) if r["model"] == "sgnet" and r["dataset"] == "ev_objects"
            and r["config"]["model_revision"] == 3]
    assert len(kept) == 10
    assert sgnet[0].startswith("Measured at revision 3")
    assert sgnet[-1].startswith(f"| `full` | {figure(group(kept, 'sgnet', 'ev_objects'), 'test')} |")
    assert sgnet[-1].endswith("| `table1-r5` |")
    convlstm = card_block(ctx, "convlstm").splitlines()[-1]
    assert convlstm.endswith("| `table1-full-r3`, `table1-full-r4` |") and convlstm.count("(10)") == 3
    assert card_block(ctx, "multibarrel").startswith("No study has published a measured figure of multi-barrel SNN")


def test_a_card_row_names_its_label_and_models(tmp_path: Path) -> None:
    from tactile_zoo.errors import ConfigError

    text = (STUDIES / "table1-r5.yaml").read_text()
    for entry in ("{where: docs/models.md, block: cards, table: full}", "{where: docs/models.md, block: cards, "
                                                                          "models: [sgnet]}"):
        path = tmp_path / "table1-r5.yaml"
        path.write_text(f"{text}publishes:\n  - {entry}\n")
        with pytest.raises(ConfigError, match=re.escape("a model card row names its `table` (the row's label)")):
            load_study(path)


def test_a_study_report_shows_the_cards_it_feeds(cells_checked_once: None) -> None:
    from tactile_zoo.study.publish import study_blocks

    blocks = {(page, block): text for page, block, text in study_blocks(load_study(STUDIES / "table1-full-r4.yaml"))}
    assert blocks[("docs/models.md", "card convlstm")].startswith("Measured at revision")
    assert ("docs/models.md", "card sgnet") not in blocks and ("docs/table1.md", "table1 round 4") in blocks


def test_another_label_adds_rows_of_its_own_under_the_model(cells_checked_once: None) -> None:
    """A publication of the `ours` block under another label (here table1-r5's grid `rest`, as if it were a variant)
    adds one row per dataset beneath the model's own rows, naming its study; the model's rows do not move."""
    from tactile_zoo.study.publish_rounds import ours_block
    from tactile_zoo.study.publish_tables import figure
    from tactile_zoo.study.schema import Publication

    ctx = load_context(STUDIES)
    study = ctx.studies["table1-r5"]
    before = ours_block(ctx).splitlines()
    extra = Publication(where="docs/published-results.md", block="ours", table="variant", grid="rest",
                        models=["x_tacformer"])
    study.spec.publishes.append(extra)
    try:
        after = ours_block(ctx).splitlines()
    finally:
        study.spec.publishes.remove(extra)
    added = [line for line in after if line not in before]
    assert [line.split(" | ")[1] for line in added] == ["Ev-Objects", "Ev-Containers", "BioTac-DoS (textures)"]
    rest = [r for r in ctx.cells(study, extra) if r["model"] == "x_tacformer" and r["dataset"] == "ev_objects"
            and r["config"]["model_revision"] == 3]
    assert len(rest) == 7  # seeds 3-9
    assert added[0] == (f"| X-Tacformer, `variant` | Ev-Objects | 0.9167 | - | {figure(rest, 'test')} study "
                        f"`table1-r5`, revision 3 | - |")
    last = max(i for i, line in enumerate(before) if line.startswith("| X-Tacformer"))  # its own and others' rows
    assert after[last + 1:last + 4] == added and after[:last + 1] == before[:last + 1]
