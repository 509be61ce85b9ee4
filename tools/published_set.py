"""The published set (``tactile_zoo/published/table1-v1.json.gz``): Table I's committed `full` and `zoo` cells, with
each test sample's prediction, for ``tactile-zoo study compare`` (:mod:`tactile_zoo.study.published`). The set is
package data built from the committed cells, not committed itself: ``make install`` runs this, and ``setup.py`` refuses
to build a wheel without it.

    python -m tools.published_set            # write the set from the committed cells
    python -m tools.published_set --check    # exit 1 unless the set on disk is what the cells give
    python -m tools.published_set --out F --name N --version V --from DIR [--from DIR ...] [--tuning DIR ...]
                                             # a set of other folders (a test's small set, a later version)

A new version is a new file (``table1-v2``): a published set never changes once released, so that a comparison
cites exactly what it compared against. The current version's folders are :data:`SOURCES`; the tuning trials are
counted from :data:`TUNING`.
"""

from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path

from tactile_zoo.study.published import build_set, encode_set, set_file_name

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NAME, VERSION = "table1", 1
#: the folders of Table I's cells: `full` round 3 (seeds 0-4), round 4 (seeds 5-9), and the `zoo` recipes
SOURCES = ("paper-table1-full", "paper-table1-full-r4", "paper-table1-zoo")
RECIPES = ("full", "zoo")
TUNING = RESULTS / "tuning"
OUT = ROOT / "tactile_zoo" / "published" / set_file_name(f"{NAME}-v{VERSION}")
ABOUT = ("Table I of tactile-zoo: six models on Ev-Objects, Ev-Containers and BioTac-DoS. Recipe `full`: each "
         "model trained on every training recording for a fixed epoch count declared from validation evidence "
         "(evaluation `final`, the test split read once), seeds 0-9 (benchmarks/results/paper-table1-full and "
         "-r4). Recipe `zoo`: validation-selected epochs (evaluation `validation`), seeds 0-4 on the Ev datasets "
         "and BioTac-DoS's four object folds at seed 0 (benchmarks/results/paper-table1-zoo).")
TUNING_NOTE = ("Trials of the model on the dataset under benchmarks/results/tuning (evaluation `tuning`: validation "
               "only, no test split read): configurations are distinct config hashes, cells their seeds. They chose "
               "the `zoo` recipes and dataset settings; `full` took its epoch counts from the `zoo` cells' validation "
               "choices (benchmarks/results/paper-table1-full/PLAN.md) and the trials of full-ema, full-ema99 and "
               "full-schedule (none adopted).")


def build(folders: list[Path], name: str, version: int, tuning: list[Path], recipes: list[str] | None,
          about: str = "", tuning_note: str = "") -> bytes:
    data = build_set(folders, name, version, recipes=recipes, tuning=tuning, root=ROOT, about=about,
                     tuning_note=tuning_note)
    return encode_set(data)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.published_set", description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 unless the set on disk is what the cells give")
    parser.add_argument("--out", type=Path, default=None, help=f"the set file (default {OUT.relative_to(ROOT)})")
    parser.add_argument("--name", default=None, help=f"the set's name (default {NAME})")
    parser.add_argument("--version", type=int, default=None, help=f"its version (default {VERSION})")
    parser.add_argument("--from", dest="sources", action="append", type=Path, default=None, metavar="DIR",
                        help="a bench folder of cells (repeatable; default Table I's)")
    parser.add_argument("--tuning", action="append", type=Path, default=None, metavar="DIR",
                        help="a folder of tuning cells, searched recursively (repeatable; default "
                             "benchmarks/results/tuning's folders)")
    args = parser.parse_args(argv)
    own = args.sources is None
    folders = [RESULTS / s for s in SOURCES] if own else args.sources
    tuning = sorted(p for p in TUNING.iterdir() if p.is_dir()) if args.tuning is None else args.tuning
    name, version = args.name or NAME, args.version if args.version is not None else VERSION
    out = args.out or (OUT if own else None)
    if out is None:
        parser.error("--out is required with --from")
    blob = build(folders, name, version, tuning, list(RECIPES) if own else None, ABOUT if own else "",
                 TUNING_NOTE if own else "")
    if args.check:
        committed = gzip.decompress(out.read_bytes()) if out.is_file() else b""
        if committed != blob:
            print(f"{out}: not what the cells give; run python -m tools.published_set", file=sys.stderr)
            return 1
        print(f"{out}: up to date ({len(json.loads(blob)['cells'])} cells)")
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(gzip.compress(blob, compresslevel=9, mtime=0))
    print(f"wrote {out}: {len(json.loads(blob)['cells'])} cells, {out.stat().st_size / 1e6:.2f} MB "
          f"({len(blob) / 1e6:.1f} MB of JSON)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
