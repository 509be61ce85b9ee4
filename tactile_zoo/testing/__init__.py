"""The model and dataset contracts as a public suite: one call checks a model or a dataset before it is published.

A plugin author runs :func:`check_model` on a model (a registered name, or the class itself) and
:func:`check_dataset` on a dataset; each runs the contract's named rules (:data:`MODEL_RULES`,
:data:`DATASET_RULES`) on tiny inputs, raises one :class:`ContractError` naming the rule, the model or dataset and
what was wrong, and otherwise returns a :class:`ContractReport` of the rules that held. A model is checked at a level
(:data:`MODEL_LEVELS`): ``"plugin"`` by default, what the harness needs to run it; ``"publication"`` adds metadata
completeness (paper, description, ...), and is what the project's own tests run over every registered model. They
run :func:`check_dataset` over the simulated datasets.

This layer sits beside the weights and export layers, on top of the engine: it reaches models through the registry
only (``.importlinter``), and ``import tactile_zoo`` does not import it.
"""

from ._contract import ContractError, ContractReport, random_batch, tiny_spec
from .datasets import DATASET_RULES, check_dataset
from .models import MODEL_LEVELS, MODEL_RULES, check_model

__all__ = ["check_model", "check_dataset", "ContractError", "ContractReport", "MODEL_RULES", "MODEL_LEVELS",
           "DATASET_RULES", "tiny_spec", "random_batch"]
