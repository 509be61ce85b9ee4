"""``tactile-zoo list``, ``info`` and ``plugins``: what the registry holds."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from .. import registry
from ._common import echo

__all__ = ["add_list", "add_info", "add_plugins"]


def add_list(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered models, datasets or sensors")
    p.add_argument("what", choices=["models", "datasets", "sensors"])
    p.add_argument("pattern", nargs="?", default="*", help="fnmatch pattern, e.g. '*tacformer'")
    p.add_argument("--tags", default=None, help="comma-separated tags every listed model must have")
    p.set_defaults(handler=_cmd_list)


def _cmd_list(args: argparse.Namespace) -> int:
    tags = [t for t in (args.tags or "").split(",") if t]
    lister = {"models": registry.model_names, "datasets": registry.list_datasets}.get(args.what)
    if not (lister(args.pattern, tags=tags) if lister else registry.list_sensors(args.pattern)):
        print(f"tactile-zoo: no {args.what} match {args.pattern!r}" + (f" with tags {tags}" if tags else ""),
              file=sys.stderr)
        return 0
    if args.what == "models":
        for name in registry.model_names(args.pattern, tags=tags):
            meta = registry.get_model_entry(name).meta
            echo(f"{name:<24} {', '.join(meta.get('tags', ())):<36} {meta.get('paper', '')}")
    elif args.what == "datasets":
        for name in registry.list_datasets(args.pattern, tags=tags):
            meta = registry.get_dataset_entry(name).meta
            echo(f"{name:<24} {meta.get('sensor', ''):<14} {meta.get('num_classes', ''):>4} classes  "
                 f"{meta.get('description', '')}")
    else:
        for name in registry.list_sensors(args.pattern):
            sensor = registry.get_sensor(name)
            echo(f"{name:<16} {sensor.num_nodes:>4} taxels  grid {sensor.grid_shape[0]}x{sensor.grid_shape[1]}  "
                 f"{sensor.description}")
    return 0


def add_info(sub: argparse._SubParsersAction) -> None:
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
    info["revision"] = registry.revision_of(entry)  # the default; every revision it builds, with its compute path:
    info["revisions"] = _jsonable(registry.model_revisions(entry))
    ds_name = args.dataset or next(iter(registry.list_datasets("sim_*")), None)
    if ds_name is not None:
        ds = registry.load_dataset(ds_name, root=args.root, split="train")
        model = registry.instantiate_model(name, ds.spec)
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


def _unknown_name_message(name: str) -> str:
    """Close matches among every model, dataset and sensor name (a typo of a sensor must suggest the sensor)."""
    import difflib

    known = {"models": registry.model_names(), "datasets": registry.list_datasets(),
             "sensors": registry.list_sensors()}
    by_key = {registry.normalize_name(n): n for names in known.values() for n in names}
    close = [by_key[k] for k in difflib.get_close_matches(registry.normalize_name(name), list(by_key), n=3,
                                                          cutoff=0.6)]
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    listing = "; ".join(f"{kind}: {', '.join(names) or '(none)'}" for kind, names in known.items())
    return f"unknown name {name!r}: not a model, dataset or sensor.{hint} Known {listing}"


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
        raise registry.UnknownNameError(_unknown_name_message(args.name))
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
        echo(json.dumps(_jsonable(info), indent=2))
    else:
        width = max(len(k) for k in info)
        for key, value in info.items():
            echo(f"{key:<{width}}  {json.dumps(_jsonable(value)) if not isinstance(value, str) else value}")
    return 0


def add_plugins(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="discovered plugin distributions (models, datasets, weights) and their status")
    p.set_defaults(handler=_cmd_plugins)


def _cmd_plugins(args: argparse.Namespace) -> int:
    from ..weights import WEIGHTS_GROUP, weight_sources

    found, weights = registry.plugins(), weight_sources()
    if not found and not weights:
        echo("no tactile-zoo plugins installed" + (" (discovery disabled)" if not registry._enabled() else ""))
        return 0
    for info in found:
        line = f"{info.dist} {info.version:<8} {info.group:<22} {info.name} = {info.value}  [{info.status}]"
        echo(line + (f"  {info.error}" if info.error else ""))
    for src in weights:  # weights distributions: `tactile-zoo weights` lists what they ship
        line = (f"{src.dist} {src.version:<8} {WEIGHTS_GROUP:<22} {src.name} = {src.value}"
                + ("" if src.status == "failed" else f" (entries: {src.count})") + f"  [{src.status}]")
        echo(line + (f"  {src.error}" if src.error else ""))
    failed = any(i.status == "failed" for i in (*found, *weights))
    return 1 if failed and registry._strict() else 0
