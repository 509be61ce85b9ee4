"""The ``tactile-zoo`` command line.

``main(argv=None) -> int`` so tests call it in-process. Every subcommand is one ``_cmd_*`` function plus one
``_add_*`` function that declares its arguments; errors tactile-zoo raises on purpose print one line and exit 2
(``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from . import registry
from .errors import TactileZooError

__all__ = ["main", "entry", "build_parser"]

Handler = Callable[[argparse.Namespace], int]


def _print(*args: Any) -> None:
    print(*args, flush=True)


# ----------------------------------------------------------------------------------------------- list / info / plugins
def _add_list(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered models, datasets or sensors")
    p.add_argument("what", choices=["models", "datasets", "sensors"])
    p.add_argument("pattern", nargs="?", default="*", help="fnmatch pattern, e.g. '*tacformer'")
    p.add_argument("--tags", default=None, help="comma-separated tags every listed model must have")
    p.set_defaults(handler=_cmd_list)


def _cmd_list(args: argparse.Namespace) -> int:
    tags = [t for t in (args.tags or "").split(",") if t]
    if args.what == "models":
        for name in registry.list_models(args.pattern, tags=tags):
            meta = registry.get_model_entry(name).meta
            _print(f"{name:<24} {', '.join(meta.get('tags', ())):<36} {meta.get('paper', '')}")
    elif args.what == "datasets":
        for name in registry.list_datasets(args.pattern, tags=tags):
            meta = registry.get_dataset_entry(name).meta
            _print(f"{name:<24} {meta.get('sensor', ''):<14} {meta.get('num_classes', ''):>4} classes  "
                   f"{meta.get('description', '')}")
    else:
        for name in registry.list_sensors(args.pattern):
            sensor = registry.get_sensor(name)
            _print(f"{name:<16} {sensor.num_nodes:>4} taxels  grid {sensor.grid_shape[0]}x{sensor.grid_shape[1]}  "
                   f"{sensor.description}")
    return 0


def _add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="metadata of a model, dataset or sensor (a model's parameter count too)")
    p.add_argument("name")
    p.add_argument("--root", default=None, help="data home (for a dataset's spec)")
    p.add_argument("--dataset", default=None, help="dataset whose spec a model is built for (default: first "
                                                   "simulated one)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_cmd_info)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict) or hasattr(value, "items"):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_jsonable(v) for v in value]
    return value if isinstance(value, str | int | float | bool | type(None)) else str(value)


def _model_info(name: str, args: argparse.Namespace) -> dict[str, Any]:
    entry = registry.get_model_entry(name)
    info: dict[str, Any] = {"kind": "model", "name": entry.qualified_name, **_jsonable(dict(entry.meta))}
    ds_name = args.dataset or next(iter(registry.list_datasets("sim_*")), None)
    if ds_name is not None:
        ds = registry.load_dataset(ds_name, root=args.root, split="train")
        model = registry.create_model(name, ds.spec)
        info["built_for"] = ds.spec.name
        info["parameters"] = sum(p.numel() for p in model.parameters())
    return info


def _dataset_info(name: str, args: argparse.Namespace) -> dict[str, Any]:
    entry = registry.get_dataset_entry(name)
    info: dict[str, Any] = {"kind": "dataset", "name": entry.qualified_name, **_jsonable(dict(entry.meta))}
    ds = registry.load_dataset(name, root=args.root, split=None)
    info["spec"] = ds.spec.to_dict()
    info["num_folds"] = ds.num_folds
    info["samples"] = len(ds)
    counts: dict[str, int] = {}
    for split in ("train", "val", "test", *getattr(ds, "extra_splits", ())):
        counts[split] = len(registry.load_dataset(name, root=args.root, split=split))
    info["split_sizes_fold0"] = counts
    return info


def _cmd_info(args: argparse.Namespace) -> int:
    kinds = []
    for kind, lookup in (("model", registry.get_model_entry), ("dataset", registry.get_dataset_entry),
                         ("sensor", registry.get_sensor)):
        try:
            lookup(args.name)
            kinds.append(kind)
        except registry.UnknownNameError:
            pass
    if not kinds:
        registry.get_model_entry(args.name)  # raises the error with suggestions
    if kinds[0] == "model":
        info = _model_info(args.name, args)
    elif kinds[0] == "dataset":
        info = _dataset_info(args.name, args)
    else:
        sensor = registry.get_sensor(args.name)
        info = {"kind": "sensor", "name": sensor.name, "taxels": sensor.num_nodes, "grid_shape": sensor.grid_shape,
                "default_graph": sensor.default_graph, "edges": int(sensor.edge_index().shape[1]) // 2,
                "channels": sensor.channels, "description": sensor.description}
    if args.json:
        _print(json.dumps(_jsonable(info), indent=2))
    else:
        width = max(len(k) for k in info)
        for key, value in info.items():
            _print(f"{key:<{width}}  {json.dumps(_jsonable(value)) if not isinstance(value, str) else value}")
    return 0


def _add_plugins(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="discovered plugin distributions and their status")
    p.set_defaults(handler=_cmd_plugins)


def _cmd_plugins(args: argparse.Namespace) -> int:
    found = registry.plugins()
    if not found:
        _print("no tactile-zoo plugins installed" + (" (discovery disabled)" if not registry._enabled() else ""))
        return 0
    for info in found:
        line = f"{info.dist} {info.version:<8} {info.group:<22} {info.name} = {info.value}  [{info.status}]"
        _print(line + (f"  {info.error}" if info.error else ""))
    return 1 if any(i.status == "failed" for i in found) and registry._strict() else 0


# ----------------------------------------------------------------------------------------------- parser and main
#: Every subcommand's argument declaration, in help order. Later subcommands append themselves here.
SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [_add_list, _add_info, _add_plugins]


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

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
    registry.set_plugin_policy(strict=True if args.strict_plugins else None,
                               enabled=False if args.no_plugins else None)
    try:
        with warnings.catch_warnings():
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
