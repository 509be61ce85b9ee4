"""``tactile-zoo download``: fetch and verify a dataset's raw files, or say exactly where to place them."""

from __future__ import annotations

import argparse
import json

from .. import registry
from ._common import echo

__all__ = ["add_download"]


def add_download(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("download", help="fetch and verify a dataset's raw files, or say exactly where to place them")
    p.add_argument("name")
    p.add_argument("--root", default=None, help="data home (default $TACTILE_ZOO_DATA, else ~/.cache/tactile_zoo/data)")
    p.add_argument("--extract", action="store_true", help="also unpack the verified archive next to it (members "
                                                          "with absolute paths, '..' or links are refused)")
    p.set_defaults(handler=_cmd_download)


def _cmd_download(args: argparse.Namespace) -> int:
    entry = registry.get_dataset_entry(args.name)
    obj = entry.obj
    if getattr(obj, "simulated", False):
        echo(f"{entry.qualified_name}: simulated, nothing to download")
        return 0
    check = getattr(obj, "availability", None)
    present, where = check(args.root) if callable(check) else (False, "")
    downloadable = bool(getattr(obj, "downloadable", False))
    if not present and not downloadable:
        echo(f"{entry.qualified_name} cannot be downloaded automatically. {where or entry.meta.get('obtain', '')}")
        return 1
    # loading downloads when needed, verifies the checksum, and builds the processed cache in one go
    ds = registry.load_dataset(args.name, root=args.root, split=None, download=downloadable)
    state = "present" if present else "downloaded and verified"
    echo(f"{entry.qualified_name}: {state} ({check(args.root)[1] if callable(check) else 'loaded'}); "
         f"{len(ds)} samples, spec {json.dumps(ds.spec.to_dict())}")
    if args.extract:
        extract = getattr(obj, "extract", None)
        if not callable(extract):
            echo(f"{entry.qualified_name}: nothing to extract (its raw files are not an archive)")
        else:
            echo(f"{entry.qualified_name}: extracted to {extract(args.root)}")
    return 0
