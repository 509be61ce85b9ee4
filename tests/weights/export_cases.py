"""The models tests/weights/test_export.py exports, as it builds them, and the multi-barrel SNN's export made in a
child process (forked from the warm server of tests/forked_bench.py, with a bare environment) whose stdout and stderr
tests/weights/test_export_quiet.py checks (onnxruntime printed warnings from C++, past Python's streams), and whose
files test_export.py's tests then check against eager.
One export serves both (its ONNX export is the costliest of the module's: about 4,800 nodes, 15 CPU seconds).
:func:`one_onnx_registry` lets the test process's ONNX exports share the exporter's operator registry.

Plain Python (no pytest): the child imports this module to build the model the tests build, bit for bit.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

import tactile_zoo as tz
from tactile_zoo import registry

__all__ = ["CASES", "DEFAULT_CASE", "DATA", "STEPS", "BATCH", "SEED", "IN_CHILD", "build_case", "calibrate",
           "child_export", "child_result", "one_onnx_registry"]

#: the dataset each model is exported for and its hyper-parameters: both kinds of input (events without globals,
#: readings with 8 global features), and bins of several frames for every binned model (ConvLSTM and CNN-LSTM bin
#: ceil(T / max_frames) frames, T the spec's 10 or 20), so that the 5 frames below end in a partial bin: bins of 3
#: (ConvLSTM, CNN-LSTM, both Tacformers: two bins, 3 + 2 frames) and DeepTactile's of 2 (three bins, 2 + 2 + 1). An
#: export unrolls the forward over every bin, and its time grows with them: 7 frames (ConvLSTM's bins of 3 made three
#: bins, DeepTactile's four) cost a third more
CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "sgnet": ("sim_evtouch", {}), "dcnn": ("sim_biotac_slip", {}),
    "convlstm": ("sim_uskin_textures", {"max_frames": 4}), "cnn_lstm": ("sim_evtouch", {"max_frames": 7}),
    "tacformer": ("sim_evtouch", {"bin_size": 3}), "x_tacformer": ("sim_uskin_textures", {"bin_size": 3}),
    "deeptactile": ("sim_evtouch", {"bin_size": 2, "block_config": (1, 1), "growth_rate": 8, "init_features": 16,
                                    "hidden": (32,)}),
}
#: DeepTactile narrow and short (1 + 1 dense layers, with the transition between, and one hidden linear layer): the
#: exports unroll every layer per bin: with the source's widths (3 + 3 layers, 64 + 32 per layer) its tests took 38
#: CPU seconds, narrow with 2 + 1 layers 24, with 1 + 1 about 22; one dense layer per block and one spiking hidden
#: layer still hold every kind of operation (each dense layer appends its channels to its input, the transition
#: between the blocks, a hidden layer between the flattened spikes and the output, 9 membranes in the state); the
#: source's second hidden layer cost 10 % of its export.
#: Bins of 2 frames: with bins of 4, its output spike counters stayed 0 over 7 frames, and the exact comparison of
#: spikes would compare zeros (over these 5 frames its first output spikes come in the second bin; SGnet's in frame 4)
#: the multi-barrel SNN small (its read-out has 28M parameters) and short (its convolutions' 201 frames by default
#: would unroll 11 steps of 8 populations into the graphs); a read-out kernel of 2 makes the frames (zero-padded to
#: its 9-frame minimum) two steps of its columns, so the second step reads the membranes, spikes and adaptation
#: traces the first computed
CASES["multibarrel"] = ("sim_evtouch", {"readout_channels": 16, "kernel_size": 3, "dilation": 1, "readout_kernel": 2})
DEFAULT_CASE = ("sim_uskin_textures", {})
#: small simulator splits (the smallest number of steps each simulator allows, at least 8)
DATA = {"sim_evtouch": {"num_steps": 20}, "sim_uskin_textures": {"num_steps": 10}, "sim_biotac_slip": {"num_steps": 8}}
STEPS, BATCH, SEED = 5, 2, 3
#: the models exported in a child process (:func:`child_export`), not in the test process
IN_CHILD = ("multibarrel",)


def build_case(name: str) -> tuple[torch.nn.Module, Any, torch.Tensor, torch.Tensor | None]:
    """The model (eval mode), its spec and ``BATCH`` simulator samples of ``STEPS`` frames (``x``, ``g`` or None)."""
    dataset, hparams = CASES.get(name, DEFAULT_CASE)
    ds = tz.load_dataset(dataset, split="test", n_train_per_class=2, n_test_per_class=1, seed=0, **DATA[dataset])
    torch.manual_seed(0)
    model = tz.create_model(name, ds.spec, **hparams)
    if registry.get_model_entry(name).meta["recipe"]["loss"] == "mse_rate":  # scores are spike rates
        calibrate(model, ds.x, ds.g if ds.spec.num_globals else None)
    x = ds.x[:BATCH, :STEPS].clone()
    g = ds.g[:BATCH, :STEPS].clone() if ds.spec.num_globals else None
    return model.eval(), ds.spec, x, g


def calibrate(model: torch.nn.Module, x: torch.Tensor, g: torch.Tensor | None) -> None:
    """Batch-norm running statistics of one training-mode pass over the samples, as training leaves them: an untrained
    spiking network evaluated with batch norm's initial statistics (mean 0, variance 1) falls silent (DeepTactile's
    spike counts would all stay 0, and the exact comparisons would compare zeros). Spiking models only: D-CNN's
    logits grow after it, and onnxruntime's rounding with them, past test_export.py's absolute tolerance (1e-5)."""
    norms = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    for norm in norms:
        norm.reset_running_stats()
        norm.momentum = None  # a cumulative average: after one pass, that pass's statistics
    if norms:
        with torch.no_grad():
            model.train()(x, g)


_REGISTRIES: dict[tuple[Any, int], Any] = {}


@contextlib.contextmanager
def one_onnx_registry() -> Iterator[None]:
    """Inside it, every ``torch.onnx.export`` (dynamo) of the process reuses one operator registry per opset.
    The exporter builds it from onnxscript's torchlib on every call: 0.5-0.6 CPU seconds of parsing function
    sources, most of a small graph's export. The files are byte for byte the ones it writes without this (the
    exporter only reads the registry, unless passed a ``custom_translation_table``, which tactile_zoo never passes).
    For the tests alone: torch's private API, left as it is where a torch has moved it."""
    try:
        from torch.onnx._internal.exporter import _registration
    except ImportError:
        yield
        return
    real = _registration.ONNXRegistry.__dict__.get("from_torchlib")
    if not isinstance(real, classmethod):
        yield
        return

    def from_torchlib(cls: Any, *args: Any, **kwargs: Any) -> Any:
        opset = kwargs.get("opset_version", args[0] if args else None)
        if not isinstance(opset, int) or len(args) + len(kwargs) != 1:
            return real.__func__(cls, *args, **kwargs)
        if (cls, opset) not in _REGISTRIES:
            _REGISTRIES[(cls, opset)] = real.__func__(cls, opset_version=opset)
        return _REGISTRIES[(cls, opset)]

    _registration.ONNXRegistry.from_torchlib = classmethod(from_torchlib)
    try:
        yield
    finally:
        _registration.ONNXRegistry.from_torchlib = real


