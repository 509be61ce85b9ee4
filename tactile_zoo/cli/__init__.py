"""The ``tactile-zoo`` command line: one module per command family, assembled here.

``main(argv=None) -> int`` so tests call it in-process. Each command is an ``add_*`` function that declares its
arguments and sets its handler; errors tactile-zoo raises on purpose print one line and exit 2 (``--debug`` shows the
traceback).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from .. import registry
from .._version import __version__
from ..errors import TactileZooError
from .bench import add_bench, add_report
from .catalog import add_info, add_list, add_plugins
from .download import add_download
from .stream import add_stream
from .train import add_evaluate, add_train

__all__ = ["main", "entry", "build_parser", "SUBCOMMANDS"]

#: Every subcommand's argument declaration, in help order.
SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    add_list, add_info, add_plugins, add_download, add_bench, add_train, add_evaluate, add_report, add_stream,
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tactile-zoo", description="Tactile recognition model zoo and benchmark.")
    parser.add_argument("--version", action="version", version=f"tactile-zoo {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("--strict-plugins", action="store_true", help="a plugin that fails to load is an error")
    parser.add_argument("--no-plugins", action="store_true", help="do not discover entry-point plugins")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in SUBCOMMANDS:
        add(sub)
    return parser


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    print(f"tactile-zoo: warning: {message}", file=sys.stderr)


class _ArgumentError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        raise _ArgumentError(message)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 some work failed, 2 bad input or error)."""
    parser = build_parser()
    parser.__class__ = _Parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action.choices.values():
                choice.__class__ = _Parser
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except _ArgumentError as exc:
        print(f"tactile-zoo: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help and --version: main() returns its code instead of exiting the caller
        return exc.code if isinstance(exc.code, int) else 0
    registry.set_plugin_policy(strict=True if args.strict_plugins else None,
                               enabled=False if args.no_plugins else None)
    from ..engine.runtime import flush_denormals

    try:
        # before torch starts its thread pool, so that every thread it starts inherits flush-to-zero
        with warnings.catch_warnings(), flush_denormals():
            warnings.simplefilter("always", registry.PluginWarning)
            warnings.showwarning = _show_warning
            return int(args.handler(args) or 0)
    except TactileZooError as exc:
        if args.debug:
            raise
        print(f"tactile-zoo: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("tactile-zoo: interrupted", file=sys.stderr)
        return 130
    finally:
        registry.set_plugin_policy()


def entry() -> None:  # console script
    sys.exit(main())




