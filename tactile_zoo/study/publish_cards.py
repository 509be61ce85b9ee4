"""The measured figures of each model card in docs/models.md, generated from the studies that publish there.

A study adds a row to the cards of the models it names: ``publishes: [{where: docs/models.md, block: cards, table:
LABEL, models: [...]}]`` (``grid``: that grid only; several studies under one label pool their cells, on one CPU
type, as the README headline pools a recipe's rounds). The row reads the cells of the model at its registered
revision, one figure per dataset (mean [95 % interval] (runs) on the split Table I reads), and names the study, the
grid where one is given, and the revision. So a model's card moves with the studies, never by hand: a new revision's
study claims the model's row, a distillation study adds its students, a new model's first cells add its first row.
Each card holds the block ``<!-- card MODEL: begin (...) -->``; a model with no row says so.
"""

from __future__ import annotations

from .. import registry
from ..errors import ResultsError
from .publish_tables import SPLITS, TITLES, Context, figure, group, name, registered_revision
from .schema import Publication, Study

__all__ = ["PAGE", "BLOCK", "card_models", "card_block"]

PAGE, BLOCK = "docs/models.md", "cards"


def card_models() -> list[str]:
    """The built-in models, each of which has a card (and so a block) in docs/models.md."""
    return [m for m in registry.model_names()
            if str(getattr(registry.get_model_entry(m).obj, "__module__", "")).startswith("tactile_zoo.models.")]


def _rows(ctx: Context, model: str) -> dict[str, list[tuple[Study, Publication]]]:
    """label -> the publications of that label naming ``model``, in study order (several studies' cells pool)."""
    out: dict[str, list[tuple[Study, Publication]]] = {}
    for study, pub in ctx.parts(PAGE, BLOCK):
        if model in pub.models:
            out.setdefault(str(pub.table), []).append((study, pub))
    return out


def card_block(ctx: Context, model: str) -> str:
    """The body of ``model``'s card block: one row per publishing study (in study order), one column per dataset."""
    revision = registered_revision(model)
    rows = _rows(ctx, model)
    if not rows:
        return (f"No study has published a measured figure of {name(model)} at revision {revision} yet "
                f"(docs/published-results.md lists the published ones and their protocols).")
    lines = [f"Measured at revision {revision}, each row the cells of the studies it names (mean [95 % interval] "
             f"(runs); the test split read once per cell; BioTac-DoS on its unseen textures):", "",
             "| cells | " + " | ".join(TITLES.values()) + " | study |", "|---|" + "---|" * (len(TITLES) + 1)]
    for label, parts in rows.items():
        recs = ctx.model_cells(model, parts, f"{name(model)}'s card, studies {', '.join(s.name for s, _ in parts)}")
        if not recs:
            raise ResultsError(f"{parts[0][0].where}: publishes {name(model)} on its card ({label}), but has no cell "
                               f"of it at its registered revision {revision}")
        figures = [figure(group(recs, model, d), SPLITS[d]) if group(recs, model, d) else "-" for d in TITLES]
        where = ", ".join(f"`{s.name}`" + (f" (grid `{p.grid}`)" if p.grid else "") for s, p in parts)
        lines.append(f"| `{label}` | " + " | ".join(figures) + f" | {where} |")
    return "\n".join(lines)
