"""The recipe audit on a throw-away git repository: trials, the freeze commit, and the final cells' test reads."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import tiny_zoo

from tactile_zoo import registry
from tactile_zoo.engine.config import resolve_cell
from tactile_zoo.recipe import full_recipe
from tools.audit import audit, audit_plan

ZOO = {**tiny_zoo.TINY_RECIPE, "lr": 0.02, "label_smoothing": 0.1}
FULL = full_recipe(ZOO, {"tiny_blobs": 3})
#: a subclass of its own: registering sets the class's metadata, which tiny_mlp's class must keep
AuditMLP = type("AuditMLP", (tiny_zoo.TinyMLP,), {})


@pytest.fixture(autouse=True)
def audited_model() -> Iterator[None]:
    registry.register_model("audit_mlp", recipes={"source": tiny_zoo.TINY_RECIPE, "zoo": ZOO, "full": FULL}
                            )(AuditMLP)
    tiny_zoo.register()
    yield
    registry._TABLES["model"].builtin.pop("audit_mlp", None)
    tiny_zoo.unregister()


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout.strip()


def _commit(repo: Path, message: str) -> str:
    _git(repo, "add", "-A")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", message)
    return _git(repo, "rev-parse", "HEAD")


def _cell(folder: Path, name: str, **fields: object) -> None:
    config = resolve_cell("audit_mlp", "tiny_blobs", recipe_name="zoo").to_dict()
    record = {"cell_id": name, "model": "audit_mlp", "dataset": "tiny_blobs", "fold": 0, "seed": 0, "status": "ok",
              "config_hash": name, "config": config, "metrics": {"val": {"accuracy": 0.5}}, "test_reads": 1,
              "epochs_run": 1, "best_epoch": 1, "train_seconds": 1.0}
    for key, value in fields.items():
        if key == "evaluation":
            config["evaluation"] = value
        else:
            record[key] = value
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    (folder / "cells" / f"{name}.json").write_text(json.dumps(record))


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    _git(tmp_path, "init", "-q")
    tuning = tmp_path / "tuning"
    for i in range(2):  # two trials on seed 0, in tuning mode
        _cell(tuning / "lr", f"trial{i}", evaluation="tuning", test_reads=0)
    before = _commit(tmp_path, "trials")
    (tuning / "freeze.json").write_text(json.dumps({"recipe": "zoo", "models": {"audit_mlp": ZOO}}))
    freeze = _commit(tmp_path, "freeze the zoo recipes")
    _cell(tmp_path / "final", "final_ok", commit=freeze)
    _cell(tmp_path / "final", "final_early", commit=before)  # computed before the freeze
    _cell(tmp_path / "final", "final_twice", commit=freeze, test_reads=2)
    _cell(tmp_path / "final", "final_dirty", commit=freeze + "+dirty")
    return tmp_path


def test_the_audit_passes_a_clean_history_and_names_each_breach(repo: Path) -> None:
    lines, failures = audit(repo / "tuning", repo / "final", "zoo", repo=repo)
    text = "\n".join(lines)
    assert "audit_mlp on tiny_blobs: 2 trial(s); best validation accuracy 0.5000" in text
    assert "| final_ok | 1 |" in text and "| yes |" in text.split("final_ok")[1].splitlines()[0]
    assert sorted(f.split(":")[0] for f in failures) == ["final_dirty", "final_early", "final_twice"]
    assert any("read 2 time(s), not once" in f for f in failures)


def test_trials_outside_tuning_mode_over_budget_or_off_seed_fail(repo: Path) -> None:
    _cell(repo / "tuning" / "lr", "peeked")  # a validation cell: it read the test split
    _cell(repo / "tuning" / "lr", "seed3", evaluation="tuning", test_reads=0, seed=3)
    _, failures = audit(repo / "tuning", repo / "empty", "zoo", max_trials=3, repo=repo)
    assert any(f.startswith("trial peeked: not a tuning-mode cell") for f in failures)
    assert any(f.startswith("trial seed3: seed 3") for f in failures)
    assert any("4 trials, more than the budget of 3" in f for f in failures)


def test_a_recipe_changed_after_the_freeze_or_a_missing_freeze_fails(repo: Path) -> None:
    changed = {"source": tiny_zoo.TINY_RECIPE, "zoo": {**ZOO, "lr": 0.05}}
    registry.register_model("audit_mlp", recipes=changed)(AuditMLP)
    _, failures = audit(repo / "tuning", repo / "empty", "zoo", repo=repo)
    assert "audit_mlp: the registered 'zoo' recipe differs from the frozen one" in failures
    (repo / "tuning" / "freeze.json").unlink()
    _, failures = audit(repo / "tuning", repo / "empty", "zoo", repo=repo)
    assert failures == [f"{repo / 'tuning' / 'freeze.json'}: missing; the recipes were never frozen"]


def test_the_freeze_scopes_the_seed_rule_to_the_zoo_trial_folders_but_every_trial_counts(repo: Path) -> None:
    # an earlier issue tuned the source recipe on other seeds, in its own folder
    _cell(repo / "tuning" / "source-issue", "oldseed1", evaluation="tuning", test_reads=0, seed=1)
    _cell(repo / "tuning" / "lr", "zooseed2", evaluation="tuning", test_reads=0, seed=2)
    freeze = json.loads((repo / "tuning" / "freeze.json").read_text())
    (repo / "tuning" / "freeze.json").write_text(json.dumps({**freeze, "trial_folders": ["lr"]}))
    lines, failures = audit(repo / "tuning", repo / "empty", "zoo", max_trials=3, repo=repo)
    assert any(f.startswith("trial zooseed2: seed 2") for f in failures)
    assert not any("oldseed1" in f for f in failures)
    assert any("oldseed1 (in source-issue/, not a zoo trial folder): seed 1" in line for line in lines)
    assert any("4 trials, more than the budget of 3" in f for f in failures)  # the old trial still counts


def test_write_freeze_records_the_registered_recipes_and_refuses_an_unknown_folder(tmp_path: Path) -> None:
    from tools.audit import write_freeze

    (tmp_path / "lr").mkdir()
    frozen = json.loads(write_freeze(tmp_path, "zoo", ["lr"]).read_text())
    assert frozen["recipe"] == "zoo" and frozen["trial_folders"] == ["lr"]
    assert frozen["models"]["audit_mlp"] == json.loads(json.dumps(ZOO))
    assert "tiny_mlp" not in frozen["models"]  # a model without a zoo recipe is not frozen
    with pytest.raises(SystemExit, match="no trial folder nope"):
        write_freeze(tmp_path, "zoo", ["nope"])


def test_the_audit_prints_what_each_frozen_recipe_changes(repo: Path) -> None:
    from tools.audit import recipe_changes

    lines, _ = audit(repo / "tuning", repo / "final", "zoo", repo=repo)
    assert "- audit_mlp against `source`: everywhere: label_smoothing None -> 0.1, lr 0.03 -> 0.02" in lines
    sectioned = {**ZOO, "datasets": {"tiny_blobs": {"lr": 0.5, "dataset_kwargs": {"window": 5}}}}
    assert recipe_changes("audit_mlp", sectioned) == ("everywhere: label_smoothing None -> 0.1, lr 0.03 -> 0.02; "
                                                       "tiny_blobs: dataset_kwargs.window None -> 5, lr 0.03 -> 0.5")
    assert recipe_changes("audit_mlp", dict(tiny_zoo.TINY_RECIPE)) == "the source recipe"


def _full_cell(folder: Path, name: str, commit: str, cpu: str = "EPYC", **config: object) -> None:
    cfg = {**resolve_cell("audit_mlp", "tiny_blobs", recipe_name="full").to_dict(), **config}
    record = {"cell_id": name, "model": "audit_mlp", "dataset": "tiny_blobs", "fold": 0, "seed": 0, "status": "ok",
              "config": cfg, "test_reads": 1, "commit": commit, "cpu": cpu, "cpu_isa": {"capability": "AVX512"},
              "config_hash": name, "metrics": {"test": {"accuracy": 0.5}}, "epochs_run": 1, "best_epoch": 1,
              "train_seconds": 1.0}
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    (folder / "cells" / f"{name}.json").write_text(json.dumps(record))


def test_a_planned_round_needs_its_plan_first_the_planned_recipe_and_one_cpu(tmp_path: Path) -> None:
    _git(tmp_path, "init", "-q")
    round_ = tmp_path / "full"
    round_.mkdir()
    (round_ / "README.md").write_text("a round")
    before = _commit(tmp_path, "before the plan")
    lines, failures = audit_plan(round_, "full", repo=tmp_path)
    assert failures == [f"{round_ / 'PLAN.md'}: missing; a plan is declared by a commit"]
    (round_ / "PLAN.md").write_text("the plan")
    plan = _commit(tmp_path, "the plan")
    (round_ / "PLAN.md").write_text("the plan\n\n## Outcomes\n")
    _commit(tmp_path, "an outcome appended: the plan's commit is still the first")
    _full_cell(round_, "ok", plan)
    _full_cell(round_, "early", before)
    _full_cell(round_, "selected", plan, evaluation="validation")
    _full_cell(round_, "longer", plan, recipe={**resolve_cell("audit_mlp", "tiny_blobs", recipe_name="full")
                                                 .recipe.to_dict(), "max_epochs": 9})
    lines, failures = audit_plan(round_, "full", repo=tmp_path)
    assert f"Plan committed in {plan[:12]}; 4 cell(s) so far." in lines
    assert sorted(f.split(":")[0] for f in failures) == ["early", "longer", "selected"]
    _full_cell(round_, "elsewhere", plan, cpu="Xeon")
    assert any("cells on 2 CPU types" in f for f in audit_plan(round_, "full", repo=tmp_path)[1])


def test_a_plan_kept_in_another_folder_is_read_with_plan(tmp_path: Path) -> None:
    """DeepTactile's round-4 cells live in their own folder, under a section of the round's PLAN.md elsewhere."""
    _git(tmp_path, "init", "-q")
    cells, other = tmp_path / "cells_here", tmp_path / "round"
    cells.mkdir()
    other.mkdir()
    (other / "PLAN.md").write_text("the plan")
    plan = _commit(tmp_path, "the plan")
    _full_cell(cells, "ok", plan)
    assert audit_plan(cells, "full", repo=tmp_path)[1] == [f"{cells / 'PLAN.md'}: missing; a plan is declared by a "
                                                           "commit"]
    lines, failures = audit_plan(cells, "full", repo=tmp_path, plan=other / "PLAN.md")
    assert failures == [] and f"Plan committed in {plan[:12]}; 1 cell(s) so far." in lines
    _full_cell(cells, "dirty", plan + "+dirty")
    assert [f.split(":")[0] for f in audit_plan(cells, "full", repo=tmp_path, plan=other / "PLAN.md")[1]] == ["dirty"]
