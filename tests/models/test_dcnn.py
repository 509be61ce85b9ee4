"""D-CNN: the time x feature image, Keras-equivalent layers, the source's layer sizes, prefixes padded."""

from __future__ import annotations

import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError


def spec_for(sensor: str, steps: int, channels: int, globals_: int, classes: int = 7) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec("t", classes, tuple(map(str, range(classes))), steps, s.num_nodes, channels, globals_, s)


AUGMENT8000 = spec_for("optoforce3", 50, 4, 3)  # 3 sensors x 4 force channels + 3 finger positions = 15 features
EV_OBJECTS = spec_for("neutouch", 250, 2, 0, 36)


def test_image_rows_are_node_major_features_then_globals() -> None:
    model = tz.create_model("dcnn", AUGMENT8000)
    x = torch.arange(2 * 50 * 12, dtype=torch.float32).view(2, 50, 3, 4)
    g = -torch.arange(2 * 50 * 3, dtype=torch.float32).view(2, 50, 3) - 1
    img = model.image(x, g)
    assert img.shape == (2, 1, 50, 15)  # the source's 50 x 15 image
    assert torch.equal(img[1, 0, 7, :12], x[1, 7].reshape(12))  # sensor 0 fx..f_norm, sensor 1 ...
    assert torch.equal(img[1, 0, 7, 12:], g[1, 7])


@pytest.mark.parametrize(("spec", "flat"), [(AUGMENT8000, 57 * 7 * 2), (EV_OBJECTS, 57 * 32 * 10)])
def test_layer_sizes_follow_the_source(spec: DatasetSpec, flat: int) -> None:
    model = tz.create_model("dcnn", spec)
    convs = [m for m in model.features.modules() if isinstance(m, nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size) for c in convs] == [(31, (1, 2)), (128, (2, 3)), (57, (3, 1))]
    dense = [m for m in model.classifier if isinstance(m, nn.Linear)]
    # "same" convs keep the size, each "same" pool halves it rounding up: 50x15 -> 25x8 -> 13x4 -> 7x2
    assert [(d.in_features, d.out_features) for d in dense] == [(flat, 103), (103, 138), (138, spec.num_classes)]
    bns = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    assert len(bns) == 5 and all(b.momentum == 0.1 and b.eps == 1e-3 for b in bns)  # Keras eps, see the card
    assert all(torch.equal(m.bias, torch.zeros_like(m.bias)) for m in convs + dense)
    assert model(torch.rand(3, spec.num_steps, spec.num_nodes, spec.num_channels),
                 torch.rand(3, spec.num_steps, spec.num_globals)).shape == (3, spec.num_classes)


def test_keras_same_padding_puts_the_odd_cell_after() -> None:
    model = tz.create_model("dcnn", AUGMENT8000)
    pad, conv = model.features[0][0], model.features[0][1]  # the 1x2 conv
    with torch.no_grad():
        conv.weight.zero_()
        conv.weight[:, 0, 0, 1] = 1.0  # picks the right-hand neighbour
    img = torch.rand(1, 1, 4, 5)
    out = conv(pad(img))[0, 0]
    assert out.shape == (4, 5)
    assert torch.equal(out[:, :4], img[0, 0, :, 1:]) and torch.equal(out[:, 4], torch.zeros(4))


def test_same_pooling_keeps_the_last_odd_row() -> None:
    block = tz.create_model("dcnn", AUGMENT8000).features[0]
    pool = block[-1]
    x = torch.zeros(1, 1, 3, 3)
    x[0, 0, 2, 2] = 5.0  # only the last row/column, which a floor-mode pool would drop
    assert pool(x).shape == (1, 1, 2, 2) and pool(x)[0, 0, 1, 1] == 5.0


def test_prefix_is_zero_padded_and_longer_input_is_refused() -> None:
    torch.manual_seed(0)
    model = tz.create_model("dcnn", AUGMENT8000).eval()
    x, g = torch.rand(2, 20, 3, 4), torch.rand(2, 20, 3)
    padded_x = torch.cat([x, torch.zeros(2, 30, 3, 4)], 1)
    padded_g = torch.cat([g, torch.zeros(2, 30, 3)], 1)
    with torch.no_grad():
        assert torch.allclose(model(x, g), model(padded_x, padded_g))
    with pytest.raises(ConfigError, match="50 time steps"):
        model(torch.rand(2, 51, 3, 4), torch.rand(2, 51, 3))
    with pytest.raises(ConfigError, match="global"):
        model(x)


