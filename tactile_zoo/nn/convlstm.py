"""Convolutional LSTM (Shi et al., "Convolutional LSTM Network", NeurIPS 2015), without peephole connections.

Update rule for one layer, ``*`` a 2-D convolution with "same" zero padding and ``o`` the element-wise product::

    i_t = sigmoid(W_xi * X_t + W_hi * H_{t-1} + b_i)
    f_t = sigmoid(W_xf * X_t + W_hf * H_{t-1} + b_f)
    o_t = sigmoid(W_xo * X_t + W_ho * H_{t-1} + b_o)
    g_t = tanh(W_xg * X_t + W_hg * H_{t-1} + b_g)
    C_t = f_t o C_{t-1} + i_t o g_t
    H_t = o_t o tanh(C_t)

Shi et al. also add peephole terms ``W_c o C`` to the gates; the ConvLSTM source of the tactile model
(yayaneath/BioTacSP-DoS, PyTorch notebooks: its peephole weights are constant zeros) has none, and neither has this
layer. Initial states are zero.

Speed: the input-side convolutions ``W_x* * X_t`` do not depend on the recurrence, so one convolution computes them
for all ``B*T`` frames at once; only the hidden-side convolution and the gates run once per step. A stack runs layer by
layer, so layer ``l+1``'s input convolution is again one call over all frames. Three backends run the
recurrence:

``"fused"`` (default)
    one autograd Function over the whole time loop, channel-major (``(channels, B*H*W)``: each gate a contiguous
    block, the whole batch one matrix). Its forward writes gates, cell states and hidden states into preallocated
    time-major buffers; per step one gather builds the im2col matrix of ``h_{t-1}`` and one matrix product adds the
    hidden convolution to the input side's, then 7 in-place or ``out=`` ops, no autograd graph. Its hand-written
    backward walks the steps in reverse: the gate derivatives, the kernel gradient (one product) and the gradient
    of ``h_{t-1}`` (one product and a scatter-add, the transpose of the gather). Without gradients (inference) the
    same loop runs on reused scratch tensors. On CPU float32/float64 the gather and the scatter-add are numba's
    shifted row copies and adds (:mod:`tactile_zoo.nn._kernels.convlstm`; ``index_select``/``index_add_``
    elsewhere, with the same bits), and the large buffers come from :mod:`~tactile_zoo.nn.storage_pool`: together
    about 1.2x a training step (performance round 5), with every number unchanged. The gates keep the strides of the
    input side's channels-last output: a contiguous gate buffer would be faster for the element-wise ops, but the
    products would then write a transposed output, a different BLAS kernel with different rounding. The input-side
    convolution runs channels-last, where oneDNN's CPU backward is about 2x faster on these grids. Measured on one
    CPU thread, the two-layer 16-channel model on a 9x13 grid, B = 32, T = 100: 2.15 s forward + backward (0.64 s
    forward alone), against 2.29 s for the previous per-step ``conv2d`` version and 2.31 s for the ``"autograd"``
    backend. The matrix products dominate: about 65 GFLOP, whose floor at the ~60 GFLOP/s one core reaches at these
    sizes is about 1.1 s; the rest is memory-bound element-wise work and the gather/scatter.
``"autograd"``
    the same update written with ordinary differentiable ops, stepped in Python: the reference the fused backend
    is tested against, and the path for double backward.
``"compiled"`` (opt-in)
    the fused loop with each step's work around its one matrix product in one numba call
    (:mod:`tactile_zoo.nn._kernels.convlstm`, single-threaded, compiled on first use and cached on disk). Forward:
    ``addmm`` of the kernel with the im2col matrix of ``h_{t-1}``, then one kernel that activates the gates,
    updates ``c`` and ``h`` and, channel by channel while the new ``h`` row is in cache, writes the im2col matrix for
    step ``t+1`` (each tap one contiguous shifted copy plus zeroed borders: no index array). Backward: one kernel per
    step sums ``dL/dh_t`` from the im2col gradient (the scatter-add, as a shifted add per tap), computes the gate
    derivatives and writes the im2col matrix of ``h_{t-1}`` for the kernel's gradient; the two products stay
    ``addmm_``/``mm``. Its float32 sigmoid and tanh are its own polynomials (within 2 ulp; numba has no vectorised
    ``exp``), so the results equal ``"fused"``'s to float32 rounding, not bit for bit (tests/nn/test_convlstm_kernel.py
    compares forward and every gradient with both other backends); float64 uses libm. It runs on plain CPU float32
    or float64 tensors and falls back to the ``"fused"`` loop elsewhere (GPU, other dtypes, tracing). Measured
    under load from other processes (2 shared cores, load average 1.0 to 1.4), one torch thread, the two backends
    interleaved, median of 9: the two-layer model above 1.76 s forward + backward against 2.02 s for ``"fused"``
    (1.14x; 1.10x in an earlier run of 7), 0.53 s against 0.63 s forward alone, and a training step of the
    ``convlstm`` model on an Ev-Objects batch (B = 32, 250 frames in 50 bins, Adam) 0.79 s against 0.92 s (1.17x).
    What it does not touch bounds the gain: the three matrix products per step and the input-side convolution
    (oneDNN, above all its backward) are most of the time; the element-wise work, gather and scatter-add it
    replaces took about 0.5 s of ``"fused"``'s forward + backward and take about 0.26 s here (cProfile, one run).
    Since performance round 5 it reads ``xz`` as the convolution's view (it enters only the products, as their bias)
    and writes the gradient back in the convolution's channels-last layout one step at a time, where it used to copy
    both whole tensors through a transpose (about 0.25 s of a 0.85 s training step); its buffers are pooled. Its
    numbers did not change (tests/nn/test_convlstm_kernel.py holds the copying version's bits).

Initialisation (``init``): ``"keras"`` (default) follows Keras' ``ConvLSTM2D`` defaults: Glorot-uniform input
kernels, orthogonal recurrent kernels, zero biases except 1 on the forget gate (``unit_forget_bias``). ``"torch"``
keeps PyTorch's own ``nn.Conv2d`` initialisation, the one of the tactile source's PyTorch cells (one convolution per
gate there; the fused ``4h``-channel convolution here has the same fan-in, hence the same distributions), with no
forget-gate bias.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from ..errors import ConfigError
from . import backend as switch
from .backend import ConvLSTMBackend
from .convlstm_compiled import CompiledRecurrence, compiled_applies, compiled_recurrence
from .storage_pool import reusable, reusable_like

__all__ = ["ConvLSTMCell", "ConvLSTM", "ConvLSTMConfig", "BACKENDS", "INITS"]

State = tuple[Tensor, Tensor]  # (h, c), each (B, hidden, H, W)


def _gates(z: Tensor, c: Tensor) -> State:
    """The LSTM cell update from the pre-activations ``z = (i, f, o, g)`` stacked on dim 1."""
    hidden = c.shape[1]
    ifo = torch.sigmoid(z[:, : 3 * hidden])
    i, f, o = ifo.chunk(3, dim=1)
    g = torch.tanh(z[:, 3 * hidden:])
    c = torch.addcmul(f * c, i, g)
    return o * torch.tanh(c), c


def _tap_index(batch: int, height: int, width: int, kernel: int) -> Tensor:
    """Gather index of the im2col matrix of a "same" convolution, channel-major.

    Each channel of a batch of maps sits in one row of ``B*H*W + 1`` values (sample-major, then cells; the last slot
    stays 0). Gathering a row with this index gives, at position ``(dr*k + dc) * B*H*W + b*H*W + p``, the value of
    tap ``(dr, dc)`` around cell ``p`` of sample ``b``, or the zero slot where the tap falls outside the grid; over
    ``C`` rows that is the im2col matrix ``(C*k*k, B*H*W)``, its rows in the order of a conv kernel flattened to
    ``(C_out, C*k*k)``.
    """
    pad = kernel // 2
    dr = torch.arange(kernel).view(kernel, 1, 1, 1) - pad
    dc = torch.arange(kernel).view(1, kernel, 1, 1) - pad
    rr = torch.arange(height).view(1, 1, height, 1) + dr
    cc = torch.arange(width).view(1, 1, 1, width) + dc  # with rr: (k, k, H, W)
    inside = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
    cells = height * width
    offset = torch.arange(batch).view(1, batch, 1) * cells
    idx = (rr * width + cc).flatten(0, 1).unsqueeze(1).flatten(2) + offset  # (k*k, B, H*W)
    idx = torch.where(inside.flatten(0, 1).unsqueeze(1).flatten(2), idx, batch * cells)
    return idx.reshape(-1)


class _Taps:
    """The im2col gather of a state and its transpose, for one grid: numba's shifted row copies and adds
    (:func:`~tactile_zoo.nn._kernels.convlstm.im2col_rows`, ``col2im_rows``) on plain CPU float32/float64 tensors
    where numba is installed, ``index_select`` / ``index_add_`` with :func:`_tap_index` elsewhere. Both give the same
    values bit for bit: the gather is a copy, and the kernel adds each position's taps in the index's order."""

    def __init__(self, grid: tuple[int, int, int], kernel: int, like: Tensor, *tensors: Tensor) -> None:
        self.grid, self.kernel = grid, kernel
        self.kern = _kernels_for(like, *tensors)
        self.idx = _tap_index(*grid, kernel).to(like.device) if self.kern is None else None

    def gather(self, rows: Tensor, cols: Tensor) -> None:
        """``rows (h, N + 1)`` (the last column 0) -> ``cols (h*k*k, N)``, the im2col matrix of ``rows[:, :N]``."""
        if self.kern is None:
            torch.index_select(rows, 1, self.idx, out=cols.view(rows.shape[0], -1))
        else:
            self.kern.im2col_rows(rows.numpy(), cols.numpy(), *self.grid, self.kernel)

    def scatter(self, d_cols: Tensor, out: Tensor) -> None:
        """``out[:, :N]`` (``out (h, N + 1)``) becomes the transpose of the gather applied to ``d_cols``, which
        may be overwritten."""
        if self.kern is None:
            out.zero_().index_add_(1, self.idx, d_cols.view(out.shape[0], -1))
        else:
            self.kern.col2im_rows(d_cols.numpy(), out.numpy(), *self.grid, self.kernel)


def _kernels_for(*tensors: Tensor) -> Any:
    """The numba kernel module where it runs on ``tensors`` (:func:`compiled_applies`, and numba installed), else
    ``None``."""
    if not compiled_applies(*tensors):
        return None
    try:
        return switch.convlstm_kernels()
    except ImportError:
        return None


def _recurrence(xz: Tensor, weight: Tensor, h0: Tensor, c0: Tensor, taps: _Taps, keep: bool
                ) -> tuple[Tensor, Tensor, tuple[Tensor, Tensor, Tensor] | None]:
    """The time loop without autograd, channel-major: ``xz (T, 4h, B*H*W)`` (the input side's pre-activations),
    ``h0, c0 (h, B*H*W)``, the grid's :class:`_Taps` -> ``hbuf (T+1, h, B*H*W + 1)`` (``hbuf[t, :, :-1]`` is
    ``h_t``, ``hbuf[0]`` holds ``h0``, the last column stays 0) and ``c_T (h, B*H*W)``.

    A step is one gather and one matrix product: the gather builds the im2col matrix ``(h*k*k, B*H*W)`` of
    ``h_{t-1}`` (taps outside the grid read zeros), and ``addmm`` adds the kernel times it to ``xz_t``, writing the
    pre-activations straight into the gate buffer. Channel-major keeps each gate a contiguous block for the
    element-wise updates, and the whole batch is one ``4h x h*k*k x B*H*W`` product: on these small grids much faster
    on CPU than a ``conv2d`` per step.
    With ``keep`` the activated gates, cell states and ``tanh(c)`` of every step stay in buffers for the backward;
    without it (inference) per-step scratch tensors are reused. The large buffers come from the storage pool: a
    training step rewrites memory already mapped instead of faulting in about 80 MB of fresh pages per layer.
    """
    steps, four_h, cols_n = xz.shape
    hid = four_h // 4
    kernel = weight.reshape(four_h, -1)  # (4h, h*k*k)
    hbuf = reusable((steps + 1, hid, cols_n + 1), xz)  # every position is written below or by the loop
    hbuf[0, :, :cols_n] = h0
    hbuf[:, :, cols_n] = 0
    if keep:
        gates, cs = reusable_like(xz), reusable((steps + 1, hid, cols_n), xz)
        tcs = reusable((steps, hid, cols_n), xz)
        cs[0] = c0
    else:
        z_buf, c, tc = torch.empty_like(xz[0]), c0.clone(), torch.empty_like(c0)
    cols = reusable((kernel.shape[1], cols_n), xz)  # a fresh multi-megabyte tensor per call costs page faults
    for t in range(steps):
        z = gates[t] if keep else z_buf
        taps.gather(hbuf[t], cols)  # (h*k*k, B*H*W)
        torch.addmm(xz[t], kernel, cols, out=z)  # (4h, B*H*W) pre-activations
        z[: 3 * hid].sigmoid_()
        z[3 * hid:].tanh_()
        i, f, o, g = z.split(hid)
        if keep:
            c, tc = cs[t + 1], tcs[t]
            torch.mul(f, cs[t], out=c)
        else:
            c.mul_(f)
        c.addcmul_(i, g)
        torch.tanh(c, out=tc)
        torch.mul(o, tc, out=hbuf[t + 1, :, :cols_n])
    return hbuf, c, ((gates, cs, tcs) if keep else None)


class _FusedRecurrence(torch.autograd.Function):
    """The ConvLSTM time loop as one autograd node, channel-major: ``(xz (T, 4h, B*H*W), W_h (4h, h, k, k),
    h0, c0 (h, B*H*W), grid (B, H, W)) -> (hs (T, h, B*H*W), c_T (h, B*H*W))``."""

    @staticmethod
    def forward(ctx: Any, xz: Tensor, weight: Tensor, h0: Tensor, c0: Tensor, grid: tuple[int, int, int]
                ) -> tuple[Tensor, Tensor]:
        taps = _Taps(grid, weight.shape[-1], xz, weight, h0, c0)
        hbuf, c_last, saved = _recurrence(xz, weight, h0, c0, taps, keep=True)
        # the returned hs is a view of hbuf: the version counter they share guards against in-place edits
        ctx.save_for_backward(weight, hbuf, *saved)
        ctx.taps = taps
        return hbuf[1:, :, :-1], c_last

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, d_hs: Tensor, d_c_last: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, None]:
        weight, hbuf, gates, cs, tcs = ctx.saved_tensors
        taps = ctx.taps
        steps, four_h, cols_n = gates.shape
        hid = four_h // 4
        kernel = weight.reshape(four_h, -1)  # (4h, h*k*k)
        d_kernel = torch.zeros_like(kernel)
        d_z = reusable_like(gates)  # (T, 4h, B*H*W): gradient of the pre-activations = gradient of xz
        d_hbuf = hbuf.new_zeros(hid, cols_n + 1)  # gradient of h_{t-1}, scattered back from the im2col columns
        d_h = d_hbuf[:, :cols_n]
        d_c = d_c_last.clone()
        cols, d_cols = reusable((kernel.shape[1], cols_n), gates), reusable((kernel.shape[1], cols_n), gates)
        for t in reversed(range(steps)):
            dh = d_h + d_hs[t]
            i, f, o, g = gates[t].split(hid)
            di, df, do, dg = d_z[t].split(hid)
            tc = tcs[t]
            torch.mul(dh, tc, out=do)
            d_tanh = dh * o
            d_c.add_(d_tanh).addcmul_(d_tanh * tc, tc, value=-1.0)  # += dh * o * (1 - tanh(c)^2)
            torch.mul(d_c, g, out=di)
            torch.mul(d_c, cs[t], out=df)
            torch.mul(d_c, i, out=dg)
            d_c.mul_(f)  # on to c_{t-1}
            sig = gates[t][: 3 * hid]
            d_z[t][: 3 * hid].mul_(torch.addcmul(sig, sig, sig, value=-1.0))  # sigmoid' = s (1 - s)
            dg.addcmul_(dg * g, g, value=-1.0)  # tanh' = 1 - g^2
            # the kernel's gradient needs h_{t-1}'s im2col matrix again: one gather, cheaper than keeping T of them
            taps.gather(hbuf[t], cols)
            d_kernel.addmm_(d_z[t], cols.t())
            # on to h_{t-1}: the transpose of the gather, a scatter-add of the im2col matrix's gradient
            torch.mm(kernel.t(), d_z[t], out=d_cols)  # (h*k*k, B*H*W)
            taps.scatter(d_cols, d_hbuf)
        return d_z, d_kernel.view_as(weight), d_h.clone(), d_c, None


#: The recurrence's implementations (:class:`~tactile_zoo.nn.backend.ConvLSTMBackend`; module docstring).
BACKENDS = tuple(choice.value for choice in ConvLSTMBackend)
INITS = ("keras", "torch")


class ConvLSTMCell(nn.Module):
    """One ConvLSTM layer.

    Args:
        in_channels: channels of the input frames.
        hidden_channels: channels of the hidden and cell state.
        kernel_size: odd side of the square kernels ("same" padding keeps the grid size, also on a 1x3 grid).
        forget_bias: initial forget-gate bias (``init="keras"`` only).
        backend: ``"fused"`` (default), ``"autograd"`` or ``"compiled"`` (module docstring).
        init: ``"keras"`` (default) or ``"torch"`` (module docstring).

    Shapes:
        :meth:`forward`: ``x [B, T, C_in, H, W]`` -> ``(h_seq [B, T, hidden, H, W], (h_T, c_T))``;
        :meth:`forward_time_major` the same with ``T`` first.
        :meth:`step`: ``x_t [B, C_in, H, W]`` -> ``(h_t, c_t)``, each ``[B, hidden, H, W]``.
    """

    def __init__(self, in_channels: int, hidden_channels: int, kernel_size: int = 3, forget_bias: float = 1.0,
                 backend: str = "fused", init: str = "keras") -> None:
        super().__init__()
        if kernel_size % 2 != 1 or kernel_size < 1:
            raise ConfigError(f"ConvLSTM kernel_size must be a positive odd integer, got {kernel_size}")
        if in_channels < 1 or hidden_channels < 1:
            raise ConfigError(f"ConvLSTM channels must be positive, got in={in_channels}, hidden={hidden_channels}")
        backend = switch.resolve(ConvLSTMBackend, backend, "backend", "ConvLSTM")
        if init not in INITS:
            raise ConfigError(f"ConvLSTM init must be one of {INITS}, got {init!r}")
        self.hidden_channels, self.backend, self.padding = hidden_channels, backend, kernel_size // 2
        # gate order along the output channels: i, f, o (sigmoid, adjacent: one op), then g (tanh)
        self.input_conv = nn.Conv2d(in_channels, 4 * hidden_channels, kernel_size, padding=self.padding, bias=True)
        self.hidden_conv = nn.Conv2d(hidden_channels, 4 * hidden_channels, kernel_size, padding=self.padding,
                                     bias=False)
        if init == "keras":  # "torch": the convolutions keep the initialisation they were built with
            self.reset_parameters(forget_bias)

    def reset_parameters(self, forget_bias: float = 1.0) -> None:
        nn.init.xavier_uniform_(self.input_conv.weight)
        nn.init.orthogonal_(self.hidden_conv.weight)
        nn.init.zeros_(self.input_conv.bias)
        with torch.no_grad():
            self.input_conv.bias[self.hidden_channels: 2 * self.hidden_channels] = forget_bias

    def init_state(self, batch_size: int, grid_shape: tuple[int, int]) -> State:
        w = self.hidden_conv.weight
        h = w.new_zeros(batch_size, self.hidden_channels, *grid_shape)
        return h, h.clone()

    def forward_time_major(self, x: Tensor, state: State | None = None) -> tuple[Tensor, State]:
        steps, b = x.shape[:2]
        h, c = self.init_state(b, x.shape[-2:]) if state is None else state
        # one call over all T*B frames, channels-last: there oneDNN's CPU convolution (above all its backward) runs
        # about 2x faster than in NCHW on these small grids
        frames = x.flatten(0, 1).contiguous(memory_format=torch.channels_last)  # (T*B, C_in, H, W)
        xz = self.input_conv(frames).unflatten(0, (steps, b))  # (T, B, 4*hidden, H, W)
        weight = self.hidden_conv.weight
        if self.backend is not ConvLSTMBackend.AUTOGRAD:
            height, width = xz.shape[-2:]
            # channel-major for the fused loop: (T, 4h, B*H*W), and the states (h, B*H*W)
            # The fused loop takes these views as they come (a channels-last xz is a strided view here): a copy would
            # change the layout of xz's gradient, and with it the input convolution's backward in the last bits.
            xz_cm = xz.transpose(1, 2).reshape(steps, xz.shape[2], -1)
            h_cm, c_cm = (v.transpose(0, 1).reshape(self.hidden_channels, -1) for v in (h, c))
            train = torch.is_grad_enabled() and any(v.requires_grad for v in (xz, weight, h, c))
            if self.backend is ConvLSTMBackend.COMPILED and compiled_applies(xz_cm, weight, h_cm, c_cm):
                # numba reads the states' raw rows; xz only enters the products (as a bias: a copy), so it stays the
                # convolution's view, and its gradient goes back in the convolution's layout: no full-size transposes
                h_cm, c_cm = h_cm.contiguous(), c_cm.contiguous()
                grid = (b, height, width)
                if train:
                    hs, c = CompiledRecurrence.apply(xz_cm, weight, h_cm, c_cm, grid)
                else:
                    hs, c = compiled_recurrence(xz_cm, weight, h_cm, c_cm, grid, keep=False)[:2]
                    hs = hs[1:]
            elif train:
                hs, c = _FusedRecurrence.apply(xz_cm, weight, h_cm, c_cm, (b, height, width))  # (T, h, N), (h, N)
            else:  # inference: the same loop without buffers for a backward pass
                taps = _Taps((b, height, width), weight.shape[-1], xz_cm, weight, h_cm, c_cm)
                hbuf, c, _ = _recurrence(xz_cm, weight, h_cm, c_cm, taps, keep=False)
                hs = hbuf[1:, :, :-1]
            hs = hs.unflatten(2, (b, height, width)).transpose(1, 2)  # (T, B, hidden, H, W), a view
            c = c.unflatten(1, (b, height, width)).transpose(0, 1)  # (B, hidden, H, W)
            return hs, (hs[-1], c)
        out = []
        for z_x in xz.unbind(0):  # (B, 4*hidden, H, W) per step
            h, c = _gates(z_x + self.hidden_conv(h), c)
            out.append(h)
        return torch.stack(out), (h, c)

    def forward(self, x: Tensor, state: State | None = None) -> tuple[Tensor, State]:
        hs, state = self.forward_time_major(x.transpose(0, 1), state)
        return hs.transpose(0, 1), state  # (B, T, hidden, H, W)

    def step(self, x_t: Tensor, state: State) -> State:
        h, c = state
        return _gates(self.input_conv(x_t) + self.hidden_conv(h), c)


@dataclass
class ConvLSTMConfig:
    """A stack of ConvLSTM layers (the source's model: 16 channels, 3x3 kernels, 2 layers)."""

    in_channels: int
    hidden_channels: int = 16
    num_layers: int = 2
    kernel_size: int = 3
    forget_bias: float = 1.0
    backend: str = "fused"
    init: str = "keras"


class ConvLSTM(nn.Module):
    """Stacked ConvLSTM layers, each layer's hidden sequence the next layer's input.

    Args:
        config: a :class:`ConvLSTMConfig`.

    Shapes:
        :meth:`forward`: ``x [B, T, C, H, W]`` -> ``(h_seq [B, T, hidden, H, W]`` of the top layer, states per layer).
        :meth:`step`: ``x_t [B, C, H, W]`` and the per-layer states -> ``(h_t [B, hidden, H, W], new states)``.
    """

    def __init__(self, config: ConvLSTMConfig) -> None:
        super().__init__()
        if config.num_layers < 1:
            raise ConfigError(f"ConvLSTM num_layers must be >= 1, got {config.num_layers}")
        self.config = config
        widths = [config.in_channels] + [config.hidden_channels] * config.num_layers
        self.layers = nn.ModuleList(
            ConvLSTMCell(widths[i], config.hidden_channels, config.kernel_size, config.forget_bias, config.backend,
                         config.init)
            for i in range(config.num_layers))

    def init_state(self, batch_size: int, grid_shape: tuple[int, int]) -> list[State]:
        return [layer.init_state(batch_size, grid_shape) for layer in self.layers]

    def forward(self, x: Tensor, state: list[State] | None = None) -> tuple[Tensor, list[State]]:
        if x.dim() != 5:
            raise ConfigError(f"ConvLSTM expects frames [B, T, C, H, W], got {tuple(x.shape)}")
        if x.shape[1] == 1:  # one frame (streaming): the cells' step skips the sequence path's per-call set-up
            h, states = self.step(x[:, 0], state if state is not None else self.init_state(x.shape[0], x.shape[-2:]))
            return h[:, None], states  # (B, 1, hidden, H, W)
        seq = x.transpose(0, 1)  # (T, B, C, H, W): time-major between layers, so every step's slice is contiguous
        states = []
        for i, layer in enumerate(self.layers):  # layer by layer: each layer's input convs batch over all frames
            seq, s = layer.forward_time_major(seq, None if state is None else state[i])
            states.append(s)
        return seq.transpose(0, 1), states  # (B, T, hidden, H, W)

    def step(self, x_t: Tensor, state: list[State]) -> tuple[Tensor, list[State]]:
        states = []
        for layer, s in zip(self.layers, state):
            s = layer.step(x_t, s)
            x_t = s[0]
            states.append(s)
        return x_t, states