def _child_main(name: str, out: str, formats: str) -> None:
    """In the child: export ``name`` as the tests do, write where the files went next to ``out``, print one line."""
    from tactile_zoo.export import export_model

    model, spec, _, _ = build_case(name)
    result = export_model(model, out, name=name, spec=spec, formats=tuple(formats.split(",")), batch=BATCH,
                          steps=STEPS, seed=SEED, progress=False)
    files = [[fmt, graph, str(path)] for (fmt, graph), path in result.files.items()]
    Path(f"{out}.result.json").write_text(json.dumps({"files": files, "manifest_path": str(result.manifest_path)}))
    print("exported")


#: the child's script: the bare environment a user's shell gives it (the server's environment was the test
#: process's), the working folder, the export, then the interpreter's exit functions, as a ``python -c`` ends
_CHILD = """import atexit, os, sys
os.environ.clear()
os.environ.update({"PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1", "HOME": sys.argv[2]})
os.chdir(sys.argv[2])
sys.path.insert(0, sys.argv[1])
import export_cases
export_cases._child_main(*sys.argv[3:])
atexit._run_exitfuncs()
"""
_DONE: dict[tuple[str, str], tuple[subprocess.CompletedProcess, Path]] = {}


def child_export(name: str, formats: tuple[str, ...], folder: Path) -> tuple[subprocess.CompletedProcess, Path]:
    """Export ``name`` as the tests do, in a child process with a bare environment (as a user's shell runs it),
    into ``folder / name``, once per test process and formats: the finished process (its output captured) and the
    export's folder. ``folder``: a fresh folder for the first call.

    The child is forked from the warm server of tests/forked_bench.py (torch and the package imported: a fresh
    interpreter spent about 6 of its 24 CPU seconds importing them), with a new interpreter's stdout and stderr:
    file descriptors 1 and 2 of its own, where what onnx, onnxscript and onnxruntime import, print or log (from
    C++ too) during the export lands, as it would on a user's terminal. What torch and the package print when
    imported, the server printed: other tests run them fresh (``python -m tactile_zoo.cli``)."""
    key = (name, ",".join(formats))
    if key not in _DONE:
        from forked_bench import finish_python  # the test process's (tests/ is on its module path)

        out = folder / name
        argv = [str(Path(__file__).parent), str(folder), name, str(out), key[1]]
        status, stdout, stderr = finish_python(_CHILD, argv, folder / f"{name}.child", timeout=600)
        _DONE[key] = (subprocess.CompletedProcess(["python", "-c", _CHILD, *argv], status, stdout, stderr), out)
    return _DONE[key]


def child_result(name: str, formats: tuple[str, ...], folder: Path) -> tuple[dict[tuple[str, str], Path], Path]:
    """What :func:`child_export`'s ``export_model`` returned: its files (format and graph -> path) and the JSON
    description's path; AssertionError with the child's stderr when it failed."""
    proc, out = child_export(name, formats, folder)
    assert proc.returncode == 0, proc.stderr
    written = json.loads(Path(f"{out}.result.json").read_text())
    return {(fmt, graph): Path(path) for fmt, graph, path in written["files"]}, Path(written["manifest_path"])

