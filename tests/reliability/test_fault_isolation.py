"""Faults inside a bench run: failing models, a dying worker, failing writes, and broken third-party plugins.

Each fault must mark only its own cell failed (the grid goes on, the exit code says something failed), keep every
file written before it, and say what happened in one line.
"""

from __future__ import annotations

import errno
import json
import os
import warnings
from pathlib import Path

import pytest
from fake_plugins import GOOD_MODULE, FakeSite, unique
from reliability_helpers import cell_files, cell_records, numbers, quiet_bench, read_csv

from tactile_zoo.cli import main
from tactile_zoo.registry import PluginWarning

FAULTS = {  # model -> what its cell's error must say
    "fault_late_nan": "the training loss became nan in epoch 2",
    "fault_eval_error": "ValueError: fault_eval_error: evaluation failed on purpose",
    "fault_oom_runtime": "RuntimeError: CUDA error: out of memory",
    "fault_torch_oom": "OutOfMemoryError: out of memory: Tried to allocate 64.00 GiB",
    "fault_host_oom": "MemoryError: out of memory",
    "fault_ctor_error": "KeyError: 'fault_ctor_error: a bug in the constructor'",
    "tiny_broken": "RuntimeError: tiny_broken exploded on purpose",
}


def _run_order(reference_run: Path) -> list[str]:
    return json.loads((reference_run / "run.json").read_text())["grid"]["cells"]


