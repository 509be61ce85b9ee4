"""D-CNN from the released Keras 2.2.4 HDF5 models: ``from_keras`` against an independent NumPy forward pass.

The fixture files copy the released layout (``model_config`` JSON and ``keras_version``/``backend`` on the root,
``model_weights/<layer>/<layer>_1/<weight>:0`` with ``layer_names``/``weight_names`` attributes). The reference below
is written channels-last as Keras computes, straight from the file's arrays. Its sizes make every mapping mistake
visible: odd image sides (21 x 15, then 11 x 8 before the 2x3 kernel) so where the odd padding cell of an even kernel
or pool goes matters, a non-square 3 x 2 final map with several channels so the flatten order matters, and batch-norm
variances near 1e-3 so the epsilon matters. ``test_each_mapping_mistake_is_caught`` shows, per mistake, that the
reference with that mistake disagrees with our model and agrees with our model made to commit it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from torch import nn

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.data.spec import DatasetSpec
from tactile_zoo.errors import ConfigError
from tactile_zoo.models.dcnn import DCNN, from_keras

FILTERS, KERNELS, DENSE = (3, 4, 5), ((1, 2), (2, 3), (3, 1)), (6, 7)  # the source's kernels, small widths
STEPS = 21  # 21 x 15 -> 11 x 8 -> 6 x 4 -> 3 x 2
MISTAKES = ("kernel_layout", "bn_eps", "conv_padding", "pool_padding", "flatten_order")


def make_spec(steps: int = STEPS, sensor: str = "optoforce3", channels: int = 4, globals_: int = 3,
              classes: int = 4) -> DatasetSpec:
    s = tz.get_sensor(sensor)
    return DatasetSpec("t", classes, tuple(map(str, range(classes))), steps, s.num_nodes, channels, globals_, s)


def _layer(kind: str, name: str, **cfg: Any) -> dict[str, Any]:
    return {"class_name": kind, "config": {"name": name, "trainable": True, **cfg}}


def _bn_weights(rng: np.random.Generator, y: np.ndarray) -> dict[str, np.ndarray]:
    """Batch-norm weights whose moving statistics are near those of the activations ``y`` (channels last)."""
    axes = tuple(range(y.ndim - 1))
    mean, var = y.mean(axes), np.maximum(y.var(axes), 1e-4)  # a floor for channels the ReLU leaves dead
    n = len(mean)
    return {"gamma": rng.uniform(0.5, 1.5, n), "beta": rng.normal(0, 0.2, n),
            "moving_mean": mean + rng.normal(0, 0.1, n) * np.sqrt(var),
            "moving_variance": var * rng.uniform(0.7, 1.3, n)}


def random_weights(steps: int, features: int, classes: int, seed: int = 0) -> dict[str, dict[str, np.ndarray]]:
    """Random D-CNN weights in a sensible regime: on standard-normal images every batch norm sees activations of
    variance about 2e-3 (so epsilon 1e-3 against 1e-5 changes its scale by ~20 %) and moving statistics near the
    true ones (so nothing saturates the softmax). Calibrated with the reference's own layers, Keras' order."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(16, steps, features, 1))
    out: dict[str, dict[str, np.ndarray]] = {}

    def calibrated(name: str, kernel: np.ndarray, bias: np.ndarray, y: np.ndarray) -> np.ndarray:
        # ReLU is positively homogeneous: scaling kernel and bias by s scales the activations y by s
        s = np.sqrt(2e-3 / y.var())
        out[name] = {"kernel": kernel * s, "bias": bias * s}
        return y * s

    cin = 1
    for i, (f, k) in enumerate(zip(FILTERS, KERNELS)):
        kernel, bias = rng.normal(0, 1 / np.sqrt(cin * k[0] * k[1]), (*k, cin, f)), rng.normal(0, 0.3, f)
        y = calibrated(f"conv2d_{i + 1}", kernel, bias, np.maximum(np_conv_same(x, kernel, bias), 0))
        out[f"batch_normalization_{i + 1}"] = _bn_weights(rng, y)
        x, cin = np_pool_same(np_bn(y, out[f"batch_normalization_{i + 1}"], 1e-3)), f
    x = x.reshape(len(x), -1)
    widths = [x.shape[1], *DENSE]
    for i in range(2):
        kernel, bias = rng.normal(0, 1 / np.sqrt(widths[i]), widths[i:i + 2]), rng.normal(0, 0.3, widths[i + 1])
        y = calibrated(f"dense_{i + 1}", kernel, bias, np.maximum(x @ kernel + bias, 0))
        out[f"batch_normalization_{i + 4}"] = _bn_weights(rng, y)
        x = np_bn(y, out[f"batch_normalization_{i + 4}"], 1e-3)
    out["dense_3"] = {"kernel": rng.normal(0, 2 / np.sqrt(DENSE[1]), (DENSE[1], classes)),
                      "bias": rng.normal(0, 0.3, classes)}
    return {layer: {k: v.astype(np.float32) for k, v in ws.items()} for layer, ws in out.items()}


