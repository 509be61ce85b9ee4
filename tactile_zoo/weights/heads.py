"""The classifier head of a model: the one layer whose shape depends on the number of classes.

Convention: a model names its final classifier layer in a ``zoo_head`` attribute, the dotted name of the submodule
(``"head"`` for Tacformer, X-Tacformer, ConvLSTM and CNN-LSTM, ``"classifier.8"`` for D-CNN). A model without one
(SGnet, plugins) is read by its last ``nn.Linear`` with ``num_classes`` outputs, in registration order (SGnet's
``fcs.<last>``). ``create_model(..., pretrained=..., new_head=True)`` keeps every other parameter and lets the model
initialise this layer afresh for the new classes.
"""

from __future__ import annotations

from torch import nn

from ..nn.classifier import classifier_name

__all__ = ["head_name", "head_keys"]


def head_name(model: nn.Module, num_classes: int | None = None) -> str:
    """The dotted name of ``model``'s final classifier layer (its ``zoo_head``, else the last ``nn.Linear`` with
    ``num_classes`` outputs): :func:`tactile_zoo.nn.classifier.classifier_name`, which ``reset_classifier`` uses
    too."""
    return classifier_name(model, num_classes)


def head_keys(model: nn.Module, name: str) -> list[str]:
    """The state-dict keys of submodule ``name`` (its parameters and persistent buffers)."""
    return [k for k in model.state_dict() if k.startswith(f"{name}.")]
