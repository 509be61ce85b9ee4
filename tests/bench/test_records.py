"""A damaged cell is never silent (issue 28): every unreadable or invalid cell file is named by ``report`` and
``bench``, which exit non-zero unless ``--skip-invalid``; ``bench`` moves a damaged cell of its grid to
``cells/damaged/`` before recomputing it. Before, a truncated, empty or ``[]`` cell vanished from the leaderboard
without a word, ``"accuracy": "high"`` crashed both commands with a traceback, and an ok cell without metrics was
listed with a blank accuracy."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import SMALL, read_board, run_cli

from tactile_zoo.cli import main

REPO = Path(__file__).resolve().parents[2]


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:200])


def _empty(path: Path) -> None:
    path.write_bytes(b"")


def _array(path: Path) -> None:
    path.write_text("[]\n")


def _edit(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def apply(path: Path) -> None:
        record = json.loads(path.read_text())
        change(record)
        path.write_text(json.dumps(record))  # Python writes NaN and Infinity as the bare (non-JSON) literals
    return apply


def _huge_seconds(path: Path) -> None:
    """``1e999`` is valid JSON syntax that Python's json reads as infinity."""
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "train_seconds": "HUGE"}).replace('"HUGE"', "1e999"))


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated": (_truncate, "not valid JSON"),
    "empty": (_empty, "empty file"),
    "array": (_array, "holds an array"),
    "accuracy_high": (_edit(lambda r: r["metrics"]["test"].update(accuracy="high")),
                      'metrics.test.accuracy is "high", expected a number between 0 and 1'),
    "no_metrics": (_edit(lambda r: r.pop("metrics")), "no 'metrics'"),
    "fold_text": (_edit(lambda r: r.update(fold="0")), 'fold is "0", expected a non-negative integer'),
    "accuracy_above_one": (_edit(lambda r: r["metrics"]["test"].update(accuracy=1.5)), "metrics.test.accuracy"),
    "predictions_mismatch": (_edit(lambda r: r["predictions"]["test"]["targets"].pop()), "predictions.test"),
    # issue 38: the finite-and-range rule (tactile_zoo.bench.schema)
    "accuracy_nan": (_edit(lambda r: r["metrics"]["test"].update(accuracy=float("nan"))),
                     "metrics.test.accuracy is NaN, expected a number between 0 and 1"),
    "fold_negative": (_edit(lambda r: r.update(fold=-5)), "fold is -5, expected a non-negative integer"),
    "best_epoch_huge": (_edit(lambda r: r.update(best_epoch=10 ** 30)),
                        "best_epoch is 1000000000000000000000000000000, expected at most epochs_run"),
    "best_epoch_float": (_edit(lambda r: r.update(best_epoch=1e30)),
                         "best_epoch is 1e+30, expected a non-negative integer"),
    "seconds_infinite": (_huge_seconds, "train_seconds is Infinity, expected a finite number, 0 or more"),
    "seconds_negative": (_edit(lambda r: r.update(train_seconds=-1.0)), "train_seconds is -1.0"),
    "count_negative": (_edit(lambda r: r.update(n_test=-3)), "n_test is -3, expected a non-negative integer"),
    "seed_negative": (_edit(lambda r: r.update(seed=-1)), "seed is -1"),
    "val_n_negative": (_edit(lambda r: r["metrics"]["val"].update(n=-1)), "metrics.val.n is -1"),
    "nan_in_a_curve": (_edit(lambda r: r["curve"][1].update(val_loss=float("nan"))),
                       "curve[1].val_loss is NaN, expected a finite number (a record holds no NaN or infinity)"),
    "curve_accuracy_above_one": (_edit(lambda r: r["curve"][0].update(val_accuracy=2.0)),
                                 "curve[0].val_accuracy is 2.0, expected a number between 0 and 1"),
    "prefix_nan": (_edit(lambda r: r["prefix"]["accuracy"].__setitem__(0, float("nan"))), "prefix needs"),
    "probability_infinite": (_edit(lambda r: r["predictions"]["test"]["probabilities"][0].__setitem__(
        0, float("inf"))), "predictions.test.probabilities[0][0] is Infinity"),
    "newer_format": (_edit(lambda r: r.update(format=9)), "format is 9, newer than the cell record format this "
                                                          "tactile-zoo reads (1)"),
}