def write_keras_dcnn(path: Path, steps: int, features: int, classes: int, seed: int = 0,
                     **override: Any) -> dict[str, dict[str, np.ndarray]]:
    """A full-model Keras 2.2.4 file of a small D-CNN with :func:`random_weights`; returns them
    (``{layer: {weight: array}}``). ``override`` replaces config keys of every layer that has them
    (``padding="valid"``)."""
    h5py = pytest.importorskip("h5py")
    weights = random_weights(steps, features, classes, seed)
    bn = {"axis": -1, "momentum": 0.99, "epsilon": 0.001, "center": True, "scale": True}
    layers = []
    for i, (f, k) in enumerate(zip(FILTERS, KERNELS)):
        conv = _layer("Conv2D", f"conv2d_{i + 1}", filters=f, kernel_size=list(k), strides=[1, 1], padding="same",
                      data_format="channels_last", dilation_rate=[1, 1], activation="relu", use_bias=True)
        if i == 0:
            conv["config"]["batch_input_shape"] = [None, steps, features, 1]
        layers += [conv, _layer("BatchNormalization", f"batch_normalization_{i + 1}", **bn),
                   _layer("MaxPooling2D", f"max_pooling2d_{i + 1}", pool_size=[2, 2], padding="same",
                          strides=[2, 2], data_format="channels_last")]
    layers.append(_layer("Flatten", "flatten_1", data_format="channels_last"))
    for i, units in enumerate((*DENSE, classes)):
        layers.append(_layer("Dense", f"dense_{i + 1}", units=units, use_bias=True,
                             activation="softmax" if i == 2 else "relu"))
        if i < 2:
            layers.append(_layer("BatchNormalization", f"batch_normalization_{i + 4}", **bn))
    for layer in layers:
        layer["config"].update({k: v for k, v in override.items() if k in layer["config"]})
    config = {"class_name": "Sequential", "config": {"name": "sequential_1", "layers": layers}}
    with h5py.File(path, "w") as f:
        f.attrs["keras_version"], f.attrs["backend"] = "2.2.4", "tensorflow"
        f.attrs["model_config"] = json.dumps(config)
        f.attrs["training_config"] = json.dumps({"loss": "categorical_crossentropy", "metrics": ["accuracy"]})
        group = f.create_group("model_weights")
        group.attrs["keras_version"], group.attrs["backend"] = "2.2.4", "tensorflow"
        names = [layer["config"]["name"] for layer in layers]
        group.attrs["layer_names"] = np.array(names, dtype="S")
        for name in names:
            g = group.create_group(name)
            ws = weights.get(name, {})
            # as Keras writes them: "<layer>_1/kernel:0", ...; an empty float array for a layer without weights
            g.attrs["weight_names"] = np.array([f"{name}_1/{k}:0" for k in ws], dtype="S") if ws else np.array([])
            for k, v in ws.items():
                g[f"{name}_1/{k}:0"] = v
    return weights


