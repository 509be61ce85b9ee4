"""CHANGELOG.md keeps the Keep a Changelog 1.1.0 form (issue 39): versions newest first with their dates, only the six
kinds of change, and an entry is a line or two (at most three) that links the docs page holding the detail; its links
are docs pages, which the site's copy (docs/changelog.md, docs/hooks/changelog.py) can follow."""

from __future__ import annotations

import re
from pathlib import Path

from packaging.version import Version

from tactile_zoo import __version__

REPO = Path(__file__).resolve().parents[1]
CHANGELOG = REPO / "CHANGELOG.md"
KINDS = ["Added", "Changed", "Deprecated", "Removed", "Fixed", "Security"]
#: the most lines one entry may take: "a line or two", three for the odd list of figures
MAX_ENTRY_LINES = 3
MAX_LINE = 120
RELEASE = re.compile(r"^## \[(\d+\.\d+\.\d+)\] - (\d{4}-\d{2}-\d{2})$")


def changelog_problems(text: str, root: Path = REPO) -> list[str]:  # noqa: C901 - one rule per line kind
    """Everything in ``text`` that breaks the form; empty when it keeps it."""
    problems, versions, kinds, entry = [], [], [], 0
    lines = text.splitlines()
    if not lines or lines[0] != "# Changelog" or "keepachangelog.com/en/1.1.0" not in text:
        problems.append("the title and the Keep a Changelog 1.1.0 statement come first")
    for number, line in enumerate(lines, 1):
        where = f"line {number}"
        if len(line) > MAX_LINE:
            problems.append(f"{where}: {len(line)} characters (at most {MAX_LINE})")
        if line.startswith("## "):
            release = RELEASE.match(line)
            if line != "## [Unreleased]" and not release:
                problems.append(f"{where}: a version heading is '## [Unreleased]' or '## [X.Y.Z] - YYYY-MM-DD'")
            if line == "## [Unreleased]" and versions:
                problems.append(f"{where}: [Unreleased] comes first")
            versions.append(release.groups() if release else None)
            kinds = []
        elif line.startswith("### "):
            kind = line[4:]
            if kind not in KINDS:
                problems.append(f"{where}: '{kind}' is not one of {', '.join(KINDS)}")
                continue
            if kind in kinds or any(KINDS.index(k) > KINDS.index(kind) for k in kinds):
                problems.append(f"{where}: '{kind}' repeated or out of order ({', '.join(KINDS)})")
            kinds.append(kind)
        elif line.startswith("- "):
            if not kinds:
                problems.append(f"{where}: an entry outside a kind of change")
            entry = 1
        elif line.startswith("  ") and entry:
            if line.lstrip().startswith(("- ", "* ")):
                problems.append(f"{where}: a nested list; make it entries of their own")
            entry += 1
            if entry == MAX_ENTRY_LINES + 1:
                problems.append(f"{where}: an entry over {MAX_ENTRY_LINES} lines; link the docs page for the detail")
        elif not line.strip():
            entry = 0
        elif versions and not re.match(r"^\[[^\]]+\]: \S+$", line):  # link references may close the file
            problems.append(f"{where}: prose; a change is a '- ' entry under its kind")
    released = [v for v in versions if v]
    if [Version(v) for v, _ in released] != sorted((Version(v) for v, _ in released), reverse=True) or \
            [d for _, d in released] != sorted((d for _, d in released), reverse=True):
        problems.append("versions and their dates run newest first")
    if __version__ not in {v for v, _ in released}:
        problems.append(f"no section for the package's version {__version__}")
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"https?://", target):
            continue
        path = target.partition("#")[0]
        if not (path.startswith("docs/") and path.endswith(".md") and (root / path).is_file()):
            problems.append(f"a link to {target}: the changelog links docs pages (docs/NAME.md) that exist")
    return problems


def test_the_changelog_keeps_its_form() -> None:
    assert changelog_problems(CHANGELOG.read_text()) == []


def test_a_planted_mistake_of_each_kind_is_found() -> None:
    good = CHANGELOG.read_text()
    head, _, tail = good.partition("### Added\n")
    planted = {
        "an entry over 3 lines": head + "### Added\n- one\n  two\n  three\n  four\n" + tail,
        "'Improved' is not one of": head + "### Improved\n- a change\n\n### Added\n" + tail,
        "repeated or out of order": good.replace("### Changed", "### Fixed\n- a fix\n\n### Changed", 1),
        "a nested list": head + "### Added\n- one\n  - two\n" + tail,
        "prose;": head + "### Added\nA paragraph about the release.\n\n" + tail,
        "newest first": good.replace("## [0.2.0] - 2026-12-03", "## [0.1.0] - 2026-12-01\n\n### Added\n- x\n\n"
                                     "## [0.2.0] - 2026-12-03", 1),
        "a link to benchmarks/results/README.md": good + "\n[x](benchmarks/results/README.md)\n",
        "a link to docs/no-such-page.md": good + "\n[x](docs/no-such-page.md)\n",
        "characters (at most 120)": head + "### Added\n- " + "x" * 130 + "\n" + tail,
        "a version heading is": good.replace("## [0.2.0] - 2026-12-03", "## 0.2.0 (December 2026)", 1),
    }
    for message, text in planted.items():
        problems = changelog_problems(text)
        assert any(message in p for p in problems), (message, problems)
