"""Each job exists once (issue 51): the one-CPU-type check (:func:`tactile_zoo.study.audit.cpu_type_clash`), the
generated-page blocks (:mod:`tactile_zoo._files`: ``replace_block``, ``stale_files``, ``update_pages``) and a
study's results folder (named through its study, :func:`tactile_zoo.study.publish.study_folder`). A copy typed
again in the package or the tools fails here, naming its file and line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tactile_zoo._files import replace_block, stale_files
from tactile_zoo.study.publish import study_files
from tactile_zoo.study.schema import parse_study

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
SOURCES = sorted([*(REPO / "tactile_zoo").rglob("*.py"), *(REPO / "tools").rglob("*.py")])

#: what each copy looks like -> the one file allowed to hold it
HOMES = {
    # reading a cell's CPU type, or writing the clash's "N CPU types (A; B)"
    r"""(\.get\(|\[)["']cpu_isa["']""": "tactile_zoo/study/audit.py",
    r"CPU types \(": "tactile_zoo/study/audit.py",
    # cutting a page at a block's end marker, or naming a stale page
    r"\.split\(\s*(end|END)\b": "tactile_zoo/_files.py",
    r"is out of date: run": "tactile_zoo/_files.py",
}


def _lines(path: Path) -> list[tuple[int, str]]:
    return list(enumerate(path.read_text(encoding="utf-8").splitlines(), 1))


def test_each_job_is_written_in_one_file() -> None:
    copies = [f"{path.relative_to(REPO)}:{n}: {line.strip()} (its home: {home})"
              for pattern, home in HOMES.items() for path in SOURCES if path.relative_to(REPO).as_posix() != home
              for n, line in _lines(path) if re.search(pattern, line)]
    assert not copies, "\n".join(copies)


def test_no_tool_types_a_studys_results_folder() -> None:
    """``RESULTS / "<folder>"`` for a folder a study holds is spelt through the study instead; folders no study
    holds (the tuning trials' parent, a released model's CSV, ConvLSTM's BioTac-DoS setups) may be named."""
    studies = [parse_study(path) for path in study_files(REPO / "benchmarks" / "studies")]
    folders = {study.folder(grid).resolve().relative_to(RESULTS.resolve()).as_posix()
               for study in studies for grid in study.grids()}
    literal = re.compile(r'RESULTS((?:\s*/\s*"[^"]+")+)')
    typed = [f"{path.relative_to(REPO)}:{n}: {line.strip()} (study folder {name})"
             for path in SOURCES for n, line in _lines(path) for found in literal.finditer(line)
             if (name := "/".join(re.findall(r'"([^"]+)"', found.group(1)))) in folders]
    assert not typed, "\n".join(typed)


def test_a_generated_block_needs_its_markers_once_each_in_order(tmp_path: Path) -> None:
    begin, end = "<!-- t: begin (gen) -->", "<!-- t: end -->"
    page = tmp_path / "page.md"
    assert replace_block(f"a\n{begin}\nold\n{end}\nb\n", begin, end, "new", page) == f"a\n{begin}\nnew\n{end}\nb\n"
    for text in (f"{begin}\n{end}\n{begin}\n{end}\n", f"{end}\n{begin}\n", f"{begin}\n"):
        with pytest.raises(ValueError, match=f"{page} must hold the markers"):
            replace_block(text, begin, end, "new", page)
    page.write_text("old")
    assert stale_files({page: "old", tmp_path / "missing.md": "x"}) == [tmp_path / "missing.md"]
    assert stale_files({page: "new"}, write=True) == [page] and page.read_text() == "new"
