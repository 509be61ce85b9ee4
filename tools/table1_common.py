"""What the Table I tools share (:mod:`tools.paper_table1`, :mod:`tools.headline`, :mod:`tools.table1_full`): the
models, the X-Tacformer paper's figures, and how one row's cells are gathered and printed."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from tactile_zoo.bench.intervals import records_interval

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
MODELS = ("sgnet", "convlstm", "cnn_lstm", "tacformer", "x_tacformer", "dcnn")
NAMES = {"sgnet": "SGnet", "convlstm": "ConvLSTM", "cnn_lstm": "CNN-LSTM", "tacformer": "Tacformer",
         "x_tacformer": "X-Tacformer", "dcnn": "D-CNN"}
#: model -> (Ev-Objects, Ev-Containers, BioTac-DoS textures, Augment8000), Table I of the X-Tacformer paper
PAPER: dict[str, tuple[float | None, ...]] = {
    "sgnet": (0.8944, 0.6417, None, None),
    "convlstm": (0.8611, 0.7333, 0.7380, None),
    "cnn_lstm": (0.8472, 0.7167, 0.8182, None),
    "tacformer": (0.9027, 0.7500, 0.8442, None),
    "x_tacformer": (0.9167, 0.7833, 0.8833, None),
    "dcnn": (None, None, None, 0.7258),
}
EV = {"ev_objects": ("Ev-Objects", 0, "144 test recordings, 36 classes"),
      "ev_containers": ("Ev-Containers", 1, "60 test recordings, 20 classes")}


def paper_column(dataset: str) -> int:
    """The index of ``dataset``'s figure in a :data:`PAPER` row (BioTac-DoS, not an Ev dataset, is the third)."""
    return EV[dataset][1] if dataset in EV else 2


def _group(records: list[dict[str, Any]], model: str, dataset: str) -> list[dict[str, Any]]:
    recs = sorted((r for r in records if r["model"] == model and r["dataset"] == dataset),
                  key=lambda r: (r["fold"], r["seed"]))
    hashes = sorted({r["config_hash"] for r in recs})
    if len(hashes) > 1:
        raise SystemExit(f"{model} on {dataset}: cells of {len(hashes)} configurations ({', '.join(hashes)}); one "
                         f"table row must be one configuration (move the others to their own folder)")
    return recs


def _figure(recs: list[dict[str, Any]], split: str, low_high: tuple[float, float] | None = None,
            std: bool = False) -> str:
    """``mean [95 % interval] (runs)``, with ``std``: ``mean ± std [95 % interval] (runs)``; pass ``low_high`` when the
    caller has already bootstrapped the interval."""
    if not recs:
        return "not run yet"
    values = [r["metrics"][split]["accuracy"] for r in recs]
    low_high = low_high or records_interval(recs, split)
    interval = "-" if low_high is None else f"[{low_high[0]:.3f}, {low_high[1]:.3f}]"
    spread = f" ± {statistics.stdev(values):.3f}" if std and len(values) > 1 else ""
    return f"{statistics.fmean(values):.4f}{spread} {interval} ({len(recs)})"


def cpu_types(records: list[dict[str, Any]]) -> list[str]:
    """The CPU types (name and torch's instruction-set capability) that ``records`` ran on, sorted: seeds pool only
    within one type, since the same seed can train differently on another."""
    return sorted({f"{r.get('cpu', '?')} ({(r.get('cpu_isa') or {}).get('capability', '?')})" for r in records})


def _where(paper: float, low_high: tuple[float, float]) -> str:
    """Where a paper figure lies against one of our intervals: "above", "inside" or "below"."""
    return "above" if paper > low_high[1] else "below" if paper < low_high[0] else "inside"
