"""The benchmark harness: every model crossed with every dataset into a resumable leaderboard.

``run_bench(BenchConfig(models=["all"]))`` is what ``tactile-zoo bench`` runs; :func:`write_outputs` is
``tactile-zoo report``. Layers: :mod:`.config` (settings, YAML), :mod:`.grid` (names, datasets, cells, hashes),
:mod:`.worker` (a cell's record and failure isolation, anywhere; the cell itself is
:func:`tactile_zoo.engine.cell.train_cell`), :mod:`.executors` (local, process, dask), :mod:`.rundir` (atomic files,
claims, run folders), :mod:`.tables` (leaderboard, summary and ranks, with pandas), :mod:`.report` (report.md and
plots), :mod:`.runner` (the run). The harness uses the engine (:mod:`tactile_zoo.engine`); nothing below it imports
the harness.
"""

from ..engine.config import config_hash
from .config import BenchConfig, load_yaml_config
from .grid import Cell, Grid, build_grid
from .report import write_outputs
from .rundir import RunDir
from .runner import BenchOutcome, run_bench
from .tables import LEADERBOARD_COLUMNS, SUMMARY_COLUMNS

__all__ = ["BenchConfig", "load_yaml_config", "Cell", "Grid", "build_grid", "config_hash", "write_outputs",
           "LEADERBOARD_COLUMNS", "SUMMARY_COLUMNS", "RunDir", "BenchOutcome", "run_bench"]
