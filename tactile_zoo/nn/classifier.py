"""The classifier-head convention, timm style: ``forward_features``, ``forward_head``, ``get_classifier`` and
``reset_classifier``.

Every built-in model splits its forward pass in two: ``forward_features(x, g)`` computes what the final classifier
layer reads, ``forward_head(features)`` turns it into scores, and ``forward(x, g) == forward_head(forward_features(x,
g))`` exactly (the split moves no computation, so outputs and cell hashes are unchanged). The features are ``(B, F)``
for every built-in model but SGnet and DeepTactile, whose spiking classifiers read spike trains ``(B, T, F)`` (their
scores are the output spike rates, so there is no pooled vector before the last layer).

The classifier layer is the model's ``zoo_head`` submodule, else its last ``nn.Linear`` (with ``num_classes``
outputs when given): :func:`classifier_name`. ``reset_classifier(n)`` replaces that layer by a fresh ``nn.Linear``
with ``n`` outputs, initialised as the model initialises it (:meth:`ClassifierMixin._init_classifier`), and gives the
model a spec with ``n`` classes.

A plugin model gets the same calls by subclassing :class:`ClassifierMixin` and defining ``forward_features`` and
``forward_head``. Without them, the module-level :func:`forward_features` and :func:`reset_classifier` fall back to
the convention above: the features are the input of the classifier layer, caught by a forward pre-hook during
``model(x, g)`` (so in training mode they include any dropout applied right before it).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from torch import Tensor, nn

from ..errors import ConfigError

__all__ = ["ClassifierMixin", "classifier_name", "forward_features", "reset_classifier"]


def classifier_name(model: nn.Module, num_classes: int | None = None) -> str:
    """The dotted name of ``model``'s final classifier layer (its ``zoo_head``, else the last ``nn.Linear`` with
    ``num_classes`` outputs, or the last one at all when ``num_classes`` is ``None``)."""
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


def forward_features(model: nn.Module, x: Tensor, g: Tensor | None = None) -> Tensor:
    """``model.forward_features(x, g)`` when the model has it, else the input its classifier layer receives during
    ``model(x, g)`` (the fallback for plugin models; see the module docstring)."""
    method = getattr(model, "forward_features", None)
    if callable(method):
        try:
            return method(x, g)
        except NotImplementedError:  # the mixin's (or a base class's) placeholder: the fallback below serves it
            pass
    layer = model.get_submodule(classifier_name(model))
    caught: list[Tensor] = []
    handle = layer.register_forward_pre_hook(lambda _module, args: caught.append(args[0]))
    try:
        model(x, g)
    finally:
        handle.remove()
    if len(caught) != 1:  # called per step, or not at all: there is no one feature tensor to return
        raise ConfigError(f"{type(model).__name__}: its classifier layer {classifier_name(model)!r} ran "
                          f"{len(caught)} times in one forward pass; define forward_features(x, g)")
    return caught[0]


def reset_classifier(model: nn.Module, num_classes: int) -> None:
    """Replace ``model``'s classifier layer by a fresh ``nn.Linear`` with ``num_classes`` outputs (see the module
    docstring); the model's ``spec`` (when it has one) then has ``num_classes`` classes."""
    if isinstance(num_classes, bool) or not isinstance(num_classes, int) or num_classes < 1:
        raise ConfigError(f"num_classes must be a positive integer, got {num_classes!r}")
    name = classifier_name(model)
    old = model.get_submodule(name)
    if not isinstance(old, nn.Linear):
        raise ConfigError(f"{type(model).__name__}: its classifier {name!r} is a {type(old).__name__}, not an "
                          f"nn.Linear; define reset_classifier(num_classes)")
    parent, _, attr = name.rpartition(".")
    new = nn.Linear(old.in_features, num_classes, bias=old.bias is not None).to(old.weight.device, old.weight.dtype)
    init = getattr(model, "_init_classifier", None)
    if callable(init):
        init(new)
    setattr(model.get_submodule(parent) if parent else model, attr, new)
    spec = getattr(model, "spec", None)
    if spec is not None and dataclasses.is_dataclass(spec) and getattr(spec, "num_classes", None) != num_classes:
        # the spec's class names belong to the old classes: the new ones are known only by their index
        model.spec = dataclasses.replace(spec, num_classes=num_classes,
                                         class_names=tuple(f"class_{i}" for i in range(num_classes)))


class ClassifierMixin:
    """``forward_features`` / ``forward_head`` / ``get_classifier`` / ``reset_classifier`` for an ``nn.Module``
    (see the module docstring). A subclass defines ``forward_features`` and ``forward_head``; the classifier layer is
    found by :func:`classifier_name`."""

    def forward_features(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        raise NotImplementedError

    def forward_head(self, features: Tensor) -> Tensor:
        return self.get_classifier()(features)

    def get_classifier(self) -> nn.Module:
        """The final classifier layer."""
        module: Any = self
        return module.get_submodule(classifier_name(module))

    def reset_classifier(self, num_classes: int) -> None:
        """A fresh classifier layer with ``num_classes`` outputs (see :func:`reset_classifier`)."""
        reset_classifier(self, num_classes)  # type: ignore[arg-type]

    def _init_classifier(self, layer: nn.Linear) -> None:
        """Initialise a fresh classifier layer as the model's constructor does (default: PyTorch's own)."""
