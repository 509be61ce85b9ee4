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
        path.write_text(json.dumps(record))
    return apply


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated": (_truncate, "not valid JSON"),
    "empty": (_empty, "empty file"),
    "array": (_array, "holds an array"),
    "accuracy_high": (_edit(lambda r: r["metrics"]["test"].update(accuracy="high")),
                      'metrics.test.accuracy is "high", expected a number between 0 and 1'),
    "no_metrics": (_edit(lambda r: r.pop("metrics")), "no 'metrics'"),
    "fold_text": (_edit(lambda r: r.update(fold="0")), 'fold is "0", expected an integer'),
    "accuracy_above_one": (_edit(lambda r: r["metrics"]["test"].update(accuracy=1.5)), "metrics.test.accuracy"),
    "predictions_mismatch": (_edit(lambda r: r["predictions"]["test"]["targets"].pop()), "predictions.test"),
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
    from tactile_zoo.bench.records import scan_cells

    folders = sorted({p.parent for p in (REPO / "benchmarks" / "results").rglob("cells/*.json")})
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
