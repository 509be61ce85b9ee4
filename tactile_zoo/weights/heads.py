"""The classifier head of a model: the one layer whose shape depends on the number of classes.

Convention: a model names its final classifier layer in a ``zoo_head`` attribute, the dotted name of the submodule
(``"head"`` for Tacformer, X-Tacformer, ConvLSTM and CNN-LSTM, ``"classifier.8"`` for D-CNN). A model without one
(SGnet, plugins) is read by its last ``nn.Linear`` with ``num_classes`` outputs, in registration order (SGnet's
``fcs.<last>``). ``create_model(..., pretrained=..., new_head=True)`` keeps every other parameter and lets the model
initialise this layer afresh for the new classes.
"""

from __future__ import annotations

from torch import nn

from ..errors import ConfigError

__all__ = ["head_name", "head_keys"]


def head_name(model: nn.Module, num_classes: int | None = None) -> str:
    """The dotted name of ``model``'s final classifier layer (its ``zoo_head``, else the last ``nn.Linear`` with
    ``num_classes`` outputs)."""
    name = getattr(model, "zoo_head", None)
    if name is not None:
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{type(model).__name__}.zoo_head must name a submodule, got {name!r}")
        try:
            model.get_submodule(name)
        except AttributeError:
            raise ConfigError(f"{type(model).__name__}.zoo_head names {name!r}, which is not one of its "
                              f"submodules") from None
        return name
    linear = [n for n, m in model.named_modules() if isinstance(m, nn.Linear)
              and (num_classes is None or m.out_features == num_classes)]
    if not linear:
        raise ConfigError(f"cannot find the classifier head of {type(model).__name__}: it has no zoo_head attribute "
                          f"and no nn.Linear layer with {num_classes} outputs; set zoo_head = '<submodule name>'")
    return linear[-1]


def head_keys(model: nn.Module, name: str) -> list[str]:
    """The state-dict keys of submodule ``name`` (its parameters and persistent buffers)."""
    return [k for k in model.state_dict() if k.startswith(f"{name}.")]
