"""The bench folder and the bench command's bad input (issue 28): ``--out`` never overwrites files bench did not
write; ``report`` on a read-only folder is one line; an unknown ``--hparam`` and a named dataset without its data
stop the command (exit 2) before anything runs; report.md states the torch threads the cells ran with."""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest
from conftest import SMALL, run_cli

from tactile_zoo.cli import main

REPO = Path(__file__).resolve().parents[2]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<dir>" for p in sorted(folder.rglob("*"))}


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tactile-zoo: error: ") and "Traceback" not in err, err
    return lines[0]


# ----------------------------------------------------------------------------------------------- the marker
def test_out_refuses_a_folder_bench_did_not_write(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    mine = tmp_path / "my"
    mine.mkdir()
    (mine / "report.md").write_text("notes\n")
    (mine / "summary.csv").write_text("a,b\n")
    before = _tree(mine)
    assert run_cli([*SMALL, "--out", str(mine)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {mine}:" in line and "not a tactile-zoo bench folder" in line
    assert _tree(mine) == before  # nothing written, nothing created


def test_a_folder_holding_only_its_plan_documents_is_a_new_bench_folder(tmp_path: Path) -> None:
    """A study commits its PLAN.md and README before its first cell; bench writes neither name, so it runs there
    and leaves both as they were. Anything else in the folder still makes it someone else's."""
    out = tmp_path / "planned"
    out.mkdir()
    docs = {"README.md": "# what this folder holds\n", "PLAN.md": "# declared before any cell\n"}
    for name, text in docs.items():
        (out / name).write_text(text)
    assert run_cli([*SMALL, "--out", str(out), "-q"]) == 0
    assert json.loads((out / "run.json").read_text())["format"] == "tactile-zoo-bench/1"
    assert {name: (out / name).read_text() for name in docs} == docs and any((out / "cells").glob("*.json"))
    other = tmp_path / "other"
    other.mkdir()
    (other / "README.md").write_text("mine\n")
    (other / "notes.txt").write_text("mine\n")
    assert run_cli([*SMALL, "--out", str(other), "-q"]) == 2
    assert sorted(p.name for p in other.iterdir()) == ["README.md", "notes.txt"]


def test_a_new_or_empty_folder_is_marked_and_a_marked_one_resumes(reference_run: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    assert json.loads((reference_run / "run.json").read_text())["format"] == "tactile-zoo-bench/1"
    out = tmp_path / "empty"
    out.mkdir()
    one = ["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0", "--threads", "1", "--no-plots"]
    assert run_cli([*one, "--out", str(out), "-q"]) == 0
    assert json.loads((out / "run.json").read_text())["format"] == "tactile-zoo-bench/1"
    (out / "notes.txt").write_text("mine\n")  # a marked folder is a bench folder whatever else it holds
    assert run_cli([*one, "--out", str(out)]) == 0
    assert "1 already finished, 0 to run" in capsys.readouterr().out
    assert (out / "notes.txt").read_text() == "mine\n"


@pytest.mark.parametrize("legacy", ["run.json without format", "cells only"])
def test_bench_folders_of_older_versions_still_resume(legacy: str, reference_run: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    if legacy == "cells only":  # as the committed benchmarks/results folders without run.json
        for name in ("run.json", "run.lock", "leaderboard.csv", "summary.csv", "report.md"):
            (out / name).unlink()
    else:
        info = json.loads((out / "run.json").read_text())
        del info["format"]
        (out / "run.json").write_text(json.dumps(info))
    assert run_cli([*SMALL, "--out", str(out)]) == 0
    assert "6 already finished, 0 to run" in capsys.readouterr().out
    assert json.loads((out / "run.json").read_text())["format"] == "tactile-zoo-bench/1"  # marked from now on


@pytest.mark.parametrize("found", ["tactile-zoo-bench/9", "tactile-zoo-bench/x", 9])
def test_a_run_json_of_a_newer_or_unknown_format_is_refused_before_anything_is_written(
        found: object, reference_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Issue 38: a run.json that a newer tactile-zoo wrote (format /9, with a key this version does not know) was
    rewritten as /1 and the key lost. bench and report now refuse the folder, naming the file and both formats."""
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    info = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**info, "format": found, "from_the_future": {"keep": True}}))
    before = _tree(out)
    assert run_cli([*SMALL, "--out", str(out), "--force"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"{out / 'run.json'}: format {found!r} is " in line and "'tactile-zoo-bench/1'" in line
    assert ("newer than the one this tactile-zoo reads and writes" in line) == (found == "tactile-zoo-bench/9")
    assert _tree(out) == before  # run.json (and its extra key) untouched, no cell recomputed
    assert main(["report", str(out), "--no-plots"]) == 2
    assert f"{out / 'run.json'}: format {found!r}" in _one_error_line(capsys.readouterr().err)
    assert _tree(out) == before


def test_a_cell_of_a_newer_record_format_stops_bench_and_report(reference_run: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture) -> None:
    """A cell file written by a newer tactile-zoo is not damaged, and not this version's to move aside and
    recompute: bench refuses the folder before writing anything; report names it like any cell it cannot read."""
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    cell = sorted((out / "cells").glob("*.json"))[0]
    cell.write_text(json.dumps({**json.loads(cell.read_text()), "format": 9}))
    before = _tree(out)
    assert run_cli([*SMALL, "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {out}: {cell}: format is 9, newer than the cell record format this tactile-zoo reads (1)" in line
    assert _tree(out) == before
    assert main(["report", str(out), "--no-plots"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"{out}: {cell}: format is 9, newer than the cell record format this tactile-zoo reads (1)" in line
    assert _tree(out) == before


def test_committed_result_folders_are_bench_folders() -> None:
    from tactile_zoo.bench.records import cell_files
    from tactile_zoo.bench.rundir import RunDir

    folders = sorted({p.parent.parent for p in cell_files(REPO / "benchmarks" / "results", recursive=True)})
    assert len(folders) >= 19
    assert [str(f) for f in folders if not RunDir(f).is_bench_folder()] == []


# ----------------------------------------------------------------------------------------------- read-only
def _read_only(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """Make ``folder`` refuse every write, as a read-only mount or a colleague's folder would (chmod cannot:
    tests may run as root, who writes anyway)."""
    real_open, real_mkdir = os.open, os.mkdir
    top = str(folder.resolve())
    writing = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND

    def inside(path: object) -> bool:
        return os.path.abspath(os.fspath(path)).startswith(top)

    def guarded_open(path: object, flags: int, *args: object, **kwargs: object) -> int:
        if inside(path) and flags & writing:
            raise PermissionError(errno.EROFS, "Read-only file system", os.fspath(path))
        return real_open(path, flags, *args, **kwargs)

    def guarded_mkdir(path: object, *args: object, **kwargs: object) -> None:
        if inside(path) and not os.path.isdir(path):
            raise PermissionError(errno.EROFS, "Read-only file system", os.fspath(path))
        real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", guarded_open)
    monkeypatch.setattr(os, "mkdir", guarded_mkdir)


def test_report_on_a_read_only_folder_is_one_line(reference_run: Path, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    (out / "run.lock").unlink()  # as in a folder copied without it: the reader may not create it
    before = _tree(out)
    _read_only(monkeypatch, out)
    assert main(["report", str(out), "--no-plots"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"cannot write the tables into {out}" in line
    assert main(["report", str(out), "--running"]) == 0  # what a reader can do, it does
    assert f"no cell is running in {out}" in capsys.readouterr().out
    monkeypatch.undo()
    assert _tree(out) == before


# ----------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("hparam", ["bogus=1", "tiny_mlp:bogus=1"])
def test_an_unknown_hparam_exits_2_before_anything_runs(hparam: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "o"
    assert run_cli([*SMALL, "--hparam", hparam, "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "'bogus'" in line and "tiny_mlp" in line and "hidden, dropout" in line
    assert not out.exists()


@pytest.mark.parametrize("datasets", ["tiny_absent", "tiny_blobs,tiny_absent"])
def test_a_named_dataset_without_its_data_exits_2(datasets: str, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    out, root = tmp_path / "o", tmp_path / "empty"
    root.mkdir()
    assert run_cli(["--models", "tiny_mlp", "--datasets", datasets, "--root", str(root), "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--datasets tiny_absent" in line and "copy the tiny files" in line
    assert not out.exists()


def test_a_pattern_still_skips_datasets_without_data_but_not_all_of_them(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture) -> None:
    root = tmp_path / "empty"
    root.mkdir()
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_*", "--root", str(root), "--dry-run"]) == 0
    assert "skipped dataset tiny_absent" in capsys.readouterr().out
    assert run_cli(["--models", "tiny_mlp", "--datasets", "tiny_abs*", "--root", str(root),
                    "--out", str(tmp_path / "o")]) == 2
    assert "none of the selected datasets has its data here" in _one_error_line(capsys.readouterr().err)


# ----------------------------------------------------------------------------------------------- report.md
def test_report_states_the_threads_the_cells_ran_with(reference_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    info = json.loads((out / "run.json").read_text())
    info["environment"]["torch_threads"] = 2  # the bench process's own pool, as a 2-core machine reports it
    (out / "run.json").write_text(json.dumps(info))
    assert {json.loads(p.read_text())["threads"] for p in (out / "cells").glob("*.json")} == {1}
    assert main(["report", str(out), "--no-plots"]) == 0
    text = (out / "report.md").read_text()
    assert "1 torch thread(s) per cell" in text and "2 torch threads" not in text