def test_each_fault_fails_only_its_own_cell(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    models = [*FAULTS, "tiny_mlp"]  # the healthy model runs last, after every fault
    outcome, text, _ = quiet_bench(out, models=models, datasets=["tiny_blobs"])
    assert outcome.exit_code == 1
    assert outcome.counts["ok"] == 1 and outcome.counts["failed"] == len(FAULTS) and outcome.counts["pending"] == 0
    assert f"done: 1 ok, {len(FAULTS)} failed" in text
    records = {r["model"]: r for r in cell_records(out).values()}
    for model, message in FAULTS.items():
        assert records[model]["status"] == "failed"
        assert message in records[model]["error"], (model, records[model]["error"])
        assert "Traceback" in records[model]["traceback"] and "\n" not in records[model]["error"]
    board = {row["model"]: row for row in read_csv(out / "leaderboard.csv")}
    assert {m: board[m]["status"] for m in FAULTS} == dict.fromkeys(FAULTS, "failed")
    # the healthy cell after six failures is the very cell an undisturbed run computes
    (name,) = [n for n, r in cell_records(out).items() if r["model"] == "tiny_mlp"]
    assert numbers(cell_records(out)[name]) == numbers(cell_records(reference_run)[name])


@pytest.mark.slow
def test_a_worker_killed_mid_cell_fails_only_that_cell(reference_run: Path, tmp_path: Path) -> None:
    """The kernel's OOM killer takes a worker process: that cell fails, the pool is rebuilt, the next cell runs."""
    out = tmp_path / "run"
    outcome, text, err = quiet_bench(out, models=["fault_worker_kill", "tiny_mlp"], datasets=["tiny_blobs"],
                                     executor="process", workers=1, plugin_modules=["tiny_zoo", "fault_zoo"])
    assert outcome.exit_code == 1, err
    records = {r["model"]: r for r in cell_records(out).values()}
    assert records["fault_worker_kill"]["status"] == "failed"
    assert "the worker process running this cell died" in records["fault_worker_kill"]["error"]
    assert records["tiny_mlp"]["status"] == "ok"
    (name,) = [n for n, r in cell_records(out).items() if r["model"] == "tiny_mlp"]
    assert numbers(cell_records(out)[name]) == numbers(cell_records(reference_run)[name])


def test_a_present_but_corrupt_dataset_fails_loudly_and_the_others_run(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    """Broken data is not absent data: the bench names the file and exits non-zero; the other datasets still run."""
    bad = tmp_path / "home" / "alu_textures" / "raw" / "wool" / "t0.csv"
    bad.parent.mkdir(parents=True)
    bad.write_text("1,2\n3,4\n")
    outcome, text, err = quiet_bench(tmp_path / "run", models=["tiny_mlp"], datasets=["alu_textures", "tiny_blobs"],
                                     root=str(tmp_path / "home"))
    assert outcome.exit_code == 1 and outcome.counts["ok"] == 1 and outcome.counts["datasets_failed"] == 1
    assert f"tactile-zoo: error: dataset alu_textures failed to load: {bad}: 2 columns, expected 188" in err
    assert "1 dataset(s) failed" in text
    rows = {r["dataset"]: r for r in read_csv(tmp_path / "run" / "leaderboard.csv")}
    assert rows["alu_textures"]["status"] == "failed" and str(bad) in rows["alu_textures"]["error"]
    assert "To obtain it" not in rows["alu_textures"]["error"] and rows["tiny_blobs"]["status"] == "ok"
    assert main(["train", "tiny_mlp", "alu_textures", "--root", str(tmp_path / "home"), "--plugin-module",
                 "tiny_zoo"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and f"{bad}: 2 columns, expected 188" in err


# ----------------------------------------------------------------------------------------------- failing writes
def _mark(out: Path) -> None:
    """Make ``out`` a bench folder (its run.json marker), as a run that got this far would have: bench refuses to
    write into a folder that holds files and is not one."""
    (out / "run.json").write_text(json.dumps({"format": "tactile-zoo-bench/1"}))


def test_a_cell_file_that_cannot_be_written_keeps_the_earlier_cells(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    third = _run_order(reference_run)[2]
    blocker = out / "cells" / f"{third}.json"
    blocker.mkdir(parents=True)  # os.replace onto a directory fails, for root too (unlike chmod)
    _mark(out)
    outcome, _, err = quiet_bench(out)
    assert outcome.exit_code == 1
    assert f"cannot write cell file {blocker}" in err and "every cell file written before is intact" in err
    kept = cell_files(out)
    assert len(kept) == 2 and not list((out / "cells").glob(".*.tmp"))
    assert {n: numbers(r) for n, r in cell_records(out).items()} == \
        {n: numbers(r) for n, r in cell_records(reference_run).items() if n in kept}
    assert [r["status"] for r in read_csv(out / "leaderboard.csv")] == ["ok", "ok"]
    blocker.rmdir()
    outcome, _, err = quiet_bench(out)
    assert outcome.exit_code == 0, err
    assert len(outcome.reused) == 2 and len(outcome.ran) == 4
    assert {n: cell_files(out)[n] for n in kept} == kept  # resumed, not recomputed
    assert read_csv(out / "leaderboard.csv") == read_csv(reference_run / "leaderboard.csv")


def test_disk_full_while_writing_a_cell(reference_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                        ) -> None:
    """The disk fills up while the fourth cell file is flushed: its temporary file is removed, the three finished
    cells stay, and the error says why."""
    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc to tell which file is being flushed")
    out = tmp_path / "run"
    real_fsync, flushed = os.fsync, []

    def fsync(fd: int) -> None:
        if "/cells/" in os.readlink(f"/proc/self/fd/{fd}"):
            flushed.append(fd)
            if len(flushed) == 4:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    outcome, _, err = quiet_bench(out)
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert outcome.exit_code == 1
    assert "No space left on device" in err and _run_order(reference_run)[3] in err
    assert len(cell_files(out)) == 3 and not list((out / "cells").glob(".*"))
    assert [r["status"] for r in read_csv(out / "leaderboard.csv")] == ["ok"] * 3


def test_unwritable_tables_keep_every_cell_and_say_so(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / "leaderboard.csv").mkdir(parents=True)
    _mark(out)
    outcome, text, err = quiet_bench(out, datasets=["tiny_kfold"])
    assert outcome.exit_code == 1 and outcome.counts["ok"] == 4
    assert f"cannot write the tables in {out}" in err and "intact" in err
    assert len(cell_files(out)) == 4 and "done: 4 ok, 0 failed" in text


# ----------------------------------------------------------------------------------------------- third-party plugins
@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):  # noqa: ANN201
    root = tmp_path / "site"
    root.mkdir()
    fake = FakeSite(root, monkeypatch)
    yield fake
    fake.close()


def test_broken_plugins_never_stop_the_builtins(site: FakeSite, reference_run: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture) -> None:
    good, clash, wrong, broken, broken_set = (unique(s) for s in ("good", "clash", "wrong", "broken", "bset"))
    site.add("zt-rel-broken", "import zt_no_such_dependency_rel\n", models={broken: "Net"},
             datasets={broken_set: "dataset"})
    site.add("zt-rel-wrong", "VALUE = 42\n\ndef make(spec):\n    return {'not': 'a module'}\n",
             models={unique("value"): "VALUE", wrong: "make"})
    site.add("zt-rel-a", GOOD_MODULE, models={clash: "Net", good: "Net"})
    site.add("zt-rel-b", GOOD_MODULE, models={clash: "Net"})
    site.add("zt-rel-shadow", GOOD_MODULE, models={"tiny_mlp": "Net"})  # the same name as a built-in

    # the plan: built-ins and the good plugins are there, each broken plugin is one warning line
    args = ["bench", "--plugin-module", "tiny_zoo", "--dry-run", "--datasets", "tiny_blobs", "--models"]
    assert main([*args, "all"]) == 0
    out, err = capsys.readouterr()
    planned = next(line for line in out.splitlines() if "models:" in line).split("models:")[1]
    planned = [m.strip() for m in planned.split(",")]
    assert {"tiny_mlp", good, f"zt-rel-a:{clash}", f"zt-rel-b:{clash}", wrong} <= set(planned)
    assert broken not in planned and not any("value" in m for m in planned)
    for dist in ("zt-rel-broken", "zt-rel-wrong", "zt-rel-shadow"):
        assert "tactile-zoo: warning: " in err and dist in err
    assert f"zt-rel-a:{clash}" in err and "Traceback" not in err

    # strict mode: the same command is refused, naming the culprit
    assert main(["--strict-plugins", *args, "all"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "zt-rel-broken" in err and "zt_no_such_dependency_rel" in err

    # a real run: the built-in (not the plugin that shadows its name) and the good plugin run; the plugin whose
    # factory returns the wrong type fails its own cell only
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PluginWarning)
        outcome, _, _ = quiet_bench(tmp_path / "run", models=["tiny_mlp", wrong, good], datasets=["tiny_blobs"])
    assert outcome.exit_code == 1 and outcome.counts == {**outcome.counts, "ok": 2, "failed": 1}
    records = {r["model"]: r for r in cell_records(tmp_path / "run").values()}
    assert "dict, not a torch.nn.Module" in records[wrong]["error"]
    assert records[good]["status"] == "ok" and records[good]["config"]["model_source"] == "zt-rel-a"
    assert records["tiny_mlp"]["config"]["model_source"] == "builtin"
    (name,) = [n for n, r in cell_records(tmp_path / "run").items() if r["model"] == "tiny_mlp"]
    assert numbers(cell_records(tmp_path / "run")[name]) == numbers(cell_records(reference_run)[name])