# ------------------------------------------------------------------------------- the NumPy reference, channels-last
def np_conv_same(x: np.ndarray, k: np.ndarray, b: np.ndarray, odd_cell_before: bool = False) -> np.ndarray:
    kh, kw = k.shape[:2]
    top, left = (kh - 1) // 2, (kw - 1) // 2  # TensorFlow: the odd cell of an even kernel goes after
    if odd_cell_before:
        top, left = kh - 1 - top, kw - 1 - left
    xp = np.pad(x, ((0, 0), (top, kh - 1 - top), (left, kw - 1 - left), (0, 0)))
    hh, ww = x.shape[1:3]
    out = np.zeros((*x.shape[:3], k.shape[3])) + b
    for i in range(kh):
        for j in range(kw):
            out += xp[:, i:i + hh, j:j + ww, :] @ k[i, j]
    return out


def np_pool_same(x: np.ndarray, odd_cell_before: bool = False) -> np.ndarray:
    b, hh, ww, c = x.shape
    ph, pw = hh % 2, ww % 2  # TensorFlow SAME: out = ceil(n / 2), the padding (-inf) after
    pads = ((0, 0), (ph, 0) if odd_cell_before else (0, ph), (pw, 0) if odd_cell_before else (0, pw), (0, 0))
    xp = np.pad(x, pads, constant_values=-np.inf)
    return xp.reshape(b, (hh + ph) // 2, 2, (ww + pw) // 2, 2, c).max(axis=(2, 4))


def np_bn(x: np.ndarray, w: dict[str, np.ndarray], eps: float) -> np.ndarray:
    return (x - w["moving_mean"]) / np.sqrt(w["moving_variance"] + eps) * w["gamma"] + w["beta"]


def np_dcnn(image: np.ndarray, weights: dict[str, dict[str, np.ndarray]], mistake: str | None = None) -> np.ndarray:
    """Keras' forward pass of the D-CNN in float64 on ``image (B, H, W, 1)``: softmax probabilities. ``mistake``
    commits one of :data:`MISTAKES` instead."""
    w64 = {layer: {k: v.astype(np.float64) for k, v in ws.items()} for layer, ws in weights.items()}
    eps = 1e-5 if mistake == "bn_eps" else 1e-3
    x = image.astype(np.float64)
    for i in range(3):
        k = w64[f"conv2d_{i + 1}"]["kernel"]
        if mistake == "kernel_layout":  # the (kh, kw, in, out) buffer read as PyTorch's (out, in, kh, kw)
            k = k.reshape(k.shape[3], k.shape[2], *k.shape[:2]).transpose(2, 3, 1, 0)
        x = np.maximum(np_conv_same(x, k, w64[f"conv2d_{i + 1}"]["bias"], mistake == "conv_padding"), 0)
        x = np_pool_same(np_bn(x, w64[f"batch_normalization_{i + 1}"], eps), mistake == "pool_padding")
    x = (x.transpose(0, 3, 1, 2) if mistake == "flatten_order" else x).reshape(len(x), -1)  # Keras: (H, W, C)
    for i in range(3):
        x = x @ w64[f"dense_{i + 1}"]["kernel"] + w64[f"dense_{i + 1}"]["bias"]
        if i < 2:
            x = np_bn(np.maximum(x, 0), w64[f"batch_normalization_{i + 4}"], eps)
    e = np.exp(x - x.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


class _PoolOddCellBefore(nn.Module):
    """A "same" 2x2 max pool that pads an odd side before instead of after (the mistake, for the model)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return nn.functional.max_pool2d(nn.functional.pad(x, (x.shape[3] % 2, 0, x.shape[2] % 2, 0),
                                                          value=float("-inf")), 2)


def commit(model: DCNN, mistake: str, weights: dict[str, dict[str, np.ndarray]]) -> DCNN:
    """Our model as a mapping with ``mistake`` would build it."""
    with torch.no_grad():
        for i, block in enumerate(model.features):
            if mistake == "kernel_layout":
                k = weights[f"conv2d_{i + 1}"]["kernel"]
                block[1].weight.copy_(torch.from_numpy(k.reshape(block[1].weight.shape)))
            elif mistake == "conv_padding":
                left, right, top, bottom = block[0].padding
                block[0].padding = (right, left, bottom, top)
            elif mistake == "pool_padding":
                block[4] = _PoolOddCellBefore()
        if mistake == "bn_eps":
            for m in model.modules():
                if isinstance(m, nn.modules.batchnorm._BatchNorm):
                    m.eps = 1e-5
        elif mistake == "flatten_order":  # Keras' (H, W, C) columns used on our (C, H, W) flatten unchanged
            model.classifier[1].weight.copy_(torch.from_numpy(weights["dense_1"]["kernel"].T))
    return model


def probabilities(model: nn.Module, x: torch.Tensor, g: torch.Tensor) -> np.ndarray:
    with torch.no_grad():
        return torch.softmax(model(x, g), dim=-1).double().numpy()


@pytest.fixture(scope="module")
def released(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict[str, np.ndarray]], DatasetSpec]:
    path = tmp_path_factory.mktemp("keras") / "dcnn.h5"
    return path, write_keras_dcnn(path, STEPS, 15, 4), make_spec()


@pytest.fixture(scope="module")
def inputs() -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    gen = torch.Generator().manual_seed(0)
    x, g = torch.randn(5, STEPS, 3, 4, generator=gen), torch.randn(5, STEPS, 3, generator=gen)
    image = torch.cat([x.reshape(5, STEPS, 12), g], -1).unsqueeze(-1).numpy()  # (B, T, 15, 1), channels-last
    return x, g, image


def test_matches_the_keras_forward_pass(released, inputs) -> None:
    path, weights, spec = released
    x, g, image = inputs
    model = from_keras(path, spec)
    assert isinstance(model, DCNN) and not model.training
    assert all(int(m.num_batches_tracked) == 1 for m in model.modules() if isinstance(m, nn.BatchNorm2d))
    expected = np_dcnn(image, weights)
    assert np.allclose(probabilities(model, x, g), expected, rtol=1e-4, atol=1e-6)
    assert len(set(expected.argmax(1))) > 1  # not a degenerate fixture
    via_registry = tz.registry.get_model_entry("dcnn").obj.from_keras(path, spec)
    assert np.array_equal(probabilities(via_registry, x, g), probabilities(model, x, g))


@pytest.mark.parametrize("mistake", MISTAKES)
def test_each_mapping_mistake_is_caught(released, inputs, mistake: str) -> None:
    path, weights, spec = released
    x, g, image = inputs
    right, wrong = np_dcnn(image, weights), np_dcnn(image, weights, mistake)
    ours = probabilities(from_keras(path, spec), x, g)
    mistaken = probabilities(commit(from_keras(path, spec), mistake, weights), x, g)
    assert np.abs(wrong - right).max() > 0.1  # the fixture makes the mistake visible ...
    assert np.abs(ours - wrong).max() > 0.1  # ... our mapping does not make it ...
    assert np.allclose(mistaken, wrong, rtol=1e-4, atol=1e-6)  # ... and a mapping that did would fail the test above
    assert np.abs(mistaken - right).max() > 0.1


@pytest.mark.parametrize(("override", "message"), [
    ({"padding": "valid"}, "padding='valid'"),
    ({"epsilon": 1e-5}, "epsilon=1e-05"),
    ({"activation": "tanh"}, "activation 'tanh'"),
])
def test_settings_we_do_not_compute_are_refused(tmp_path: Path, override: dict[str, Any], message: str) -> None:
    path = tmp_path / "other.h5"
    write_keras_dcnn(path, STEPS, 15, 4, **override)
    with pytest.raises(ConfigError, match=message):
        from_keras(path, make_spec())


def test_wrong_dataset_missing_file_and_missing_h5py(released, tmp_path: Path, monkeypatch) -> None:
    path, _, spec = released
    with pytest.raises(ConfigError, match=r"input shape \(21, 15, 1\).*\(22, 15, 1\)"):
        from_keras(path, make_spec(steps=22))
    with pytest.raises(ConfigError, match="4 classes"):
        from_keras(path, make_spec(classes=5))
    (tmp_path / "not.h5").write_text("no HDF5 here")
    with pytest.raises(ConfigError, match="cannot be read as an HDF5 file"):
        from_keras(tmp_path / "not.h5", spec)
    monkeypatch.setitem(sys.modules, "h5py", None)  # as if it were not installed
    with pytest.raises(ConfigError, match="pip install h5py"):
        from_keras(path, spec)


def test_cli_evaluates_a_keras_file(tmp_path: Path, capsys) -> None:
    spec = tz.load_dataset("sim_biotac_slip", root=tmp_path, split="test").spec  # 30 steps x 24 electrodes
    path = tmp_path / "sim.hdf5"
    write_keras_dcnn(path, spec.num_steps, spec.num_nodes * spec.num_channels + spec.num_globals, spec.num_classes)
    args = ["evaluate", str(path), "sim_biotac_slip", "--root", str(tmp_path), "--device", "cpu"]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    split = tz.load_dataset("sim_biotac_slip", root=tmp_path, split="test")
    direct = tz.evaluate(from_keras(path, spec), split)
    assert (out["model"], out["split"], out["n"]) == ("dcnn", "test", len(split))
    assert out["accuracy"] == direct.metrics["accuracy"]
    assert main([*args, "--split", "all", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n"] == len(tz.load_dataset("sim_biotac_slip", root=tmp_path))
    assert main(["evaluate", str(path), "--root", str(tmp_path)]) == 2  # a Keras file names no dataset
    assert "give DATASET" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "none.h5"), "sim_biotac_slip"]) == 2
    assert "does not exist" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ the real files
def test_released_models_on_the_real_life_samples(shared_data: Path) -> None:
    """The ten released models on the 120 real-life samples: 871 of 1200 correct (the paper's 0.7258), +-5; and the
    NumPy reference agrees with the mapped model on real weights and data."""
    folder = shared_data / "augment8000" / "released_models"
    files = [folder / f"VGG16_scaling_time_warp{i}.h5" for i in range(1, 11)]
    if not all(f.is_file() for f in files) or not (shared_data / "augment8000" / "raw").is_dir():
        pytest.skip(f"the released Augment8000 models or the real-life file are not under {shared_data}")
    h5py = pytest.importorskip("h5py")
    with pytest.warns(UserWarning, match="000_training_data.csv is missing"):
        data = tz.load_dataset("augment8000", root=shared_data, split=None, stats="source")
    assert len(data) == 120
    correct = []
    for file in files:
        model = from_keras(file, data.spec)
        with torch.no_grad():
            correct.append(int((model(data.x, data.g).argmax(-1) == data.y).sum()))
    assert abs(sum(correct) - 871) <= 5, correct
    with h5py.File(files[0], "r") as f:
        group = f["model_weights"]
        weights = {}
        for layer in (n.decode() for n in group.attrs["layer_names"]):
            names = [n.decode() for n in group[layer].attrs["weight_names"]]
            weights[layer.rsplit("_", 1)[0] + f"_{_position(layer, group)}"] = {
                n.rsplit("/", 1)[1].split(":")[0]: group[layer][n][()] for n in names}
    image = torch.cat([data.x[:8].reshape(8, 50, 12), data.g[:8]], -1).unsqueeze(-1).numpy()
    assert np.allclose(probabilities(from_keras(files[0], data.spec), data.x[:8], data.g[:8]),
                       np_dcnn(image, weights), rtol=1e-3, atol=1e-5)


def _position(layer: str, group: Any) -> int:
    """The 1-based position of ``layer`` among the file's layers of its kind (conv2d_92 -> 2), the fixture's names."""
    kind = layer.rsplit("_", 1)[0]
    same = [n.decode() for n in group.attrs["layer_names"] if n.decode().rsplit("_", 1)[0] == kind]
    return same.index(layer) + 1