@pytest.mark.parametrize("kind", sorted(DAMAGES))
def test_read_record_says_what_is_wrong(kind: str, reference_run: Path, tmp_path: Path) -> None:
    from tactile_zoo.bench.records import InvalidCell, read_record

    source = sorted((reference_run / "cells").glob("*.json"))[0]
    assert isinstance(read_record(source), dict)  # the undamaged record is valid
    path = tmp_path / source.name
    shutil.copy(source, path)
    damage, reason = DAMAGES[kind]
    damage(path)
    result = read_record(path)
    assert isinstance(result, InvalidCell) and reason in result.reason, result


def test_an_empty_split_scores_null_and_only_an_empty_one() -> None:
    """JSON has no NaN: the NaN scores engine.metrics gives an empty split are written null (nan_to_null), which the
    schema accepts for that split only; a null or NaN score of a split with samples is refused."""
    from tactile_zoo.bench.schema import check_record, nan_to_null
    from tactile_zoo.engine.metrics import classification_metrics

    base = {"cell_id": "c", "status": "ok", "model": "m", "dataset": "d", "fold": 0, "seed": 0, "config_hash": "h",
            "epochs_run": 3, "best_epoch": 2, "train_seconds": 1.0}
    empty = nan_to_null(classification_metrics([], [], 3))
    assert empty["accuracy"] is None and empty["n"] == 0
    assert check_record({**base, "metrics": {"test": {"accuracy": 0.5, "n": 4}, "val": empty}}) == []
    assert check_record({**base, "metrics": {"test": {**empty, "n": 4}}}) == [
        "metrics.test.accuracy is null, expected a number between 0 and 1",
        "metrics.test.balanced_accuracy is null, expected a number between 0 and 1",
        "metrics.test.macro_f1 is null, expected a number between 0 and 1"]
    assert nan_to_null({"a": [float("nan"), float("-inf"), 1.5, (2, float("inf"))]}) == {"a": [None, None, 1.5,
                                                                                              [2, None]]}


def test_the_writer_refuses_a_record_the_readers_would_refuse(reference_run: Path, tmp_path: Path) -> None:
    """A NaN (or any record failing the schema) is never written: write_cell raises before the file exists, and
    atomic_write_json refuses a non-finite number wherever it is."""
    from tactile_zoo.bench.rundir import RunDir, atomic_write_json
    from tactile_zoo.bench.schema import InvalidRecordError

    record = json.loads(sorted((reference_run / "cells").glob("*.json"))[0].read_text())
    run = RunDir(tmp_path / "run").prepare()
    bad = {**record, "metrics": {**record["metrics"], "test": {**record["metrics"]["test"], "accuracy": float("nan")}}}
    with pytest.raises(InvalidRecordError, match="metrics.test.accuracy is NaN"):
        run.write_cell(bad)
    with pytest.raises(InvalidRecordError, match="fold is -5"):
        run.write_cell({**record, "fold": -5})
    assert not list(run.cells_dir.iterdir())
    with pytest.raises(ValueError, match="not JSON compliant"):
        atomic_write_json(tmp_path / "x.json", {"curve": [{"val_loss": float("inf")}]})
    assert not (tmp_path / "x.json").exists()
    run.write_cell(record)
    assert json.loads(run.cell_path(record["cell_id"]).read_text()) == record


def test_a_copy_of_a_cell_under_another_name_is_invalid(reference_run: Path, tmp_path: Path) -> None:
    from tactile_zoo.bench.records import scan_cells

    cells = tmp_path / "cells"
    shutil.copytree(reference_run / "cells", cells)
    first = sorted(cells.glob("*.json"))[0]
    shutil.copy(first, cells / "zz_copy.json")
    scan = scan_cells(cells)
    assert len(scan.records) == len(list((reference_run / "cells").glob("*.json")))
    assert [(i.path.name, f"repeats cell_id {first.stem!r}" in i.reason) for i in scan.invalid] == [
        ("zz_copy.json", True)]


def test_every_committed_cell_is_valid() -> None:
    from tactile_zoo.bench.records import cell_files, scan_cells

    folders = sorted({p.parent for p in cell_files(REPO / "benchmarks" / "results", recursive=True)})
    scans = [scan_cells(folder) for folder in folders]
    assert [str(item) for scan in scans for item in scan.invalid] == []
    assert sum(len(scan.records) for scan in scans) >= 276