def test_not_causal_and_channels_last_inside() -> None:
    meta = tz.registry.get_model_entry("dcnn").meta
    assert meta["causal"] is False and meta["streaming"] is False
    recipe = meta["recipe"]
    assert (recipe["optimizer"], recipe["lr"], recipe["batch_size"], recipe["max_epochs"], recipe["patience"]) == \
        ("adam", 1e-2, 128, 300, 30)
    model = tz.create_model("dcnn", EV_OBJECTS)
    conv = model.features[1][1]
    assert conv.weight.is_contiguous(memory_format=torch.channels_last)


def test_keras_running_statistics_on_request() -> None:
    keras = tz.create_model("dcnn", AUGMENT8000, bn_momentum=0.01)  # Keras' momentum=0.99
    bns = [m for m in keras.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    assert all(b.momentum == 0.01 and b.eps == 1e-3 for b in bns)
    with pytest.raises(ConfigError, match="bn_momentum"):
        tz.create_model("dcnn", AUGMENT8000, bn_momentum=0.0)


def test_running_statistics_start_from_the_first_batch() -> None:
    torch.manual_seed(1)
    model = tz.create_model("dcnn", AUGMENT8000).train()
    bn = model.features[0][3]  # the first block's batch norm
    x, g = torch.rand(8, 50, 3, 4) * 0.05, torch.rand(8, 50, 3) * 0.05
    acts = []
    hook = model.features[0][2].register_forward_hook(lambda m, i, o: acts.append(o.detach().clone()))
    with torch.no_grad():
        model(x, g)
        first_mean, first_var = bn.running_mean.clone(), bn.running_var.clone()
        model(x.flip(0) * 2, g)
    hook.remove()
    a1, a2 = acts[0], acts[1]  # the ReLU outputs the batch norm saw
    mean1, var1 = a1.mean((0, 2, 3)), a1.var((0, 2, 3), unbiased=True)
    assert torch.allclose(first_mean, mean1, atol=1e-6) and torch.allclose(first_var, var1, rtol=1e-4)
    mean2 = a2.mean((0, 2, 3))  # afterwards an ordinary moving average with the configured momentum
    assert torch.allclose(bn.running_mean, 0.9 * mean1 + 0.1 * mean2, atol=1e-6)
    assert bn.momentum == 0.1


@pytest.mark.parametrize("spec", [AUGMENT8000, spec_for("neutouch", 41, 2, 0, 5)])  # odd sizes: partial windows
def test_pooling_that_keeps_only_indices_trains_exactly_like_maxpool2d(spec: DatasetSpec) -> None:
    """The blocks' pools keep only their argmax indices for the backward pass (memory, see ``_IndexOnlyMaxPool``);
    outputs, gradients, batch-norm statistics and the weights after Adam steps equal ``nn.MaxPool2d``'s bit for bit."""
    import copy

    torch.manual_seed(2)
    ours = tz.create_model("dcnn", spec).train()
    ref = copy.deepcopy(ours)
    for block in ref.features:
        block[-1] = nn.MaxPool2d(2, ceil_mode=True)
    assert all(type(block[-1]) is not nn.MaxPool2d for block in ours.features)
    opts = [torch.optim.Adam(m.parameters(), lr=1e-2) for m in (ours, ref)]
    gen = torch.Generator().manual_seed(3)
    for _ in range(3):
        x = torch.relu(torch.randn(6, spec.num_steps, spec.num_nodes, spec.num_channels, generator=gen))  # ties: 0s
        g = torch.randn(6, spec.num_steps, spec.num_globals, generator=gen) if spec.num_globals else None
        y = torch.randint(spec.num_classes, (6,), generator=gen)
        outs = []
        for model, opt in zip((ours, ref), opts):
            opt.zero_grad(set_to_none=True)
            out = model(x, g)
            nn.functional.cross_entropy(out, y).backward()
            opt.step()
            outs.append(out.detach())
        assert torch.equal(outs[0], outs[1])
        for (name, a), b in zip(ours.named_parameters(), ref.parameters()):
            assert torch.equal(a.grad, b.grad) and torch.equal(a, b), name
    for a, b in zip(ours.buffers(), ref.buffers()):
        assert torch.equal(a, b)
    with torch.no_grad():
        assert torch.equal(ours.eval()(x, g), ref.eval()(x, g))
