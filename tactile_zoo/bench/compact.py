"""Store a bench folder's cell files compact: ``python -m tactile_zoo.bench.compact FOLDER [FOLDER ...]``.

Each plain ``cells/<id>.json`` under each FOLDER (every bench folder below it) becomes ``cells/<id>.json.gz``, the
gzip of its exact bytes, about a fifth of the size; the readers (:mod:`.records`) read both forms alike, so tables,
reports and config hashes are unchanged. Each compact file is read back and compared with its plain file before
that is removed (:func:`.records.compact_cell`), so an interrupted run loses nothing and running it again finishes
the job. A damaged cell file stops it before anything is compacted. ``bench`` keeps writing new cells plain: compact
a folder once its cells are final (the committed ``benchmarks/results`` folders are).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from ..errors import TactileZooError
from .records import compact_folder

__all__ = ["main"]


def _size(paths: Sequence[Path]) -> int:
    return sum(p.stat().st_size for p in paths)


def main(argv: Sequence[str] | None = None) -> int:
    """Compact the cell files of each folder named; exit 2 naming the folder when it is missing or a cell file
    in it is damaged (nothing of that folder is compacted)."""
    parser = argparse.ArgumentParser(prog="python -m tactile_zoo.bench.compact", description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, metavar="FOLDER",
                        help="a bench folder, or a folder of bench folders (every cells/ below it is compacted)")
    args = parser.parse_args(argv)
    for folder in args.folders:
        if not folder.is_dir():
            print(f"error: FOLDER {folder}: no such folder", file=sys.stderr)
            return 2
    for folder in args.folders:
        try:
            done, already = compact_folder(folder)
        except TactileZooError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"{folder}: {len(done)} cell file(s) compacted ({_size(done) / 1e6:.1f} MB now), "
              f"{already} compact already")
    return 0


if __name__ == "__main__":  # pragma: no cover - python -m tactile_zoo.bench.compact
    sys.exit(main())
