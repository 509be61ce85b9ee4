"""The published result tables, regenerated from the study files (``benchmarks/studies/*.yaml``): the README's
headline, ``docs/table1.md``, the fidelity ledger's decomposition, ``docs/published-results.md`` and the results
index's studies (:mod:`tactile_zoo.study.publish` names each block and the studies that feed it).

    python -m tools.published_tables            # rewrite every generated block
    python -m tools.published_tables --check    # exit 1 if a page is not what the studies give, or if a headline row
                                                # reads another recipe than its model's registered default
    python -m tools.published_tables --print BLOCK   # print one block (e.g. "table1 round 4")

Nothing is trained; the declared reads are the ones each study recorded (``RESULTS/study/reads.json``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tactile_zoo._files import update_pages
from tactile_zoo.errors import TactileZooError
from tactile_zoo.study.publish import BLOCKS, COMMAND, check_pages, load_context, render_block, render_pages

STUDIES = Path(__file__).resolve().parents[1] / "benchmarks" / "studies"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.published_tables", description=__doc__.split("\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="exit 1 if a page is out of date (nothing written)")
    mode.add_argument("--print", metavar="BLOCK", dest="block", help="print one generated block")
    parser.add_argument("--studies", type=Path, default=STUDIES, help="the study files' folder (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        ctx = load_context(args.studies)
        if args.block:
            pages = [page for page, block in BLOCKS if block == args.block]
            if not pages:
                parser.error(f"--print: no block {args.block!r} (known: {', '.join(b for _, b in BLOCKS)})")
            print(render_block(ctx, pages[0], args.block))
            return 0
        if args.check:
            problems = check_pages(ctx)
            for line in problems:
                print(line, file=sys.stderr)
            return int(bool(problems))
        update_pages(render_pages(ctx), False, COMMAND)
    except TactileZooError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
