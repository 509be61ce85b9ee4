"""The training engine: recipes, ``fit``, ``evaluate``, metrics and checkpoints.

``tactile_zoo.fit`` and ``tactile_zoo.evaluate`` forward here. The engine uses the data contract and the registry; it
never imports the harness (:mod:`tactile_zoo.bench`), and models never import it.
"""

from ..recipe import DEFAULT_RECIPE, RECIPE_KEYS, Recipe, resolve_recipe
from .api import fit
from .checkpoint import build_from_checkpoint, load_checkpoint, save_checkpoint
from .evaluate import (
    DEFAULT_PREFIXES,
    EvalResult,
    earliness,
    evaluate,
    predict_scores,
    prefix_evaluation,
    time_inference,
)
from .metrics import (
    NEEDS,
    Metric,
    MetricError,
    MetricInputMissing,
    accuracy,
    balanced_accuracy,
    classification_metrics,
    confusion_matrix,
    macro_f1,
    metric_value,
    register_metric,
    registered_metrics,
    scores_to_probabilities,
    unregister_metric,
)
from .runtime import PeakMemory, count_parameters, resolve_device, seed_everything
from .tensors import TensorSplit, as_split, concat, take
from .train import FitResult, TrainingError

__all__ = [
    "fit", "evaluate", "FitResult", "EvalResult", "TrainingError", "Recipe", "DEFAULT_RECIPE", "RECIPE_KEYS",
    "resolve_recipe", "accuracy", "balanced_accuracy", "macro_f1", "confusion_matrix", "classification_metrics",
    "scores_to_probabilities", "predict_scores", "prefix_evaluation", "time_inference", "earliness",
    "DEFAULT_PREFIXES", "resolve_device", "seed_everything", "PeakMemory", "count_parameters", "TensorSplit",
    "as_split", "take", "concat", "save_checkpoint", "load_checkpoint", "build_from_checkpoint", "Metric",
    "MetricError", "MetricInputMissing", "NEEDS", "register_metric", "unregister_metric", "registered_metrics",
    "metric_value",
]
