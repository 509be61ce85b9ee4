"""The report's plots: a heat map of every model on every dataset, bars with the seeds' spread, validation curves,
accuracy on the first part of a grasp, and confusion matrices of each dataset's best cells (by validation accuracy).
:func:`write_plots` writes them under ``RUN/plots/`` and returns their paths for ``report.md``."""

from __future__ import annotations

import math
from typing import Any

from .._files import atomic_path
from .grid import safe_name
from .rundir import RunDir

__all__ = ["write_plots"]


def _val_accuracy(record: dict[str, Any]) -> float:
    val = (record.get("metrics") or {}).get("val") or {}
    accuracy = val.get("accuracy")
    return float(accuracy) if isinstance(accuracy, int | float) and accuracy == accuracy else float("-inf")


def _best_cells(records: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """Each model's "best" cell per dataset, by VALIDATION accuracy (then fold, seed): a cell picked for showing by its
    test accuracy would put a selected-on-test figure in the report."""
    best: dict[tuple[str, str], dict[str, Any]] = {}
    for rec in sorted(records, key=lambda r: (-_val_accuracy(r), r["fold"], r["seed"])):  # ok records only
        best.setdefault((rec["model"], rec["dataset"]), rec)
    return best


def write_plots(run: RunDir, records: list[dict[str, Any]], summary: list[dict[str, Any]]) -> dict[str, Any]:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    run.plots_dir.mkdir(parents=True, exist_ok=True)
    figures: dict[str, Any] = {"bars": {}, "curves": {}, "early": {}, "confusion": {}}
    ok = [r for r in records if r.get("status") == "ok"]
    if not ok:
        return figures

    def save(fig: Any, rel: str) -> str:
        target = run.path / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            with atomic_path(target) as tmp:
                fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
        finally:
            plt.close(fig)
        return rel

    models = sorted({s["model"] for s in summary})
    datasets = sorted({s["dataset"] for s in summary})
    by_key = {(s["model"], s["dataset"]): s for s in summary}
    num_classes = {r["dataset"]: len(r.get("class_names") or []) for r in ok}

    # heat map: model x dataset mean accuracy
    fig, ax = plt.subplots(figsize=(1.6 + 1.5 * len(datasets), 1.0 + 0.45 * len(models)))
    grid = [[(by_key.get((m, d)) or {}).get("accuracy_mean") for d in datasets] for m in models]
    values = [[math.nan if v is None else v for v in row] for row in grid]
    image = ax.imshow(values, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(datasets)), datasets, rotation=30, ha="right")
    ax.set_yticks(range(len(models)), models)
    for i, row in enumerate(grid):
        for j, v in enumerate(row):
            if v is not None:
                std = by_key[(models[i], datasets[j])].get("accuracy_std")
                text = f"{v:.2f}" + (f"\n±{std:.2f}" if std is not None else "")
                ax.text(j, i, text, ha="center", va="center", fontsize=8, color="white" if v < 0.6 else "black")
    fig.colorbar(image, ax=ax, label="test accuracy (mean)")
    ax.set_title("Test accuracy")
    figures["heatmap"] = save(fig, "plots/heatmap.png")

    best = _best_cells(ok)
    for dataset in datasets:
        entries = sorted((s for s in summary if s["dataset"] == dataset), key=lambda s: -(s["accuracy_mean"] or 0))
        # bars with error bars
        fig, ax = plt.subplots(figsize=(1.5 + 0.7 * len(entries), 3.6))
        spread = any(e["accuracy_std"] is not None for e in entries)  # no error bars where every model has one cell
        ax.bar(range(len(entries)), [e["accuracy_mean"] or 0 for e in entries],
               yerr=[e["accuracy_std"] or 0 for e in entries] if spread else None, capsize=4, color="tab:blue")
        ax.set_xticks(range(len(entries)), [e["model"] for e in entries], rotation=30, ha="right")
        if num_classes.get(dataset):
            ax.axhline(1 / num_classes[dataset], color="grey", ls="--", lw=1, label="chance")
            ax.legend(loc="upper right", fontsize=8)
        ax.set_ylim(0, 1)
        ax.set_ylabel("test accuracy")
        ax.set_title(f"{dataset} (mean ± std over {max(e['n_cells'] for e in entries)} cell(s) per model)")
        figures["bars"][dataset] = save(fig, f"plots/bars_{safe_name(dataset)}.png")

        # training curves of each model's best cell
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
        for (model, ds), rec in sorted(best.items()):
            if ds != dataset or not rec.get("curve"):
                continue
            epochs = [row["epoch"] for row in rec["curve"]]
            for ax, key in zip(axes, ("train_loss", "val_loss", "val_accuracy")):
                ys = [row.get(key) for row in rec["curve"]]
                if any(y is not None for y in ys):
                    ax.plot(epochs, [math.nan if y is None else y for y in ys], label=model, marker=".", ms=3)
        for ax, title in zip(axes, ("training loss", "validation loss", "validation accuracy")):
            ax.set_title(title)
            ax.set_xlabel("epoch")
        for ax in axes[:2]:  # losses of different models differ by orders of magnitude (CE vs rate MSE, D-CNN's start)
            values = [y for line in ax.get_lines() for y in line.get_ydata() if not math.isnan(y)]
            if values and min(values) > 0:
                ax.set_yscale("log")
        axes[2].set_ylim(0, 1.02)
        # the models' names go beside the accuracy panel; where no cell has a validation accuracy (a final-evaluation
        # run), into the last panel with lines; none at all when nothing was drawn (matplotlib warns on an empty one)
        labelled = [ax for ax in axes if ax.get_legend_handles_labels()[0]]
        if axes[2] in labelled:
            axes[2].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
        elif labelled:
            labelled[-1].legend(fontsize=7, loc="best")
        fig.suptitle(f"{dataset}: training curves (best cell per model)", y=1.04)
        figures["curves"][dataset] = save(fig, f"plots/curves_{safe_name(dataset)}.png")

        # accuracy versus time (prefix fraction)
        fig, ax = plt.subplots(figsize=(6, 4))
        drawn = False
        for model in sorted({r["model"] for r in ok if r["dataset"] == dataset}):
            prefixes = [r["prefix"] for r in ok if r["dataset"] == dataset and r["model"] == model and r.get("prefix")]
            if not prefixes:
                continue
            fractions = prefixes[0]["fractions"]
            means = [sum(p["accuracy"][i] for p in prefixes) / len(prefixes) for i in range(len(fractions))]
            causal = prefixes[0].get("causal")
            ax.plot([100 * f for f in fractions], means, marker="o", ls="-" if causal else "--",
                    label=model + ("" if causal else " (non-causal)"))
            drawn = True
        if drawn:
            if num_classes.get(dataset):
                ax.axhline(1 / num_classes[dataset], color="grey", ls=":", lw=1, label="chance")
            ax.set_xlabel("% of the sequence seen")
            ax.set_ylabel("test accuracy")
            ax.set_ylim(0, 1.02)
            ax.set_title(f"{dataset}: early classification")
            ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
            figures["early"][dataset] = save(fig, f"plots/early_{safe_name(dataset)}.png")
        else:
            plt.close(fig)

        # confusion matrix of each model's best cell
        for (model, ds), rec in sorted(best.items()):
            if ds != dataset:
                continue
            cm = (rec["metrics"].get("test") or {}).get("confusion")  # a tuning cell has no test figures
            names = rec.get("class_names") or [str(i) for i in range(len(cm or []))]
            if not cm:
                continue
            k = len(cm)
            size = max(3.5, 0.35 * k + 2)
            fig, ax = plt.subplots(figsize=(size + 1, size))
            norm = [[v / max(1, sum(row)) for v in row] for row in cm]
            image = ax.imshow(norm, vmin=0, vmax=1, cmap="Blues")
            ax.set_xticks(range(k), names, rotation=60, ha="right", fontsize=max(5, 9 - k // 8))
            ax.set_yticks(range(k), names, fontsize=max(5, 9 - k // 8))
            if k <= 15:
                for i in range(k):
                    for j in range(k):
                        if cm[i][j]:
                            ax.text(j, i, str(cm[i][j]), ha="center", va="center", fontsize=7,
                                    color="white" if norm[i][j] > 0.5 else "black")
            ax.set_xlabel("predicted")
            ax.set_ylabel("true")
            acc = rec["metrics"]["test"]["accuracy"]
            ax.set_title(f"{model} on {dataset}\nfold {rec['fold']} seed {rec['seed']}, accuracy {acc:.3f}",
                         fontsize=9)
            fig.colorbar(image, ax=ax, fraction=0.046, label="fraction of the true class")
            rel = f"plots/confusion/{safe_name(dataset)}__{safe_name(model)}.png"
            figures["confusion"].setdefault(dataset, {})[model] = save(fig, rel)
    return figures
