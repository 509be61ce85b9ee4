"""ONNX files: whether the exporter and onnxruntime are here, which opsets can be written, writing one file (with the
exporters' chatter kept off the terminal) and running one under onnxruntime. :mod:`.exporter` builds on these."""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import torch
from torch import Tensor, nn

from ..errors import ConfigError, ExportError

__all__ = ["ONNX_INSTALL", "onnx_available", "onnxruntime_available", "onnx_opsets", "check_opset", "to_onnx",
           "onnx_runner", "opset_of", "quiet"]

ONNX_INSTALL = 'pip install "tactile-zoo[export]"  (onnx, onnxscript, onnxruntime)'

def onnx_available() -> bool:
    """Whether the ONNX exporter's dependencies (onnx, onnxscript) are installed."""
    import importlib.util

    return all(importlib.util.find_spec(m) is not None for m in ("onnx", "onnxscript"))


def onnxruntime_available() -> bool:
    """Whether onnxruntime (the check of the ONNX files) is installed."""
    import importlib.util

    return importlib.util.find_spec("onnxruntime") is not None


_EXPORTER_LOGGERS = ("torch.onnx", "torch.export", "torch._export", "onnxscript", "onnx_ir", "onnx")
logger = logging.getLogger(__name__)


class _Collect(logging.Handler):
    """Keeps the records' text, logged once the streams are restored (logging them at once would write into the
    redirected stderr)."""

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if record.exc_info:
            text += "\n" + logging.Formatter().formatException(record.exc_info)
        self.lines.append(f"{record.name}: {text}")


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Keep the exporters' chatter off the user's terminal: torch.jit's deprecation and tracer warnings (every export
    is checked against eager on other inputs instead), the progress lines the ONNX exporter prints, and the log
    records of the exporters and the version converter, all moved to the debug log."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    handler = _Collect()
    saved = []
    for name in _EXPORTER_LOGGERS:
        other = logging.getLogger(name)
        saved.append((other, other.handlers[:], other.propagate))
        other.handlers[:] = [handler]
        other.propagate = False  # not to the root logger's handlers, nor to logging.lastResort (stderr)
    out, err = io.StringIO(), io.StringIO()
    try:
        with warnings.catch_warnings(record=True) as caught, redirect_stdout(out), redirect_stderr(err):
            warnings.simplefilter("always")
            yield
    finally:
        for other, handlers, propagate in saved:
            other.handlers[:] = handlers
            other.propagate = propagate
        for line in handler.lines:
            logger.debug("%s", line)
        for w in caught:
            logger.debug("exporter warning: %s: %s", w.category.__name__, w.message)
        for stream, text in (("stdout", out.getvalue()), ("stderr", err.getvalue())):
            if text.strip():
                logger.debug("exporter %s:\n%s", stream, text.rstrip())


def onnx_opsets() -> tuple[int, int]:
    """The ONNX opsets :func:`export_model` writes: from the one torch's exporter writes natively (18) to the newest
    the installed ``onnx`` knows. Older ones are attempted through onnx's version converter and refused when it
    cannot convert the graph."""
    import onnx

    try:
        from torch.onnx._internal.exporter._constants import TORCHLIB_OPSET as native
    except ImportError:  # a torch that moved it: the value of torch 2.x
        native = 18
    return int(native), int(onnx.defs.onnx_opset_version())


#: The oldest opset the version converter is asked for at all (torch's legacy exporter's minimum).
_OLDEST_OPSET = 7


def check_opset(opset: int | None, what: str = "ONNX opset") -> None:
    """Refuse, before any work, an opset no exporter here can write (``what`` names it in the message)."""
    if opset is None:
        return
    lo, hi = onnx_opsets()
    if isinstance(opset, bool) or not isinstance(opset, int) or not _OLDEST_OPSET <= opset <= hi:
        raise ConfigError(f"{what} {opset!r} is not supported: choose {lo} to {hi} (older ones down to "
                          f"{_OLDEST_OPSET} only where onnx's version converter can convert the graph)")


def to_onnx(graph: nn.Module, inputs: tuple[Tensor, ...], path: Path, opset: int | None, optimize: bool) -> None:
    if not onnx_available():
        raise ExportError(f"ONNX export needs onnx and onnxscript: {ONNX_INSTALL}")
    try:
        with quiet():
            torch.onnx.export(graph, inputs, str(path), dynamo=True, input_names=graph.input_names,
                              output_names=graph.output_names, external_data=False, opset_version=opset,
                              optimize=optimize, verbose=False)
    except Exception as exc:  # noqa: BLE001 - the exporter raises many types; the message says which model and why
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ExportError(f"ONNX export of {path.name} failed: {type(exc).__name__}: {first}") from exc
    if opset is not None:
        # the exporter writes opset 18 and converts; when the conversion fails it logs and keeps 18 (or whatever it
        # reached): a file that does not carry the opset asked for is removed and refused, not shipped to a robot
        # whose onnxruntime cannot load it
        got = opset_of(path)
        if got != opset:
            path.unlink(missing_ok=True)
            lo, hi = onnx_opsets()
            raise ExportError(f"ONNX export of {path.name} at opset {opset} failed: onnx's version converter could "
                              f"not convert the graph (it stayed at opset {got}); supported opsets are {lo} to {hi}")


def onnx_runner(path: Path) -> Callable[..., list[Tensor]]:
    """A function running an ONNX file under onnxruntime on one CPU thread, tensors in and out.

    The session logs errors only: onnxruntime's warnings while it optimises a graph ("Could not find a CPU kernel and
    hence can't constant fold CastLike node", on the multi-barrel SNN) are about its own constant folding, not about
    the file, whose outputs the export checks against eager PyTorch; printed, they would break the promise of a
    quiet success."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.log_severity_level = 3  # 0 verbose, 1 info, 2 warning, 3 error, 4 fatal
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]

    def run(*inputs: Tensor) -> list[Tensor]:
        feeds = {n: v.detach().cpu().numpy() for n, v in zip(names, inputs)}
        return [torch.from_numpy(o) for o in session.run(None, feeds)]

    return run


def opset_of(path: Path) -> int | None:
    try:
        import onnx

        model = onnx.load(str(path), load_external_data=False)
        return next((int(o.version) for o in model.opset_import if o.domain in ("", "ai.onnx")), None)
    except Exception:  # noqa: BLE001 - the opset is informative; a file onnx cannot read was already checked
        return None