def _damaged_copy(reference_run: Path, tmp_path: Path, kinds: list[str]) -> tuple[Path, dict[str, Path]]:
    out = tmp_path / "run"
    shutil.copytree(reference_run, out)
    cells = sorted((out / "cells").glob("*.json"))
    damaged = {}
    for kind, path in zip(kinds, cells):
        DAMAGES[kind][0](path)
        damaged[kind] = path
    return out, damaged


def _outputs(out: Path) -> dict[str, bytes]:
    return {name: (out / name).read_bytes() for name in ("leaderboard.csv", "summary.csv", "report.md")}


def test_report_names_every_damaged_cell_and_writes_nothing(reference_run: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    kinds = ["truncated", "empty", "array", "accuracy_high", "no_metrics"]
    out, damaged = _damaged_copy(reference_run, tmp_path, kinds)
    before = _outputs(out)
    assert main(["report", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("tactile-zoo: error: 5 damaged cell file(s)")
    for kind, path in damaged.items():
        assert f"{path}: " in err and DAMAGES[kind][1] in err, kind
    assert _outputs(out) == before  # nothing written


def test_report_skip_invalid_builds_the_tables_without_them_and_says_so(reference_run: Path, tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    out, damaged = _damaged_copy(reference_run, tmp_path, ["truncated", "accuracy_high"])
    assert main(["report", str(out), "--no-plots", "--skip-invalid"]) == 0
    err = capsys.readouterr().err
    assert err.count("tactile-zoo: warning: damaged cell file") == 2 and "Traceback" not in err
    assert all(str(path) in err for path in damaged.values())
    rows = read_board(out)
    assert len(rows) == len(read_board(reference_run)) - 2
    report = (out / "report.md").read_text()
    assert "2 damaged cell file(s) left out" in report and all(p.name in report for p in damaged.values())


def test_bench_moves_damaged_cells_aside_recomputes_them_and_fails(reference_run: Path, tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture) -> None:
    out, damaged = _damaged_copy(reference_run, tmp_path, ["truncated", "accuracy_high"])
    originals = {kind: path.read_bytes() for kind, path in damaged.items()}
    (out / "cells" / "junk.json").write_text("[]")  # not a cell of the grid: named, left where it is
    assert run_cli([*SMALL, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    for path in [*damaged.values(), out / "cells" / "junk.json"]:
        assert f"tactile-zoo: error: damaged cell file {path}: " in captured.err
    for kind, path in damaged.items():
        assert (out / "cells" / "damaged" / path.name).read_bytes() == originals[kind]  # kept, byte for byte
        assert json.loads(path.read_text())["metrics"]["test"]["accuracy"] >= 0  # recomputed
        assert f"moved the damaged cell file {path.name} to" in captured.out
    assert (out / "cells" / "junk.json").read_text() == "[]"
    assert read_board(out) == read_board(reference_run)
    # the grid is whole again; the foreign file is still named, and --skip-invalid makes it a warning
    assert run_cli([*SMALL, "--out", str(out), "--skip-invalid"]) == 0
    err = capsys.readouterr().err
    assert "tactile-zoo: warning: damaged cell file" in err and "junk.json" in err


def test_non_finite_and_out_of_range_cells_are_damaged_for_report_and_bench(reference_run: Path, tmp_path: Path,
                                                                           capsys: pytest.CaptureFixture) -> None:
    """Issue 38: a NaN test accuracy, ``fold: -5`` and a best epoch past the run's end were read as finished cells:
    ``report`` exited 0 with a 95 % interval, and ``bench`` counted them as done. Now each is a damaged cell, named
    with its field and value: report writes nothing (exit 2), bench moves it aside and recomputes it (exit 1)."""
    kinds = ["accuracy_nan", "fold_negative", "best_epoch_huge"]
    out, damaged = _damaged_copy(reference_run, tmp_path, kinds)
    before = _outputs(out)
    assert main(["report", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("tactile-zoo: error: 3 damaged cell file(s)")
    for kind, path in damaged.items():
        assert f"{path}: {DAMAGES[kind][1]}" in err, kind
    assert _outputs(out) == before
    originals = {kind: path.read_bytes() for kind, path in damaged.items()}
    assert run_cli([*SMALL, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert "3 already finished, 3 to run" in captured.out  # the three damaged cells are not counted as finished
    for kind, path in damaged.items():
        assert f"tactile-zoo: error: damaged cell file {path}: {DAMAGES[kind][1]}" in captured.err
        assert (out / "cells" / "damaged" / path.name).read_bytes() == originals[kind]
    assert read_board(out) == read_board(reference_run)


def test_a_record_failing_the_schema_is_written_as_a_failed_cell(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                 capsys: pytest.CaptureFixture) -> None:
    """A cell whose own record breaks the rule (here a NaN accuracy, as a buggy plugin metric could give) is not
    written as finished: it becomes a failed cell naming the field, the grid goes on, and the run exits 1."""
    from tactile_zoo.bench import executors

    real = executors.run_cell

    def nan_accuracy(task: object, **kwargs: object) -> dict:
        record = real(task, **kwargs)
        record["metrics"]["test"]["accuracy"] = float("nan")
        return record

    monkeypatch.setattr(executors, "run_cell", nan_accuracy)
    out = tmp_path / "run"
    one = ["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--seeds", "0", "--threads", "1", "--no-plots"]
    assert run_cli([*one, "--out", str(out)]) == 1
    assert "metrics.test.accuracy is NaN" in capsys.readouterr().out
    [path] = (out / "cells").glob("*.json")
    record = json.loads(path.read_text())  # valid JSON: no NaN literal
    assert record["status"] == "failed" and "metrics" not in record
    assert record["error"].startswith("its ok record is not valid, so it is not kept: metrics.test.accuracy is NaN")


def test_numbers_no_float_can_hold_are_named_not_a_traceback(reference_run: Path, tmp_path: Path) -> None:
    """An integer too large for a float is finite (no crash in the finite check); one too long for Python to read,
    or arrays nested too deep for the parser, make an invalid cell, not a traceback."""
    from tactile_zoo.bench.records import InvalidCell, read_record

    record = json.loads(sorted((reference_run / "cells").glob("*.json"))[0].read_text())
    path = tmp_path / "cell.json"
    path.write_text(json.dumps({**record, "config": {**record["config"], "note": 10 ** 400}, "seconds": 10 ** 400}))
    assert isinstance(read_record(path), dict)
    path.write_text(json.dumps(record).replace('"fold": 0', '"fold": ' + "9" * 5000))
    result = read_record(path)
    assert isinstance(result, InvalidCell) and "cannot be read as a cell record" in result.reason
    path.write_text(json.dumps({**record, "notes": "DEEP"}).replace('"DEEP"', "[" * 100_000 + "]" * 100_000))
    result = read_record(path)
    assert isinstance(result, InvalidCell) and "cannot be read as a cell record" in result.reason


@pytest.mark.parametrize(("part", "bad"), [
    ("targets", True), ("targets", 1.0), ("targets", "1"), ("predictions", False), ("confusion", -1),
    ("confusion", True), ("steps", -2), ("steps", 2.0)])
def test_lists_of_integers_refuse_any_other_item(part: str, bad: object) -> None:
    """The per-sample lists are checked by their items' types at once (fast path): a bool, a float, a string or a
    negative count among plain ints is still refused, and plain ints (int subclasses, one by one) pass."""
    import enum

    from tactile_zoo.bench.schema import check_record

    class Label(enum.IntEnum):
        A = 1

    base = {"cell_id": "c", "status": "ok", "model": "m", "dataset": "d", "fold": 0, "seed": 0, "config_hash": "h",
            "epochs_run": 3, "best_epoch": 2, "train_seconds": 1.0,
            "metrics": {"test": {"accuracy": 0.5, "n": 4, "confusion": [[1, 1], [0, 2]]}},
            "predictions": {"test": {"targets": [0, 1, Label.A, 1], "predictions": [0, 0, 1, 1]}},
            "prefix": {"fractions": [0.5, 1.0], "accuracy": [0.5, 0.75], "steps": [5, 10]}}
    assert check_record(base) == []
    record = json.loads(json.dumps(base))
    where = {"targets": record["predictions"]["test"]["targets"],
             "predictions": record["predictions"]["test"]["predictions"],
             "confusion": record["metrics"]["test"]["confusion"][1], "steps": record["prefix"]["steps"]}[part]
    where[-1] = bad
    assert len(check_record(record)) == 1, check_record(record)
