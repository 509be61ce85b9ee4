"""Export to TorchScript and ONNX: every model's full forward and, for streaming models, one step with its state as
explicit tensors, so that a robot can run the model outside Python's training loop, one frame at a time.

Two graphs per model, each as TorchScript (``torch.jit.trace``, ``.pt``) and ONNX (``.onnx``)::

    MODEL.forward.{pt,onnx}   x (B, T, N, C) [, g (B, T, G)]                     -> scores (B, K)
    MODEL.step.{pt,onnx}      x_t (B, N, C) [, g_t (B, G)], state_in_0 .. state_in_{S-1}
                              -> scores (B, K), state_out_0 .. state_out_{S-1}
    MODEL.export.json         names, shapes, dtypes, the state tensors and their initial values, the dataset spec,
                              the preprocessing, and the checks against eager PyTorch

Names, as the ONNX graphs and the JSON file carry them:

- ``x``, ``g``: a whole recording, taxel readings and global features (``g`` only when the dataset has ``G > 0``);
- ``x_t``, ``g_t``: one frame of them;
- ``scores``: the class scores, logits for models trained with cross-entropy, output spike rates in [0, 1] for
  SGnet (``"scores"`` in the JSON file says which); after step k they equal the forward on the first k frames;
- ``state_in_i`` / ``state_out_i``: state tensor ``i``; ``state_out_i`` of one call is ``state_in_i`` of the next.
  Before the first frame each holds its initial value, ``"initial"`` in the JSON file (``0.0``, or ``"-inf"`` for
  X-Tacformer's running maximum of its frame scores; ``float()`` reads both), which :func:`initial_state` fills in.
  Its ``"path"`` says what it is in the model's own state: ``mems[0]`` (SGnet's first LIF membrane), ``count``
  (output spikes so far), ``core[...]`` (a binned model's state after its last complete bin: LIF membranes, spike
  sums, LSTM ``(h, c)``, ...), ``pending_x`` / ``pending_g`` (the sums of the frames of the bin being filled).

Python-side counters become tensors. SGnet's step count, a binned model's number of frames in its open bin
(``pending``) and Tacformer's count of bins are ``(B, 1)`` float32 tensors holding whole numbers (exact up to
2**24 frames), with ``"kind": "counter"``. The eager ``step()`` decides with a Python ``if`` when a bin is complete;
the exported step computes both outcomes' states and picks one per row with ``torch.where``, which gives the same
numbers and makes every row of the batch its own stream: to start a new grasp in row i, reset row i of every state
tensor to its initial value (the batch dimension of each is ``"batch_dim"`` in the JSON file).

Shapes are fixed at export: the batch size (``batch``, default 1) and, for the forward, the number of steps
(``steps``, default the spec's ``num_steps``). Tracing records the Python arithmetic on shapes as constants (how
many bins the frames make, the loops over frames, unrolled), so another shape needs another export.

Exporters. Both formats are traced from a copy of the model whose LIF layers are written with plain tensor
operations (``_PlainLIF``: the fused loop's numbers bit for bit, in a graph a fraction of the size). TorchScript
files come from ``torch.jit.trace`` and compute what eager PyTorch computes, bit for bit (tested for every model).
ONNX files come from ``torch.onnx.export(..., dynamo=True)``, the exporter built on :func:`torch.export.export` (it
needs ``onnxscript``: ``pip install "tactile-zoo[export]"``); the step's graph is optimised, the forward's (unrolled
over all T frames, where the optimiser's cost outgrows the graph) is left to onnxruntime's optimisation at load.
The older TorchScript-based exporter (``dynamo=False``) got four of the six forwards wrong when tried on the models
as they are: the fused LIF and ConvLSTM loops write into preallocated buffers with ``out=`` kernels, which it
dropped, leaving graphs whose output no longer depends on ``x`` (SGnet, ConvLSTM: onnxruntime rejects the input
as unused), and it exported the floor division that counts frame bins, ``-(-T // k)``, as a truncating one
(Tacformer, X-Tacformer: a negative padding length). The ``torch.export`` path functionalises such kernels and
keeps shape arithmetic as Python integers.

Every export is checked before it is reported: the files are loaded back and run on seeded inputs other than the
ones traced, the forward once and the step frame by frame over two bins and more, against the eager model (the
ONNX files under onnxruntime when it is installed). The largest differences go into the JSON file; beyond
:data:`TOLERANCE` the export fails with :class:`ExportError`.
"""

from ..errors import ExportError
from .exporter import (
    EXPORT_FORMAT,
    FORMATS,
    MAX_INPUT_BYTES,
    MAX_STEPS,
    TOLERANCE,
    ExportResult,
    check_shape,
    check_steps,
    export_model,
    initial_state,
    spec_for_dataset,
)
from .graphs import ForwardGraph, StateTensor, StepGraph
from .onnx_io import ONNX_INSTALL, check_opset, onnx_available, onnx_opsets, onnxruntime_available

__all__ = ["FORMATS", "EXPORT_FORMAT", "TOLERANCE", "MAX_STEPS", "MAX_INPUT_BYTES", "check_steps", "check_shape",
           "ExportError", "StateTensor", "ForwardGraph", "StepGraph",
           "ExportResult", "export_model", "initial_state", "spec_for_dataset", "onnx_available",
           "onnxruntime_available", "onnx_opsets", "check_opset", "ONNX_INSTALL"]
