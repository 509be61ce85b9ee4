"""Bench a third-party model from ``plugins/`` against the built-in models, with the same harness and protocol.

The temporal convolutional network in ``plugins/tactile-zoo-tcn`` is an out-of-tree distribution: it declares the
entry point ``tcn = tactile_zoo_tcn:TCN`` in the group ``tactile_zoo.models``, so once it is installed tactile-zoo
finds it (``tactile-zoo plugins`` lists it) and benchmarks it exactly like a built-in. Install it once, next to
tactile-zoo, from the repository root::

    pip install ./plugins/tactile-zoo-tcn        # or: pip install -e ./plugins/tactile-zoo-tcn

then run::

    python examples/bench_plugin_model.py                 # tcn vs every built-in on the simulated datasets
    python examples/bench_plugin_model.py --quick         # a smoke run in about a minute
    python examples/bench_plugin_model.py --models sgnet,dcnn --datasets sim_evtouch --seeds 0,1,2

The same comparison from the command line is ``tactile-zoo bench --models all --datasets "sim_*"`` (``all`` includes
installed plugins). Without installing, ``--from-source`` registers the plugin's class from this checkout in this
process (local executor only: worker processes would not see it).

Results go to ``--out`` (default ``tactile-zoo-results/plugin-tcn-...``); rerunning the same command resumes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import tactile_zoo as tz
from tactile_zoo.bench import BenchConfig, run_bench
from tactile_zoo.bench.report import load_run
from tactile_zoo.bench.tables import leaderboard_rows, summary_rows

PLUGIN_DIR = Path(__file__).resolve().parents[1] / "plugins" / "tactile-zoo-tcn"
PLUGIN_MODEL = "tcn"


def register_from_source() -> None:
    """Register the plugin's TCN from the checkout, as its entry point would (metadata from ``TCN.zoo_meta``)."""
    sys.path.insert(0, str(PLUGIN_DIR))
    from tactile_zoo_tcn import TCN

    tz.register_model(PLUGIN_MODEL, **TCN.zoo_meta)(TCN)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", default="all", help="built-in models to compare with (default: all of them)")
    parser.add_argument("--datasets", default="sim_*", help="datasets (default: the simulated ones)")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--epochs", type=int, default=None)
    parser.add_argument("--quick", action="store_true", help="2 epochs on small subsets")
    parser.add_argument("--executor", default="local", choices=["local", "process", "dask"])
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", default=None)
    parser.add_argument("--from-source", action="store_true", help="register the plugin from plugins/ without "
                                                                   "installing it")
    args = parser.parse_args(argv)

    if args.from_source:
        if args.executor != "local":
            parser.error("--from-source registers the model in this process only: use --executor local, or install "
                         "the plugin")
        register_from_source()
    if PLUGIN_MODEL not in tz.list_models():
        print(f"the plugin model {PLUGIN_MODEL!r} is not installed. Install it with\n"
              f"    pip install {PLUGIN_DIR}\nor rerun with --from-source.", file=sys.stderr)
        return 2
    entry = tz.registry.get_model_entry(PLUGIN_MODEL)
    print(f"plugin model {entry.qualified_name} from {entry.dist or 'this checkout'}: "
          f"{entry.meta.get('paper', '')}")

    patterns = ["*" if p.strip() == "all" else p.strip() for p in args.models.split(",") if p.strip()]
    builtins = [m for m in tz.list_models(patterns) if not tz.registry.get_model_entry(m).is_plugin]
    models = [PLUGIN_MODEL, *[m for m in builtins if m != PLUGIN_MODEL]]
    out = args.out or f"tactile-zoo-results/plugin-{PLUGIN_MODEL}-vs-{args.models.replace('*', 'x')}" \
                      f"{'-quick' if args.quick else ''}"
    config = BenchConfig(models=models, datasets=[args.datasets], seeds=args.seeds, epochs=args.epochs,
                         quick=args.quick, executor=args.executor, workers=args.workers, out=out)
    outcome = run_bench(config)

    # the plugin's place on each dataset, from the run's own cell files
    records, skipped, _, _ = load_run(outcome.out)
    board, columns = leaderboard_rows(records, skipped)
    summary, _ = summary_rows(board, columns)
    print(f"\n{'dataset':<22}{'model':<16}{'accuracy':>10}{'rank':>6}")
    for row in sorted(summary, key=lambda r: (r["dataset"], r["rank"] or 99)):
        mark = "  <- plugin" if row["model"] == PLUGIN_MODEL else ""
        print(f"{row['dataset']:<22}{row['model']:<16}{row['accuracy_mean']:>10.3f}{row['rank']:>6}{mark}")
    print(f"\nreport: {outcome.out / 'report.md'}")
    return outcome.exit_code


if __name__ == "__main__":
    sys.exit(main())
