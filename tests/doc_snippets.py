"""What tests/test_doc_snippets.py runs: every fenced block and command code span of README.md and docs/ (not
docs/pending/), split into what each line asks for.

A block says how it is exercised by its language and, where that is not enough, by an HTML comment on the line
before its fence, ``<!-- snippet: DIRECTIVE; DIRECTIVE ... -->`` (invisible on the site and on the index page):

- ``python`` blocks run as written, ``bash`` blocks line by line (see :func:`shell_commands`); ``toml`` and
  ``bibtex`` blocks are checked against the package (entry-point groups, version), ``yaml`` blocks are recipe files
  (read with ``tactile_zoo.registry.read_recipe_file``, which validates them);
- ``output``: a transcript: its ``$ `` lines are commands, run like a bash block's; the rest is not checked;
- ``diagram``: an architecture sketch, nothing to run;
- ``installed ./plugins/NAME``: the block needs that distribution installed, as the page says in prose;
- ``files NAME ...``: fixture files (:data:`FIXTURES`) written into the working folder before the block runs, for
  the placeholders a snippet reads (``grasp.csv``); the snippet itself is never rewritten;
- ``resolve SUBCOMMAND ...``: those ``tactile-zoo`` commands take minutes to hours: ``bench`` runs with ``--dry-run``,
  the others are parsed by the CLI's parser and their model, dataset and weights names looked up;
- ``not-run PROGRAM REASON``: lines of that program (a server, another tool) are not run;
- ``compile REASON``: a Python block that needs what CI has not (a cluster) is compiled, not run;
- ``xfail REASON``: the block fails until the named issue item is fixed.

A block without a directive in a language the harness does not run fails the suite, so a new block is covered or
says why not. A command line holding a placeholder (an upper-case word such as ``OUT``, ``CELL``, ``MODEL``) is
resolved, not run; ``DATA``, ``DIR`` and ``../shared/data`` stand for the real data home, which is substituted where
it is present.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DIRECTIVES = {"output", "diagram", "files", "installed", "resolve", "not-run", "compile", "xfail"}
#: languages run or checked without a directive
KNOWN_LANGS = {"python", "bash", "toml", "bibtex", "yaml"}
#: placeholders for the data home (quick start: ``--root DATA``; Datasets: ``DIR``; Table I: ``../shared/data``)
DATA_PLACEHOLDERS = ("DATA", "DIR", "../shared/data")
#: the two ``make`` commands CI's fresh clone runs (issue 38: exempt)
EXEMPT_MAKE = {"bench", "test"}
_PLACEHOLDER = re.compile(r"(?<![A-Za-z_])(?!DATA\b|DIR\b)[A-Z]{2,}(?![a-z_])")


@dataclass
class Block:
    """One fenced block: where it is, its language, its text and its directives."""

    path: Path
    line: int
    lang: str
    body: str
    directives: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        where = self.path.relative_to(REPO) if self.path.is_relative_to(REPO) else self.path
        return f"{where}:{self.line}"


def doc_files(root: Path = REPO) -> list[Path]:
    """README.md and every page under docs/ except the notes in docs/pending/."""
    return [root / "README.md"] + sorted(p for p in (root / "docs").rglob("*.md") if "pending" not in p.parts)


def parse_directives(comment: str, where: str) -> dict[str, str]:
    """``output; files grasp.csv`` -> ``{"output": "", "files": "grasp.csv"}``; an unknown directive is an error."""
    found = {}
    for item in filter(None, (part.strip() for part in comment.split(";"))):
        key, _, value = item.partition(" ")
        if key not in DIRECTIVES:
            raise ValueError(f"{where}: unknown snippet directive {key!r} (known: {', '.join(sorted(DIRECTIVES))})")
        found[key] = value.strip()
    return found


def extract_blocks(path: Path, text: str | None = None) -> list[Block]:
    """Every fenced block of ``path`` with the directives of the comment just before it (blank lines between
    allowed)."""
    lines = (path.read_text() if text is None else text).splitlines()
    blocks, i = [], 0
    while i < len(lines):
        match = re.match(r"^\s*(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        if not match:
            i += 1
            continue
        fence, start = match.group(1), i
        j = i - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        comment = re.match(r"^\s*<!--\s*snippet:(.*?)-->\s*$", lines[j]) if j >= 0 else None
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            i += 1
        if i == len(lines):
            raise ValueError(f"{path}:{start + 1}: the fence is never closed")
        where = f"{path}:{start + 1}"
        blocks.append(Block(path, start + 1, match.group(2).lower(), "\n".join(lines[start + 1:i]),
                            parse_directives(comment.group(1), where) if comment else {}))
        i += 1
    return blocks


def code_spans(text: str) -> list[str]:
    """The inline code spans outside fenced blocks, whitespace (line breaks) collapsed."""
    prose = re.sub(r"^\s*(`{3,}|~{3,}).*?^\s*\1\s*$", "", text, flags=re.S | re.M)
    return [" ".join(span.split()) for span in re.findall(r"(?<!`)`([^`]+)`(?!`)", prose)]


def command_spans(text: str) -> list[str]:
    """The spans that are commands: ``tactile-zoo ...``, ``python -m ...``, ``pip install ...``, ``make ...`` (a
    leading ``VAR=value`` and anything after a pipe dropped)."""
    out = []
    for span in code_spans(text):
        span = re.sub(r"^(\w+=\S+\s+)+", "", span).split("|")[0].strip()
        if re.match(r"(tactile-zoo(\s|$)|python -m |pip install |make )", span):
            out.append(span)
    return out


def shell_commands(body: str, prompt: bool = False) -> list[list[str]]:
    """The commands of a shell block as argument lists: continuation lines joined, comments dropped, ``a && b`` as
    two commands; with ``prompt``, only the ``$ `` lines of a transcript."""
    joined, current = [], ""
    for line in body.splitlines():
        if prompt:
            if not line.startswith("$ "):
                continue
            line = line[2:]
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        joined.append(current)
        current = ""
    commands = []
    for line in joined:
        words = shlex.split(line, comments=True)
        while words:
            cut = words.index("&&") if "&&" in words else len(words)
            commands.append(words[:cut])
            words = words[cut + 1:]
    return [c for c in commands if c]


def has_placeholder(argv: list[str]) -> bool:
    """A word such as ``OUT``, ``CELL`` or ``MODEL`` in the command: it cannot run as written."""
    return any(_PLACEHOLDER.search(word) for word in argv[1:])


def substitute_data(argv: list[str], data: Path | None) -> list[str] | None:
    """``argv`` with the data-home placeholders replaced by ``data``; None when it needs data and there is none."""
    if not any(w in DATA_PLACEHOLDERS for w in argv):
        return argv
    if data is None:
        return None
    return [str(data) if w in DATA_PLACEHOLDERS else w for w in argv]


def pip_problems(argv: list[str], extras: set[str], third_party: set[str]) -> list[str]:
    """What is wrong with a documented ``pip install`` line: each target must install offline from a clone or a
    built wheel (``.``, ``.[extra]``, ``./plugins/<folder>``, a ``.whl`` path), or be a third-party requirement the
    project itself names (``third_party``: pyproject's dependencies and extras, the Makefile's pins)."""
    problems = []
    targets = [w for w in argv[2:] if not w.startswith("-")]
    if not targets:
        problems.append(f"{shlex.join(argv)}: names nothing to install")
    for target in targets:
        local = re.fullmatch(r"(\.|\./plugins/[\w.-]+)(\[([\w,-]+)\])?", target)
        if local:
            if local.group(1) != "." and not (REPO / local.group(1)).is_dir():
                problems.append(f"{target}: no such folder in the clone")
            unknown = set((local.group(3) or "").split(",")) - extras - {""}
            if unknown and local.group(1) == ".":
                problems.append(f"{target}: no extra {sorted(unknown)} in pyproject.toml")
        elif target.endswith(".whl"):
            continue
        else:
            name = re.split(r"[\[<>=!~; ]", target, maxsplit=1)[0].lower().replace("_", "-")
            if name.startswith("tactile-zoo") or name not in third_party:
                problems.append(f"{target}: not installable offline from a clone or a built wheel (tactile-zoo is "
                                f"not on the index: use ., .[extra], ./plugins/<folder> or a wheel path)")
    return problems


# ----------------------------------------------------------------------------------------------- fixture files
def _recording(steps: int = 250, columns: int = 78, seed: int = 0) -> np.ndarray:
    """One Ev-Objects grasp in the recordings format: 250 steps x (39 taxels x 2 polarities) event counts."""
    return np.random.default_rng(seed).poisson(0.05, size=(steps, columns)).astype(np.float32)


def _write_csv(path: Path, table: np.ndarray) -> None:
    path.write_text("\n".join(",".join(f"{v:g}" for v in row) for row in table) + "\n")


def _my_grasps(cwd: Path) -> None:
    """``DIR/my_grasps/raw/<class>/<trial>.csv``: 3 classes x 5 trials of 20 BioTac SP readings (24 columns)."""
    for c in range(3):
        folder = cwd / "DIR" / "my_grasps" / "raw" / f"class_{c}"
        folder.mkdir(parents=True)
        for t in range(5):
            _write_csv(folder / f"trial_{t}.csv", _recording(20, 24, seed=10 * c + t) + c)


def _biotac_recording(cwd: Path) -> None:
    """``bottle12.csv`` in BioTac-DoS's release format: a header ``ff_e1..ff_e24``, then 275 rows of 24 integer
    electrode readings."""
    rows = np.random.default_rng(4).integers(2200, 3400, size=(275, 24))
    header = ",".join(f"ff_e{i}" for i in range(1, 25))
    (cwd / "bottle12.csv").write_text(header + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")


FIXTURES = {
    "grasp.csv": lambda cwd: _write_csv(cwd / "grasp.csv", _recording()),
    "grasp1.csv": lambda cwd: _write_csv(cwd / "grasp1.csv", _recording(seed=1)),
    "grasp.npy": lambda cwd: np.save(cwd / "grasp.npy", _recording(seed=2)),
    "grasp2.npy": lambda cwd: np.save(cwd / "grasp2.npy", _recording(seed=3)),
    "DIR/my_grasps": _my_grasps,
    "bottle12.csv": _biotac_recording,
}
