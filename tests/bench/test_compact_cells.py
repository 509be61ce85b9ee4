"""Compact cell files (issue 51): ``cells/<id>.json.gz`` holds the gzip of a plain cell file's exact bytes.

The records module reads both forms alike, so a committed folder can be stored compact without moving a number or a
hash; a damaged compact file is named like a damaged plain one; a folder holding both forms of one cell is refused,
naming both; compaction checks every compact file against its plain file before removing that, and a stopped run
finishes when run again; ``bench`` resumes into a compact folder without recomputing its cells. And a BioTac-DoS
textures split (4,549 windows) keeps its class probabilities, so seed ensembles over such cells can be read.
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import SMALL, run_cli

from tactile_zoo.bench import records
from tactile_zoo.bench.records import (
    CellFormsError,
    InvalidCell,
    InvalidCellsError,
    cell_files,
    compact_cell,
    compact_folder,
    read_cell_bytes,
    read_record,
    run_records,
    scan_cells,
)
from tactile_zoo.bench.rundir import RunDir

REPO = Path(__file__).resolve().parents[2]
#: a committed folder whose records hold per-sample probabilities (stored plain or compact)
COMMITTED = REPO / "benchmarks" / "results" / "paper-table1-full-r4"


def _plain_copy(source: Path, cells: Path) -> Path:
    """``source`` (plain or compact) written plain into ``cells``, byte for byte as its plain form."""
    cells.mkdir(parents=True, exist_ok=True)
    target = cells / source.name.removesuffix(".gz")
    target.write_bytes(read_cell_bytes(source))
    return target


def test_a_committed_record_round_trips_through_compaction_byte_for_byte(tmp_path: Path) -> None:
    source = cell_files(COMMITTED)[0]
    plain = _plain_copy(source, tmp_path / "run" / "cells")
    data, record = plain.read_bytes(), read_record(plain)
    assert isinstance(record, dict) and any("probabilities" in split for split in record["predictions"].values())
    compact = compact_cell(plain)
    assert compact.name == plain.name + ".gz" and not plain.exists()
    assert gzip.decompress(compact.read_bytes()) == data  # zcat gives the plain file back
    assert read_cell_bytes(compact) == data and read_record(compact) == record
    assert compact.stat().st_size < len(data) / 3
    assert run_records(tmp_path / "run") == [record] and cell_files(tmp_path / "run") == [compact]
    assert gzip.compress(data, compresslevel=9, mtime=0) == compact.read_bytes()  # the same bytes every time


@pytest.mark.parametrize("damage", ["truncated", "not_gzip", "empty", "bad_json_inside"])
def test_a_damaged_compact_file_is_named_like_a_damaged_plain_one(damage: str, tmp_path: Path) -> None:
    plain = _plain_copy(cell_files(COMMITTED)[0], tmp_path / "run" / "cells")
    compact = compact_cell(plain)
    data = compact.read_bytes()
    compact.write_bytes({"truncated": data[: len(data) // 2], "not_gzip": b"{\"cell_id\": 1}", "empty": b"",
                         "bad_json_inside": gzip.compress(b"{\"cell_id\": ")}[damage])
    result = read_record(compact)
    assert isinstance(result, InvalidCell) and result.path == compact, result
    assert {"truncated": "not a readable gzip file", "not_gzip": "not a readable gzip file", "empty": "empty file",
            "bad_json_inside": "not valid JSON"}[damage] in result.reason
    with pytest.raises(InvalidCellsError, match=compact.name):
        run_records(tmp_path / "run")
    assert scan_cells(compact.parent).invalid == [result]


def test_both_forms_of_one_cell_are_refused_naming_both(tmp_path: Path) -> None:
    cells = tmp_path / "run" / "cells"
    plain = _plain_copy(cell_files(COMMITTED)[0], cells)
    compact = plain.with_name(plain.name + ".gz")
    compact.write_bytes(gzip.compress(plain.read_bytes().replace(b'"seed": 0', b'"seed": 0 ')))  # not a copy
    cell_id = plain.name.removesuffix(".json")
    for read in (lambda: scan_cells(cells), lambda: run_records(tmp_path / "run"),
                 lambda: cell_files(tmp_path, recursive=True), lambda: RunDir(tmp_path / "run").cell_path(cell_id)):
        with pytest.raises(CellFormsError) as caught:
            read()
        assert str(plain) in str(caught.value) and str(compact) in str(caught.value)
    compact.write_bytes(gzip.compress(plain.read_bytes() + b" "))  # a compact file that is not the plain file's
    with pytest.raises(CellFormsError, match=compact.name):
        compact_folder(tmp_path)
    assert plain.exists() and compact.exists()  # nothing removed


def test_a_stopped_compaction_loses_nothing_and_finishes_when_run_again(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    cells = tmp_path / "run" / "cells"
    first, second = (_plain_copy(p, cells) for p in cell_files(COMMITTED)[:2])
    before = run_records(tmp_path / "run")
    # stopped after the first compact file took its name, before its plain file was removed
    monkeypatch.setattr(Path, "unlink", lambda self, missing_ok=False: (_ for _ in ()).throw(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        compact_folder(tmp_path)
    monkeypatch.undo()
    assert first.exists() and first.with_name(first.name + ".gz").exists() and second.exists()
    assert not [p for p in cells.iterdir() if p.name.endswith(".tmp")]
    with pytest.raises(CellFormsError):
        run_records(tmp_path / "run")
    done, already = compact_folder(tmp_path)
    assert [p.name for p in done] == [first.name + ".gz", second.name + ".gz"] and already == 0
    assert run_records(tmp_path / "run") == before
    assert compact_folder(tmp_path) == ([], 2)


def test_a_compact_file_that_would_not_read_back_is_never_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plain = _plain_copy(cell_files(COMMITTED)[0], tmp_path / "run" / "cells")
    data = plain.read_bytes()
    real = gzip.compress
    monkeypatch.setattr(records.gzip, "compress", lambda raw, **_: real(raw[:-2]))  # a lossy writer
    with pytest.raises(records.ResultsError, match="does not read back equal"):
        compact_cell(plain)
    assert plain.read_bytes() == data and [p.name for p in plain.parent.iterdir()] == [plain.name]


def test_bench_resumes_into_a_compact_folder_without_recomputing_and_rewrites_compact(
        reference_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    before = run_records(out)
    done, _ = compact_folder(out)
    assert len(done) == len(before) >= 4 and not list((out / "cells").glob("*.json"))
    stamps = {p: p.stat().st_mtime_ns for p in done}
    assert run_cli([*SMALL, "--out", str(out), "-q"]) == 0
    assert {p: p.stat().st_mtime_ns for p in cell_files(out)} == stamps  # every compact cell counted as finished
    assert run_records(out) == before
    # --force rewrites each cell in the form it is stored in: one file per cell, still compact
    assert run_cli([*SMALL, "--out", str(out), "-q", "--force"]) == 0
    assert sorted(cell_files(out)) == sorted(done) and all(read_cell_bytes(p).startswith(b"{\n") for p in done)
    run = RunDir(out)
    record = run_records(out)[0]
    assert run.write_cell(record).name.endswith(".json.gz")
    assert run.write_cell({**record, "cell_id": "new_cell"}).name == "new_cell.json"  # new cells: plain
    capsys.readouterr()


def test_the_compact_command_reports_and_refuses_a_damaged_cell(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture) -> None:
    from tactile_zoo.bench.compact import main

    cells = tmp_path / "results" / "a" / "cells"
    good = _plain_copy(cell_files(COMMITTED)[0], cells)
    assert main([str(tmp_path / "missing")]) == 2 and "FOLDER" in capsys.readouterr().err
    (cells / "broken.json").write_text("{\"cell_id\": ")
    assert main([str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err
    assert "broken.json" in err and "nothing compacted" in err and good.exists()
    (cells / "broken.json").unlink()
    assert main([str(tmp_path / "results")]) == 0
    assert "1 cell file(s) compacted" in capsys.readouterr().out and not good.exists()


# ----------------------------------------------------------------------------------------------- the probability cap
def _eval(rows: int, classes: int, seed: int) -> SimpleNamespace:
    rng = np.random.default_rng(seed)
    probabilities = rng.dirichlet(np.ones(classes), size=rows)
    return SimpleNamespace(targets=[int(t) for t in rng.integers(0, classes, rows)],
                           predictions=[int(p) for p in probabilities.argmax(1)], probabilities=probabilities.tolist())


def test_a_biotac_textures_split_keeps_its_probabilities_and_its_ensemble_can_be_read(
        reference_run: Path, tmp_path: Path) -> None:
    """SGnet's and ConvLSTM's BioTac-DoS cells: a 10,705-window test split, a 4,549-window textures split. The
    textures split stores its class probabilities (it did not under the old cap of 2500), the whole split still
    leaves them to its subsets, and three seeds' cells written and read back average into an ensemble."""
    from tactile_zoo.bench import worker

    assert worker.MAX_PROBABILITY_ROWS >= 4549 * 1.05
    assert worker.MAX_PROBABILITY_ROWS < 5290  # 1-window models: their whole 5290 split leaves them to the subsets
    template = run_records(reference_run)[0]
    run = RunDir(tmp_path / "run").prepare()
    textures = _eval(4549, 3, 0)
    for seed in range(3):
        member = _eval(4549, 3, seed + 1)
        member.targets = textures.targets  # the same test set, another model
        stored = worker._predictions(SimpleNamespace(tests={"test": _eval(10705, 3, 9), "test_textures": member},
                                                     test_groups={}))
        assert "probabilities" not in stored["test"] and len(stored["test_textures"]["probabilities"]) == 4549
        metrics = {**template["metrics"], "test_textures": {**template["metrics"]["test"], "n": 4549}}
        run.write_cell({**template, "cell_id": f"sgnet__biotac_dos__f0__s{seed}__h", "seed": seed,
                        "predictions": {"test_textures": stored["test_textures"]}, "metrics": metrics})
    compact_folder(run.path)  # and read back from compact files
    members = [r["predictions"]["test_textures"] for r in run_records(run.path)]
    assert len(members) == 3 and all(len(m["probabilities"]) == 4549 for m in members)
    mean = np.mean([np.asarray(m["probabilities"]) for m in members], axis=0)
    accuracy = float(np.mean(mean.argmax(1) == np.asarray(members[0]["targets"])))
    assert 0.0 < accuracy < 1.0


def test_the_cap_enters_no_config_hash() -> None:
    """Raising the cap changes which records store probabilities, never a configuration: no hash moves."""
    from tactile_zoo.bench import worker

    source = (REPO / "tactile_zoo" / "engine" / "config.py").read_text() + \
        (REPO / "tactile_zoo" / "bench" / "config.py").read_text()
    assert "MAX_PROBABILITY_ROWS" not in source and isinstance(worker.MAX_PROBABILITY_ROWS, int)


def test_a_large_split_is_still_left_without_probabilities() -> None:
    from tactile_zoo.bench import worker

    out = worker._eval_dict(_eval(worker.MAX_PROBABILITY_ROWS + 1, 2, 0), None, probabilities=True)
    assert "probabilities" not in out and len(out["predictions"]) == worker.MAX_PROBABILITY_ROWS + 1
