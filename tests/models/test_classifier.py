"""timm's classifier calls on every registered model (parametrised over ``list_models()``, as tests/models/test_zoo.py):
``forward_features`` + ``forward_head`` is ``forward``, ``reset_classifier(n)`` gives ``n`` outputs with every other
weight kept, ``create_model(..., num_classes=n)`` builds a model with ``n`` outputs, and the fallbacks of
:mod:`tactile_zoo.nn.classifier` serve a plugin model that has none of these methods."""

from __future__ import annotations

import pytest
import torch
from test_zoo import MODELS, STREAMING, build, make_batch, make_spec
from torch import nn

import tactile_zoo as tz
from tactile_zoo.nn import classifier

SENSORS = ["neutouch", "uskin_allegro"]  # without and with global features
SPIKE_TRAIN_HEADS = {"sgnet", "deeptactile"}  # scores are output spike rates: no pooled vector before the head


@pytest.mark.parametrize("sensor", SENSORS)
@pytest.mark.parametrize("name", MODELS)
def test_forward_head_of_forward_features_is_forward(name: str, sensor: str) -> None:
    spec = make_spec(sensor)
    model = build(name, spec).eval()
    x, g, _ = make_batch(spec, 4, seed=2)
    with torch.no_grad():
        features = model.forward_features(x, g)
        out = model.forward_head(features)
        assert torch.equal(out, model(x, g))
        assert torch.equal(classifier.forward_features(model, x, g), features)  # the method wins over the fallback
    layer = model.get_classifier()
    assert isinstance(layer, nn.Linear) and layer.out_features == spec.num_classes
    # (B, F) the classifier reads; the spiking classifiers of SGnet and DeepTactile read spike trains (B, T, F)
    expected = (4, spec.num_steps, layer.in_features) if name in SPIKE_TRAIN_HEADS else (4, layer.in_features)
    assert features.shape == expected


@pytest.mark.parametrize("name", MODELS)
def test_reset_classifier_gives_a_fresh_head_and_keeps_the_rest(name: str) -> None:
    spec = make_spec("uskin_allegro")
    model = build(name, spec)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    old = model.get_classifier()
    model.reset_classifier(3)
    new = model.get_classifier()
    assert new is not old and new.out_features == 3 and new.in_features == old.in_features
    if name == "dcnn":  # initialised as the constructor initialises it: Xavier weights, zero bias
        assert not new.bias.any()
    head = classifier.classifier_name(model)
    after = model.state_dict()
    assert set(after) == set(before)
    for key, value in after.items():
        if not key.startswith(f"{head}."):
            assert torch.equal(value, before[key]), f"{name}: reset_classifier changed {key}"
    assert model.spec.num_classes == 3 and model.spec.class_names == ("class_0", "class_1", "class_2")
    x, g, _ = make_batch(spec, 4, seed=3)
    out = model.train()(x, g)
    assert out.shape == (4, 3)
    out.sum().backward()
    assert new.weight.grad is not None
    if name in STREAMING:  # the streaming state follows the new width
        model.eval()
        with torch.no_grad():
            state = model.init_state(4)
            for t in range(spec.num_steps):
                scores, state = model.step(x[:, t], g[:, t], state)
            assert scores.shape == (4, 3)
            assert torch.allclose(scores, model(x, g), atol=1e-5)


@pytest.mark.parametrize("name", MODELS)
def test_create_model_with_num_classes_builds_that_many_outputs(name: str) -> None:
    spec = make_spec("neutouch")
    model = tz.create_model(name, spec, num_classes=7)
    x, g, _ = make_batch(spec, 2, seed=4)
    assert model(x, g).shape == (2, 7)
    assert model.spec.num_classes == 7 and model.spec.class_names[-1] == "class_6"
    assert tz.create_model(name, spec, num_classes=spec.num_classes).spec == spec  # the same count: the same spec


class _PluginNet(nn.Module):
    """A plugin model with none of the classifier methods: a feature layer, dropout, and a last ``nn.Linear``."""

    def __init__(self, spec: tz.DatasetSpec) -> None:
        super().__init__()
        self.spec = spec
        self.body = nn.Linear(spec.num_nodes * spec.num_channels, 8)
        self.out = nn.Linear(8, spec.num_classes)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        return self.out(torch.tanh(self.body(x.mean(1).flatten(1))))


def test_the_fallbacks_serve_a_model_without_the_methods() -> None:
    spec = make_spec("neutouch")
    model = _PluginNet(spec)
    x, g, _ = make_batch(spec, 4, seed=5)
    features = classifier.forward_features(model, x, g)  # the input of its last nn.Linear
    assert torch.equal(features, torch.tanh(model.body(x.mean(1).flatten(1))))
    classifier.reset_classifier(model, 2)
    assert model(x, g).shape == (4, 2) and model.spec.num_classes == 2
    with pytest.raises(tz.ConfigError, match="num_classes must be a positive integer"):
        classifier.reset_classifier(model, 0)


class _MixinOnly(classifier.ClassifierMixin, _PluginNet):
    """A plugin model that takes the mixin but defines neither forward_features nor forward_head."""


def test_the_mixin_without_its_methods_falls_back_too() -> None:
    spec = make_spec("neutouch")
    model = _MixinOnly(spec)
    x, g, _ = make_batch(spec, 3, seed=6)
    assert torch.equal(classifier.forward_features(model, x, g), torch.tanh(model.body(x.mean(1).flatten(1))))
    assert model.get_classifier() is model.out
    model.reset_classifier(4)
    assert model(x, g).shape == (3, 4)
