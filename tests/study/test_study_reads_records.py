"""The study package reads cell files through :mod:`tactile_zoo.bench.records` (and finds them through
``RunDir.cell_path``) only: no module of it spells out where a bench folder keeps its cells."""

from __future__ import annotations

import re
from pathlib import Path

STUDY = Path(__file__).resolve().parents[2] / "tactile_zoo" / "study"
#: a second reader of the records: a path joined to the cells folder, or a folder listed
_LAYOUT = re.compile(r"""/\s*["']cells["/']|CELLS_DIR|\.r?glob\(|\.iterdir\(|os\.listdir|os\.scandir""")


#: a line that lists a folder which is not a bench folder says so (e.g. the packaged published sets)
_NOT_CELLS = "# not a bench folder"


def layout_lines(root: Path) -> list[str]:
    return [f"{path.name}:{n}" for path in sorted(root.rglob("*.py"))
            for n, line in enumerate(path.read_text().splitlines(), 1)
            if _LAYOUT.search(line) and not line.rstrip().endswith(_NOT_CELLS)]


def test_the_study_package_reads_cells_through_the_records_module_only() -> None:
    assert layout_lines(STUDY) == []


def test_a_second_reader_is_found(tmp_path: Path) -> None:
    (tmp_path / "ok.py").write_text("from ..bench.records import run_records\n")
    (tmp_path / "bad.py").write_text("x = 1\npaths = sorted((folder / 'cells').glob('*.json'))\n")
    (tmp_path / "said.py").write_text("names = [p.name for p in package.iterdir()]  # not a bench folder\n")
    assert layout_lines(tmp_path) == ["bad.py:2"]


def test_a_cells_digest_is_the_same_plain_or_compact(tmp_path: Path) -> None:
    """A recorded read names its members by the digest of their bytes; compacting a finished folder keeps each record's
    plain bytes, so it must not make a recorded read look like its members changed."""
    import gzip

    from tactile_zoo.study.reads import cell_digest

    plain = tmp_path / "cells" / "m__d__f0__s0__abc.json"
    plain.parent.mkdir()
    plain.write_bytes(b'{"cell_id": "m__d__f0__s0__abc"}\n')
    compact = tmp_path / "other" / "cells" / "m__d__f0__s0__abc.json.gz"
    compact.parent.mkdir(parents=True)
    compact.write_bytes(gzip.compress(plain.read_bytes()))
    assert cell_digest(compact) == cell_digest(plain)
