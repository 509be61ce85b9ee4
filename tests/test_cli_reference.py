"""docs/cli.md is what the ``tactile-zoo`` parsers give (``python -m tools.cli_reference`` rewrites it; issue 39): every
command and every flag, with its default, choices and help, and a parser change makes the committed page stale."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tactile_zoo.cli import build_parser  # noqa: E402
from tools import cli_reference  # noqa: E402

PAGE = REPO / "docs" / "cli.md"


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _section(text: str, command: str) -> str:
    return text.split(f"\n## tactile-zoo {command}\n", 1)[1].split("\n## ", 1)[0]


def test_the_committed_page_is_what_the_parsers_give() -> None:
    assert cli_reference.main(["--check"]) == 0, "run python -m tools.cli_reference and commit docs/cli.md"


def test_every_command_and_option_is_on_the_page_with_its_facts() -> None:
    """Read against the parsers, not against the renderer: a renderer that dropped a flag, a default or a choice
    would still agree with itself."""
    text = PAGE.read_text()
    commands = _commands(build_parser())
    assert {"bench", "train", "evaluate", "report", "predict", "export", "stream"} <= set(commands)
    for name, parser in commands.items():
        assert f"- [`{name}`](#tactile-zoo-{name}): " in text, f"{name} is not in the page's list of commands"
        assert f"\n## tactile-zoo {name}\n" in text, f"{name} has no section"
        section = _section(text, name)
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            first = (action.option_strings or [action.metavar or action.dest])[0]
            line = next((ln for ln in section.splitlines() if re.match(rf"- `{re.escape(first)}[` ]", ln)), None)
            assert line, f"{name} {action.option_strings or action.dest} is not on docs/cli.md"
            for choice in action.choices or []:
                assert f"`{choice}`" in line, (name, action.dest, choice)
            if action.help:
                assert " ".join(action.help.split())[:40] in line.replace("\\", "").replace("&lt;", "<"), line
            if isinstance(action.default, (int, str)) and not isinstance(action.default, bool) and action.nargs != 0:
                assert f"default: `{action.default}`" in line, line
    bench = [ln for ln in _section(text, "bench").splitlines() if ln.startswith("- `-")]
    flags = [a for a in commands["bench"]._actions if a.option_strings and not isinstance(a, argparse._HelpAction)]
    assert len(bench) == len(flags) >= 30, f"bench lists {len(bench)} flags of {len(flags)}"
    # the global options, and the mutually exclusive pairs said as such
    assert "- `--debug`: show tracebacks" in text and "- `--resume` (not with `--force`)" in _section(text, "bench")


def _planted(change) -> argparse.ArgumentParser:
    parser = build_parser()
    change(_commands(parser))
    return parser


@pytest.mark.parametrize("change", [
    lambda c: c["bench"].add_argument("--planted-flag", help="a flag nobody documented"),
    lambda c: next(a for a in c["predict"]._actions if a.dest == "top_k").__setattr__("default", 5),
    lambda c: next(a for a in c["bench"]._actions if a.dest == "executor").__setattr__("choices", ["local", "ray"]),
    lambda c: next(a for a in c["report"]._actions if a.dest == "running").__setattr__("help", "changed"),
    lambda c: next(a for a in c["export"]._actions if a.dest == "out").__setattr__("option_strings", ["--output"]),
], ids=["new flag", "default", "choices", "help", "renamed flag"])
def test_a_parser_change_makes_the_page_stale(change, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "cli.md"
    page.write_text(PAGE.read_text())
    assert cli_reference.main(["--check", "--page", str(page)]) == 0
    assert cli_reference.main(["--check", "--page", str(page)], parser_factory=lambda: _planted(change)) == 1
    assert "run python -m tools.cli_reference" in capsys.readouterr().err
    # regenerating is the one command the development page names, and it makes the check pass again
    assert cli_reference.main(["--page", str(page)], parser_factory=lambda: _planted(change)) == 0
    assert cli_reference.main(["--check", "--page", str(page)], parser_factory=lambda: _planted(change)) == 0


def test_the_page_does_not_depend_on_the_terminal_width(monkeypatch: pytest.MonkeyPatch) -> None:
    pages = set()
    for columns in ("40", "300"):
        monkeypatch.setenv("COLUMNS", columns)
        pages.add(cli_reference.render(build_parser()))
    assert len(pages) == 1


def test_help_text_is_escaped_for_markdown_outside_code() -> None:
    assert cli_reference._escape("e.g. '*tacformer' to OUT/<cell id>.pt, see `a_b*`") == \
        "e.g. '\\*tacformer' to OUT/&lt;cell id>.pt, see `a_b*`"
