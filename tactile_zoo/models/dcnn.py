"""D-CNN: a 2-D CNN over the time x feature image of a whole grasp (Maus et al., Augment8000; code:
github.com/philipmaus/Tactile_Object_Classification, Keras).

A sample becomes one single-channel image whose rows are time steps and whose columns are the features of a step:
on Augment8000 50 x 15 (3 OptoForce sensors x 4 force channels, then the 3 finger positions); on any other dataset
the ``N x C`` taxel channels flattened node-major, then the ``G`` globals (Ev-Objects: 250 x 78)::

    (B, T, N, C) [++ g] -> (B, 1, T, N*C + G)
    -> Conv 31 (1x2, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Conv 128 (2x3, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Conv 57 (3x1, same) -> ReLU -> BN -> MaxPool 2x2 (same)
    -> Flatten -> Dense 103 -> ReLU -> BN -> Dense 138 -> ReLU -> BN -> Dense K

Keras semantics in PyTorch: "same" convolution and pooling as TensorFlow pads, batch-norm epsilon 1e-3,
Glorot-uniform kernels and zero biases. The flatten size fixes the input length to ``spec.num_steps`` frames; the
model is not causal.

:func:`from_keras` builds the model from one of the source's released Keras 2.2.4 HDF5 files (evaluation of the
published weights; needs the optional ``h5py``).
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..data.spec import DatasetSpec
from ..errors import ConfigError
from ..nn import hugepages
from ..nn.backend import BatchNormStats, resolve
from ..nn.batch_norm import BatchNorm1d, BatchNorm2d
from ..nn.classifier import ClassifierMixin
from ..nn.hooks import has_hooks
from ..registry import recipe_file, register_model
from ._inputs import check_inputs

__all__ = ["DCNN", "from_keras"]

KERAS_BN_MOMENTUM = 0.01  # Keras' BatchNormalization(momentum=0.99) in PyTorch terms
BN_EPS = 1e-3  # Keras' BatchNormalization epsilon


class _FirstBatchStats:
    """Batch norm whose running statistics start from the first training batch instead of (mean 0, var 1).

    The running averages are exponential moving averages; started at (0, 1) they carry that start for ~1/momentum
    updates. On Ev-Objects the first block's activation variance is ~0.003, so with Keras' momentum the eval-mode
    statistics stay hundreds of times too large for ~150 epochs (4 updates per epoch) and validation sits at chance.
    Taking the first batch's statistics whole (momentum 1 once) removes the start value, as bias correction does for
    Adam; every later update is the ordinary moving average.
    """

    momentum: float | None
    num_batches_tracked: Tensor | None

    def forward(self, x: Tensor) -> Tensor:
        return self._first_batch_whole(super().forward, x)  # type: ignore[misc]

    def relu_pool(self, x: Tensor) -> Tensor | None:
        return self._first_batch_whole(super().relu_pool, x)  # type: ignore[misc]

    def _first_batch_whole(self, call: Any, x: Tensor) -> Any:
        if self.training and self.num_batches_tracked is not None and int(self.num_batches_tracked) == 0:
            momentum, self.momentum = self.momentum, 1.0
            try:
                return call(x)
            finally:
                self.momentum = momentum
        return call(x)


class _BatchNorm2d(_FirstBatchStats, BatchNorm2d):
    pass


class _BatchNorm1d(_FirstBatchStats, BatchNorm1d):
    pass


def _pooled(size: int, times: int) -> int:
    for _ in range(times):
        size = math.ceil(size / 2)
    return size


class _IndexOnlyMaxPool(torch.autograd.Function):
    """2x2 max pooling, stride 2, "same" (ceil mode), whose backward keeps only the argmax indices.

    ``nn.MaxPool2d`` keeps its input alive for the backward pass, though the CPU kernel reads nothing of it but its
    shape and layout. Here that input is the batch norm's output, which nothing else needs: at batch 128 on
    Ev-Containers' 325 x 78 images the three blocks' outputs are 870 MB of the 2.3 GB a training step keeps. The
    forward and backward kernels are the same ATen ones, so outputs and gradients are bit-identical. Used on CPU
    only (where that is what the kernel does) and once-differentiable (no gradient of the gradient through the pool).
    """

    @staticmethod
    def forward(ctx: Any, x: Tensor) -> Tensor:
        out, idx = F.max_pool2d(x, 2, 2, 0, 1, ceil_mode=True, return_indices=True)
        ctx.save_for_backward(idx)
        # the gradient gets the layout ATen's backward would give it (channels-last here, see DCNN.__init__)
        layout = torch.channels_last if x.dim() == 4 and not x.is_contiguous() and \
            x.is_contiguous(memory_format=torch.channels_last) else torch.contiguous_format
        ctx.input_meta = (x.shape, x.dtype, x.device, layout)
        ctx.mark_non_differentiable(idx)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: Any, grad: Tensor) -> Tensor:
        (idx,) = ctx.saved_tensors
        shape, dtype, device, layout = ctx.input_meta
        if layout == torch.channels_last:  # (N, H, W, C) in memory, seen as (N, C, H, W): channels-last strides
            grad_in = hugepages.empty((shape[0], shape[2], shape[3], shape[1]), grad).permute(0, 3, 1, 2)
        else:
            grad_in = hugepages.empty(shape, grad)  # (N, C, H, W)
        # huge pages when large (hugepages.empty): the kernel zero-fills all of grad_in first, and on fresh 4 KiB pages
        # that fill faulted once per page (Ev-Objects, block 2: (128, 128, 125, 39), 312 MiB per step)
        # the kernel takes the input only for its shape and layout: the buffer stands in for it (it is zeroed first)
        return torch.ops.aten.max_pool2d_with_indices_backward.grad_input(
            grad, grad_in, [2, 2], [2, 2], [0, 0], [1, 1], True, idx, grad_input=grad_in)


class _SamePool(nn.MaxPool2d):
    """``nn.MaxPool2d(2, ceil_mode=True)`` (TensorFlow's "same" 2x2 pool) that keeps less for the backward pass."""

    def __init__(self) -> None:
        super().__init__(2, ceil_mode=True)

    def forward(self, x: Tensor) -> Tensor:
        if torch.is_grad_enabled() and x.requires_grad and x.device.type == "cpu":
            return _IndexOnlyMaxPool.apply(x)
        return super().forward(x)


class _ConvBlock(nn.Sequential):
    """Conv ("same") -> ReLU -> BN -> 2x2 max pool ("same"): the unit the D-CNN stacks three times. With ``fused``,
    a training batch runs ReLU -> BN -> pool as one compiled kernel (:mod:`tactile_zoo.nn.relu_bn_pool`) where it
    applies and no hook waits on those three modules; else, and in evaluation, the layers one after another."""

    def __init__(self, cin: int, cout: int, kernel: tuple[int, int], bn_momentum: float,
                 bn_stats: BatchNormStats = BatchNormStats.NATIVE, fused: bool = False) -> None:
        (kh, kw) = kernel
        # Keras/TF "same": total padding k - 1, the odd cell of an even kernel after (right/bottom)
        pad = (((kw - 1) // 2), kw - 1 - (kw - 1) // 2, (kh - 1) // 2, kh - 1 - (kh - 1) // 2)
        super().__init__(nn.ZeroPad2d(pad), nn.Conv2d(cin, cout, kernel), nn.ReLU(inplace=True),
                         _BatchNorm2d(cout, eps=BN_EPS, momentum=bn_momentum, stats=bn_stats), _SamePool())
        self.fused = fused

    def forward(self, x: Tensor) -> Tensor:
        pad, conv, relu, bn, pool = self
        x = conv(pad(x))  # (B, C, H, W), channels-last
        out = bn.relu_pool(x) if self.fused and not has_hooks(relu, bn, pool) else None
        return pool(bn(relu(x))) if out is None else out  # (B, C, ceil(H / 2), ceil(W / 2))


@register_model(
    "dcnn",
    paper="Tactile Object Classification (D-CNN on the Augment8000 OptoForce grasp data)",
    citation="P. Maus et al., D-CNN for tactile object classification; code: "
             "github.com/philipmaus/Tactile_Object_Classification",
    url="https://github.com/philipmaus/Tactile_Object_Classification",
    description="2-D CNN over the time x feature image of a grasp: three conv/ReLU/BN/max-pool blocks (31, 128, 57 "
                "filters), dense 103 and 138 with BN, linear classifier.",
    tags=["convolutional", "table1"],
    inputs=["globals"],
    display_name="D-CNN",
    family="2-D CNN over time x features",
    reference={"type": "article",
               "title": "Tactile object classification with a three-finger gripper: the D-CNN and the Augment8000 data "
                        "set",
               "authors": ["Maus, Philip", "Kim, Jaeseok", "Nocentini, Olivia", "Bashir, Muhammad Zain",
                           "Cavallo, Filippo"],
               "notes": "the Augment8000 dataset. Descriptive title: cite the publication named in the source "
                        "repository"},
    **recipe_file("tactile_zoo", "dcnn"),
    causal=False,
    streaming=False,
    # revision 2 (the default since issue 53): batch statistics accurate to a float64 copy on the CPU, and the running
    # statistics recomputed over the training split after training; 1 builds the committed cells (docs/revisions.md).
    # 3 (selectable until Table I has cells of it): ReLU -> batch norm -> pool fused, statistics summed in float64
    revision=2,
    revisions={1: {"bn_stats": "native", "precise_bn": False, "fused_blocks": False},
               2: {"bn_stats": "two_pass", "precise_bn": True, "fused_blocks": False},
               3: {"bn_stats": "two_pass", "precise_bn": True, "fused_blocks": True}},
)
class DCNN(ClassifierMixin, nn.Module):
    """D-CNN of Maus et al.: three conv blocks and two dense layers over the time x feature image.

    Departure (ours): batch-norm running statistics start from the first training batch and then average with
    momentum 0.1, not Keras' 0.01 (``bn_momentum=0.01`` restores Keras' averaging); a prefix shorter than
    ``num_steps`` is zero-padded at the end. Model card: docs/models.md, section "`dcnn`: D-CNN (Maus et al.)".

    Args:
        spec: the dataset's :class:`DatasetSpec` (fixes the image size ``num_steps x (N*C + G)``).
        filters: output channels of the three conv layers (source: 31, 128, 57).
        kernels: their kernel sizes (source: 1x2, 2x3, 3x1).
        dense: widths of the two hidden dense layers (source: 103, 138).
        bn_momentum: PyTorch momentum of the batch-norm running statistics (Keras: 0.01; default 0.1, see the card).
        bn_stats: how batch norm computes a training batch's statistics and its backward sums
            (:class:`~tactile_zoo.nn.backend.BatchNormStats`): ``"native"`` (torch's kernel; on the CPU, over the
            channels-last maps, scores 3e-2 from a float64 copy of the step), ``"two_pass"`` (float32 pairwise sums,
            two-pass variance; the default, revision 2) or ``"float64"`` (the same sums in float64); see
            :mod:`tactile_zoo.nn.batch_norm`.
        precise_bn: after training, the engine recomputes every batch norm's running statistics over the training
            split with the final weights (:func:`tactile_zoo.engine.train.recompute_bn_stats`), so evaluation does
            not read moving averages that lag the weights (seed 6 of the ``full`` recipe on Ev-Objects; on by default,
            revision 2; revision 1, every committed cell's, is ``bn_stats="native"``, ``precise_bn=False``).
        fused_blocks: a training batch runs each conv block's ReLU -> batch norm -> max pool as one compiled kernel
            with its statistics summed in float64 (:mod:`tactile_zoo.nn.relu_bn_pool`; CPU, float32), instead of
            the three layers with ``bn_stats``: revision 3, selectable (``create_model("dcnn", spec, revision=3)``),
            not yet the default. The same function, rounded differently (within 1e-7 of a float64 copy, relative).

    Shapes:
        ``x (B, T, N, C)`` with ``T <= num_steps``, ``g (B, T, G)`` or None -> logits ``(B, num_classes)``.
    """

    def __init__(self, spec: DatasetSpec, filters: tuple[int, int, int] = (31, 128, 57),
                 kernels: tuple[tuple[int, int], ...] = ((1, 2), (2, 3), (3, 1)),
                 dense: tuple[int, int] = (103, 138), bn_momentum: float = 0.1, bn_stats: str = "two_pass",
                 precise_bn: bool = True, fused_blocks: bool = False) -> None:
        super().__init__()
        if len(filters) != 3 or len(kernels) != 3 or len(dense) != 2:
            raise ConfigError(f"dcnn: need 3 filters, 3 kernels and 2 dense widths, got {filters}, {kernels}, {dense}")
        if not 0.0 < bn_momentum <= 1.0:
            raise ConfigError(f"dcnn: bn_momentum must lie in (0, 1], got {bn_momentum}")
        if not isinstance(precise_bn, bool):
            raise ConfigError(f"dcnn: precise_bn must be true or false, got {precise_bn!r}")
        if not isinstance(fused_blocks, bool):
            raise ConfigError(f"dcnn: fused_blocks must be true or false, got {fused_blocks!r}")
        stats = resolve(BatchNormStats, bn_stats, "bn_stats", "dcnn")
        #: read by the engine after training (tactile_zoo.engine.train): recompute the running statistics
        self.precise_bn = precise_bn
        bn = {"eps": BN_EPS, "momentum": bn_momentum, "stats": stats}
        self.spec = spec
        self.num_steps = spec.num_steps
        self.num_features = spec.num_nodes * spec.num_channels + spec.num_globals
        chans = (1, *filters)
        self.features = nn.Sequential(*(_ConvBlock(chans[i], chans[i + 1], tuple(kernels[i]), bn_momentum, stats,
                                                   fused_blocks) for i in range(3)))
        flat = filters[-1] * _pooled(self.num_steps, 3) * _pooled(self.num_features, 3)
        self.classifier = nn.Sequential(
            nn.Flatten(),
            nn.Linear(flat, dense[0]), nn.ReLU(inplace=True), _BatchNorm1d(dense[0], **bn),
            nn.Linear(dense[0], dense[1]), nn.ReLU(inplace=True), _BatchNorm1d(dense[1], **bn),
            nn.Linear(dense[1], spec.num_classes),
        )
        #: the final classifier layer, which ``create_model(..., pretrained=..., new_head=True)`` starts afresh
        self.zoo_head = f"classifier.{len(self.classifier) - 1}"
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)
        # channels-last convolution weights make every activation channels-last: CPU max pooling and batch norm
        # run several times faster on that layout than on NCHW (measured on Ev-Objects-sized images)
        self.features.to(memory_format=torch.channels_last)

    def image(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """The model's input image ``(B, 1, num_steps, N*C + G)`` of a batch."""
        g = check_inputs("dcnn", self.spec, x, g)
        b, t = x.shape[:2]
        if t > self.num_steps:
            raise ConfigError(f"dcnn: built for {self.num_steps} time steps (its dense layer depends on it), "
                              f"got {t}; build it for a spec with num_steps >= {t}")
        rows = x.reshape(b, t, -1)  # (B, T, N*C), node-major
        if g is not None:
            rows = torch.cat([rows, g], dim=-1)  # (B, T, N*C + G)
        rows = F.pad(rows, (0, 0, 0, self.num_steps - t))  # (B, num_steps, F): a prefix reads as zeros after it
        return rows.unsqueeze(1)  # (B, 1, num_steps, F)

    def forward(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        return self.classifier(self.features(self.image(x, g)))

    def forward_features(self, x: Tensor, g: Tensor | None = None) -> Tensor:
        """The last hidden dense layer's output ``(B, dense[1])``, which the classifier layer reads."""
        return self.classifier[:-1](self.features(self.image(x, g)))

    def forward_head(self, features: Tensor) -> Tensor:
        return self.classifier[-1](features)

    def _init_classifier(self, layer: nn.Linear) -> None:
        nn.init.xavier_uniform_(layer.weight)  # as the constructor initialises every layer
        nn.init.zeros_(layer.bias)

    @classmethod
    def from_keras(cls, path: str | os.PathLike, spec: DatasetSpec) -> DCNN:
        """:func:`from_keras` as a class method: the way in for the layers above the models, which reach a model
        only through the registry (``get_model_entry("dcnn").obj.from_keras(...)``)."""
        return from_keras(path, spec)


# ------------------------------------------------------------------------------------ released Keras weights
#: the layer classes of the source's Sequential D-CNN, in order
_KERAS_LAYERS = ("Conv2D", "BatchNormalization", "MaxPooling2D") * 3 + \
    ("Flatten", "Dense", "BatchNormalization", "Dense", "BatchNormalization", "Dense")


def _text(value: Any) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


def _keras_layers(file: Any, where: str) -> list[dict[str, Any]]:
    """The ``model_config`` layers of a full-model file as ``{"class_name", "config"}`` dicts, checked to be the
    D-CNN (an ``InputLayer``, which later Keras versions write, is dropped)."""
    if "model_config" not in file.attrs:
        raise ConfigError(f"{where}: no 'model_config' attribute; from_keras needs a full-model file saved by "
                          f"model.save() (a weights-only file does not say the architecture)")
    config = json.loads(_text(file.attrs["model_config"]))
    if config.get("class_name") != "Sequential":
        raise ConfigError(f"{where}: a Keras {config.get('class_name')!r} model; the D-CNN is a Sequential one")
    inner = config["config"]
    layers = inner["layers"] if isinstance(inner, dict) else inner  # Keras < 2.2.3 wrote the bare list
    layers = [layer for layer in layers if layer["class_name"] != "InputLayer"]
    found = tuple(layer["class_name"] for layer in layers)
    if found != _KERAS_LAYERS:
        raise ConfigError(f"{where}: the layers {', '.join(found)} are not the D-CNN's {', '.join(_KERAS_LAYERS)}")
    return layers


def _check_layer(layer: dict[str, Any], where: str, activation: str | tuple[str, ...] | None = None) -> None:
    """Refuse a setting our modules do not compute (they hard-code Keras' defaults and the source's choices)."""
    cfg, name = layer["config"], f"{where}: layer {layer['config'].get('name')!r}"
    expect: dict[str, Any] = {"data_format": "channels_last"}
    if layer["class_name"] == "Conv2D":
        expect.update(padding="same", strides=[1, 1], dilation_rate=[1, 1], use_bias=True)
    elif layer["class_name"] == "MaxPooling2D":
        expect.update(padding="same", pool_size=[2, 2], strides=[2, 2])
    elif layer["class_name"] == "BatchNormalization":
        expect = {"axis": -1, "epsilon": BN_EPS, "center": True, "scale": True}
    elif layer["class_name"] == "Dense":
        expect = {"use_bias": True}
    for key, want in expect.items():
        got = cfg.get(key)
        if (list(got) if isinstance(got, (list, tuple)) else got) != want:
            raise ConfigError(f"{name}: {key}={got!r}; the D-CNN mapping needs {key}={want!r}")
    wanted = (activation,) if isinstance(activation, str) else activation
    if wanted is not None and cfg.get("activation") not in wanted:
        raise ConfigError(f"{name}: activation {cfg.get('activation')!r}; the D-CNN has {' or '.join(wanted)} here")


def _keras_weights(file: Any, where: str) -> dict[str, dict[str, np.ndarray]]:
    """``{layer name: {"kernel" | "bias" | "gamma" | ...: float32 array}}`` found through the ``layer_names`` and
    ``weight_names`` attributes, as Keras itself loads them (the datasets sit at ``<layer>/<layer>_1/kernel:0``)."""
    group = file["model_weights"] if "model_weights" in file else file
    if "layer_names" not in group.attrs:
        raise ConfigError(f"{where}: no 'layer_names' attribute on the weights; not a Keras HDF5 model file")
    out: dict[str, dict[str, np.ndarray]] = {}
    for layer in map(_text, group.attrs["layer_names"]):
        names = [_text(n) for n in group[layer].attrs.get("weight_names", [])]
        # "conv2d_91_1/kernel:0" -> "kernel"
        out[layer] = {n.rsplit("/", 1)[-1].split(":")[0]: np.asarray(group[layer][n], dtype=np.float32) for n in names}
    return out


def _weight(weights: dict[str, dict[str, np.ndarray]], layer: str, name: str, ndim: int, where: str) -> np.ndarray:
    value = weights.get(layer, {}).get(name)
    if value is None:
        raise ConfigError(f"{where}: no weight {name!r} for layer {layer!r} under model_weights")
    if value.ndim != ndim:
        raise ConfigError(f"{where}: {layer}/{name} has shape {value.shape}, expected {ndim} dimensions")
    return value


def _assign(target: Tensor, value: np.ndarray, where: str) -> None:
    if tuple(target.shape) != value.shape:
        raise ConfigError(f"{where}: shape {value.shape} after the layout change, the model needs "
                          f"{tuple(target.shape)}")
    with torch.no_grad():
        target.copy_(torch.from_numpy(np.ascontiguousarray(value)))  # copy_ keeps the channels-last layout


def from_keras(path: str | os.PathLike, spec: DatasetSpec) -> DCNN:
    """Build a :class:`DCNN` for ``spec`` from a released Keras 2.2.4 HDF5 model file of the source
    (``VGG16_scaling_time_warp{1..10}.h5``: the file name says VGG16, the model inside is the D-CNN), in eval mode.

    The file's ``model_config`` must be the D-CNN with the settings our modules compute ("same" convolutions and
    pools, batch-norm epsilon 1e-3, ReLU, channels-last); its input ``(T, F, 1)`` must be ``spec``'s image
    ``(num_steps, N*C + G)`` and its last layer ``spec.num_classes`` wide. Keras layouts become PyTorch's: conv
    kernels ``(kh, kw, in, out)`` -> ``(out, in, kh, kw)``, dense kernels ``(in, out)`` -> ``(out, in)``, and the
    first dense kernel's rows go from Keras' channels-last flatten order ``(H, W, C)`` to ours ``(C, H, W)``; batch
    norm gamma, beta, moving mean and variance become weight, bias, running mean and variance. The model returns the
    logits of Keras' softmax layer (same argmax). Inputs must be preprocessed as the source did (Augment8000: the
    object-weight compensation and the published normalisation, ``augment8000(stats="source")``).

    Raises:
        ConfigError: h5py is missing, or the file is not such a D-CNN for ``spec``.
    """
    try:
        import h5py  # optional: only this reader needs it
    except ImportError:
        raise ConfigError("reading Keras HDF5 files needs h5py, which is not installed: pip install h5py (or pip "
                          "install 'tactile-zoo[keras]')") from None
    where = os.fspath(path)
    try:
        file = h5py.File(where, "r")
    except OSError as exc:
        raise ConfigError(f"{where}: cannot be read as an HDF5 file ({exc})") from None
    with file:
        layers = _keras_layers(file, where)
        weights = _keras_weights(file, where)
    convs, bns, dense = ([layer for layer in layers if layer["class_name"] == kind]
                         for kind in ("Conv2D", "BatchNormalization", "Dense"))
    for layer in layers[:-1]:
        _check_layer(layer, where, {"Conv2D": "relu", "Dense": "relu"}.get(layer["class_name"]))
    _check_layer(layers[-1], where, ("softmax", "linear"))  # either way the logits' argmax is the prediction
    shape = convs[0]["config"].get("batch_input_shape")
    features = spec.num_nodes * spec.num_channels + spec.num_globals
    if shape is None or list(shape[1:]) != [spec.num_steps, features, 1]:
        raise ConfigError(f"{where}: input shape {shape and tuple(shape[1:])}; dataset {spec.name!r} gives "
                          f"({spec.num_steps}, {features}, 1)")
    if dense[-1]["config"]["units"] != spec.num_classes:
        raise ConfigError(f"{where}: {dense[-1]['config']['units']} classes; dataset {spec.name!r} has "
                          f"{spec.num_classes}")
    model = DCNN(spec, filters=tuple(c["config"]["filters"] for c in convs),  # type: ignore[arg-type]
                 kernels=tuple(tuple(c["config"]["kernel_size"]) for c in convs),
                 dense=tuple(d["config"]["units"] for d in dense[:2]),  # type: ignore[arg-type]
                 # only matters for fine-tuning: Keras' moving-average momentum in PyTorch's convention
                 bn_momentum=1.0 - float(bns[0]["config"].get("momentum", 0.99)))
    ours_bn = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    ours_dense = [m for m in model.classifier if isinstance(m, nn.Linear)]
    h, w = _pooled(model.num_steps, 3), _pooled(model.num_features, 3)
    for layer, block in zip(convs, model.features):
        conv, name = block[1], layer["config"]["name"]
        kernel = _weight(weights, name, "kernel", 4, where)  # (kh, kw, in, out) -> (out, in, kh, kw)
        _assign(conv.weight, kernel.transpose(3, 2, 0, 1), f"{where}: {name}/kernel")
        _assign(conv.bias, _weight(weights, name, "bias", 1, where), f"{where}: {name}/bias")
    for i, (layer, linear) in enumerate(zip(dense, ours_dense)):
        name = layer["config"]["name"]
        kernel = _weight(weights, name, "kernel", 2, where).T  # (in, out) -> (out, in)
        if i == 0:  # columns in Keras' channels-last flatten order (H, W, C) -> ours, over NCHW maps (C, H, W)
            if kernel.shape[1] != h * w * model.features[-1][1].out_channels:
                raise ConfigError(f"{where}: {name}/kernel has {kernel.shape[1]} inputs, the flattened "
                                  f"{h} x {w} x {model.features[-1][1].out_channels} maps are not that many")
            kernel = kernel.reshape(-1, h, w, kernel.shape[1] // (h * w)).transpose(0, 3, 1, 2).reshape(len(kernel), -1)
        _assign(linear.weight, kernel, f"{where}: {name}/kernel")
        _assign(linear.bias, _weight(weights, name, "bias", 1, where), f"{where}: {name}/bias")
    for layer, bn in zip(bns, ours_bn):
        name = layer["config"]["name"]
        for ours, theirs in (("weight", "gamma"), ("bias", "beta"), ("running_mean", "moving_mean"),
                             ("running_var", "moving_variance")):
            _assign(getattr(bn, ours), _weight(weights, name, theirs, 1, where), f"{where}: {name}/{theirs}")
        # the statistics are trained ones: fine-tuning must average into them, not restart from its first batch
        bn.num_batches_tracked.fill_(1)
    return model.eval()
