"""The ``tactile-zoo`` command line: one module per command family, assembled here.

``main(argv=None) -> int`` so tests call it in-process. Each command is an ``add_*`` function that declares its
arguments and sets its handler; errors tactile-zoo raises on purpose print one line and exit 2 (``--debug`` shows the
traceback).

Everything the package says goes through :mod:`logging` under the ``tactile_zoo`` logger; library code never
configures it, :func:`main` installs one handler for the command's duration: INFO and up by default (progress lines,
warnings, errors), ``-v`` adds DEBUG, ``-q`` keeps warnings and errors only. Warnings users must see (a skipped
plugin, a missing file) are ``warnings.warn`` in the library and shown here as ``tactile-zoo: warning: ...`` at every
verbosity.

A reader that closes the pipe early (``tactile-zoo weights | head -1``) ends any command quietly with status 141, what
a shell reports for a command killed by SIGPIPE. Python ignores SIGPIPE (writes raise BrokenPipeError), and it stays
ignored: restoring the default action would also kill a bench process whose worker connection drops.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from .. import registry
from .._env import check_environment
from .._version import __version__
from ..errors import TactileZooError
from .bench import add_bench, add_rebuild_weights, add_report
from .catalog import add_info, add_list, add_plugins
from .download import add_download
from .export import add_export
from .stream import add_stream
from .study import add_study
from .train import add_evaluate, add_train
from .weights import add_predict, add_weights

__all__ = ["main", "entry", "build_parser", "SUBCOMMANDS"]

#: Every subcommand's argument declaration, in help order.
SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    add_list, add_info, add_plugins, add_download, add_bench, add_train, add_evaluate, add_report, add_stream,
    add_weights, add_predict, add_export, add_study, add_rebuild_weights,
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tactile-zoo", description="Tactile recognition model zoo and benchmark.")
    parser.add_argument("--version", action="version", version=f"tactile-zoo {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("--strict-plugins", action="store_true", help="a plugin that fails to load is an error")
    parser.add_argument("--no-plugins", action="store_true", help="do not discover entry-point plugins")
    loud = parser.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", dest="log_verbose", action="count", default=0,
                      help="more diagnostics (debug log lines)")
    loud.add_argument("-q", "--quiet", dest="log_quiet", action="store_true",
                      help="only warnings and errors on stderr (before the command; `bench -q` also hides progress)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in SUBCOMMANDS:
        add(sub)
    return parser


logger = logging.getLogger("tactile_zoo")


class _StderrHandler(logging.Handler):
    """Lines on the *current* ``sys.stderr`` (tests swap it), through ``tqdm.write`` so that live bars survive."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record)
            from tqdm import tqdm

            tqdm.write(text, file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never break the command
            self.handleError(record)


class _Formatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.exc_info and record.levelno >= logging.ERROR:
            text += "\n" + self.formatException(record.exc_info)
        if record.levelno == logging.INFO:
            return text
        return f"tactile-zoo: {text}" if getattr(record, "bare", False) else \
            f"tactile-zoo: {record.levelname.lower()}: {text}"


def _install_logging(verbose: int, quiet: bool) -> tuple[logging.Handler, int, bool]:
    handler = _StderrHandler()
    handler.setFormatter(_Formatter())
    previous = (logger.level, logger.propagate)
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    logger.propagate = False  # the command owns stderr: no second copy through a root handler
    return handler, *previous


def _show_warning(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
    logging.getLogger("tactile_zoo.warnings").warning("%s", message)


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
    handler, level, propagate = _install_logging(args.log_verbose, args.log_quiet)
    registry.set_plugin_policy(strict=True if args.strict_plugins else None,
                               enabled=False if args.no_plugins else None)
    from ..engine.runtime import flush_denormals

    try:
        check_environment()  # a boolean variable set to "banana" stops every command here, before any work
        # before torch starts its thread pool, so that every thread it starts inherits flush-to-zero
        with warnings.catch_warnings(), flush_denormals():
            warnings.simplefilter("always", registry.PluginWarning)
            warnings.showwarning = _show_warning
            return int(args.handler(args) or 0)
    except TactileZooError as exc:
        if args.debug:
            raise
        logger.error("%s", exc)
        return 2
    except KeyboardInterrupt:
        logger.error("interrupted", extra={"bare": True})
        return 130
    except BrokenPipeError:
        # the reader went away (`tactile-zoo weights | head -1`): stop quietly, as a command killed by SIGPIPE does
        _silence_stdout()
        return 128 + signal.SIGPIPE
    finally:
        registry.set_plugin_policy()
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's final flush of what is still buffered for the closed pipe
    does not print a second BrokenPipeError at exit."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a replaced sys.stdout (tests) has no descriptor to redirect
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


def entry() -> None:  # console script
    sys.exit(main())




