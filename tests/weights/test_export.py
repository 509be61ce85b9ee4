"""``tactile_zoo.export``: TorchScript and ONNX files of every model against eager PyTorch.

Every registered model is exported once (module fixture) for a small simulator spec at batch 2, and its files are run
on seeded simulator samples, not on the inputs the export traced. TorchScript runs the same kernels as eager, so its
outputs must be bit-identical; onnxruntime's must be within 1e-5, and exact where the value is a count of spikes
(SGnet's rates, the spike sums and counters of the state). The step files are run frame by frame from the initial
state the JSON file describes, against the model's own ``step()`` and against its forward on every prefix.
"""

from __future__ import annotations

import copy
import importlib.util
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from export_cases import BATCH, IN_CHILD, SEED, STEPS, child_result, one_onnx_registry
from export_cases import build_case as _case

import tactile_zoo as tz
from tactile_zoo import registry
from tactile_zoo.errors import ConfigError
from tactile_zoo.export import (
    EXPORT_FORMAT,
    ExportError,
    ExportResult,
    StepGraph,
    export_model,
    initial_state,
    onnx_available,
    onnxruntime_available,
)

TESTS_DIR = Path(__file__).resolve().parents[1]


def _zoo_member(name: str) -> bool:
    """Built-ins and installed plugins, not the fixture models other test modules register in the same process."""
    module = sys.modules.get(getattr(registry.get_model_entry(name).obj, "__module__", ""), None)
    path = getattr(module, "__file__", None)
    return path is None or TESTS_DIR not in Path(path).resolve().parents


MODELS = [name for name in tz.list_models() if _zoo_member(name)]
STREAMING = [m for m in MODELS if registry.get_model_entry(m).meta.get("streaming")]


def _grouped(names: list[str]) -> list[Any]:
    """One xdist group per model: under ``--dist loadgroup`` the tests of a model run on one worker, which exports
    it once (the exports are most of this module's time), and the models' groups spread over the workers."""
    return [pytest.param(name, marks=pytest.mark.xdist_group(f"export_{name}")) for name in names]


#: state tensors that count spikes, compared exactly under onnxruntime too (counters are, for every model)
SPIKE_STATES = {"sgnet": {"count"}, "tacformer": {"core[2]"}, "x_tacformer": {"core[0][2]"},
                "deeptactile": {"core[1]"}}

ONNX = onnx_available() and onnxruntime_available()
needs_onnx = pytest.mark.skipif(not ONNX, reason='ONNX checks need onnx, onnxscript and onnxruntime: pip install '
                                                 '"tactile-zoo[export]"')


@dataclass
class Exported:
    name: str
    model: torch.nn.Module
    spec: Any
    x: torch.Tensor  # (B, T, N, C) simulator samples
    g: torch.Tensor | None
    result: ExportResult

    @property
    def inputs(self) -> tuple[torch.Tensor, ...]:
        return (self.x,) if self.g is None else (self.x, self.g)

    def frame(self, t: int) -> tuple[torch.Tensor, ...]:
        """Frame ``t`` as the exported graphs take it: ``x_t``, and ``g_t`` only when there are globals."""
        return (self.x[:, t],) if self.g is None else (self.x[:, t], self.g[:, t])

    def eager(self, t: int, rows: slice = slice(None)) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Frame ``t`` as ``model.step`` takes it: ``x_t, g_t`` (``None`` without globals)."""
        return self.x[rows, t], None if self.g is None else self.g[rows, t]

    def file(self, fmt: str, graph: str) -> Path:
        return self.result.files[(fmt, graph)]


@pytest.fixture(scope="session")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """``exported(name)``: the model, its inputs and its export (made once per model and worker: session scope, as a
    worker may run other modules' tests between two of this module's). The multi-barrel SNN is exported in a child
    process (tests/weights/export_cases.py: the same model, bit for bit), whose output test_export_quiet.py checks.
    The worker's ONNX exports share the exporter's operator registry (export_cases.one_onnx_registry)."""
    done: dict[str, Exported] = {}
    described: dict[str, Exported] = {}
    formats = ("torchscript", "onnx") if ONNX else ("torchscript",)

    def get(name: str, *, files: bool = True) -> Exported:
        """``files=False``: a test that reads only the JSON description, in another model's xdist group, gets the
        export its worker made already, else a TorchScript-only one (the description does not depend on the formats;
        the model's own group, maybe on the other worker, makes the full one)."""
        if name not in done and not files:
            if name not in described:
                model, spec, x, g = _case(name)
                result = export_model(model, tmp_path_factory.mktemp(f"{name}_described"), name=name, spec=spec,
                                      formats=("torchscript",), batch=BATCH, steps=STEPS, seed=SEED)  # no ONNX
                described[name] = Exported(name, model, spec, x, g, result)
            return described[name]
        if name not in done:
            model, spec, x, g = _case(name)
            if name in IN_CHILD:
                written, manifest_path = child_result(name, formats, tmp_path_factory.mktemp(f"{name}_child"))
                result = ExportResult(written, json.loads(manifest_path.read_text()), manifest_path)
            else:
                with one_onnx_registry():
                    result = export_model(model, tmp_path_factory.mktemp(name), name=name, spec=spec,
                                          formats=formats, batch=BATCH, steps=STEPS, seed=SEED)
            done[name] = Exported(name, model, spec, x, g, result)
        return done[name]

    return get


def _onnx(path: Path) -> Any:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    return lambda *inputs: [torch.from_numpy(o) for o in session.run(None, {n: v.numpy() for n, v in
                                                                             zip(names, inputs)})]


def _max_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest absolute difference; equal entries count 0 (X-Tacformer's state holds -inf), NaN counts NaN."""
    assert a.shape == b.shape
    a, b = a.double(), b.double()
    differ = a != b
    return float((a - b)[differ].abs().max()) if bool(differ.any()) else 0.0


# ------------------------------------------------------------------------------------------------------- forward
@pytest.mark.parametrize("name", _grouped(MODELS))
def test_torchscript_forward_is_the_eager_forward(exported: Any, name: str) -> None:
    e = exported(name)
    forward = torch.jit.load(str(e.file("torchscript", "forward")))
    with torch.no_grad():
        want, got = e.model(*e.inputs), forward(*e.inputs)
    assert torch.equal(got, want), _max_diff(got, want)  # the same kernels: bit for bit
    if name == "sgnet":
        assert float(want.sum()) > 0  # output spikes were compared, not two silent networks
    bins = getattr(e.model, "bin_size", 1)
    if bins > 1:  # export_cases.CASES: the frames end in a partial bin, after a full one
        assert STEPS > bins and STEPS % bins, (STEPS, bins)
    if name == "multibarrel":  # two steps of its columns: the second reads the state the first left
        assert e.model.compress(e.x).shape[0] == 2


@needs_onnx
@pytest.mark.parametrize("name", _grouped(MODELS))
def test_onnx_forward_matches_eager_under_onnxruntime(exported: Any, name: str) -> None:
    e = exported(name)
    with torch.no_grad():
        want = e.model(*e.inputs)
    (got,) = _onnx(e.file("onnx", "forward"))(*e.inputs)
    if e.result.manifest["scores"] == "spike_rates":  # SGnet: rates are spike counts / T, exact or wrong
        assert torch.equal(got, want), _max_diff(got, want)
    else:
        assert _max_diff(got, want) <= 1e-5


# ---------------------------------------------------------------------------------------------------------- step
@pytest.mark.parametrize("name", _grouped(STREAMING))
def test_torchscript_step_is_the_eager_step_on_every_frame(exported: Any, name: str) -> None:
    """Frame by frame from the JSON file's initial state: the scores are ``step()``'s bit for bit, the state tensors
    those of the eager flat-state step (SGnet's to rounding: its exported graph holds the dense products, its eager
    step the event ones), and after frame t the scores are the forward on frames 0..t."""
    e = exported(name)
    step = torch.jit.load(str(e.file("torchscript", "step")))
    flat = StepGraph(e.model, e.spec, BATCH, name)
    state, state_eager, own = initial_state(e.result.manifest), flat.initial_state(), e.model.init_state(BATCH)
    assert all(torch.equal(a, b) for a, b in zip(state, state_eager))
    with torch.no_grad():
        for t in range(STEPS):
            want, own = e.model.step(*e.eager(t), own)
            out, ref = step(*e.frame(t), *state), flat(*e.frame(t), *state_eager)
            assert torch.equal(out[0], want), (t, _max_diff(out[0], want))
            if name == "sgnet":  # eager: the event products (revision 3); exported: the dense ones, its oracle
                assert all(_max_diff(a, b) <= 1e-5 for a, b in zip(out[1:], ref[1:])), t
            else:
                assert all(torch.equal(a, b) for a, b in zip(out[1:], ref[1:])), t
            prefix = e.model(e.x[:, :t + 1], None if e.g is None else e.g[:, :t + 1])
            assert _max_diff(out[0], prefix) <= 1e-5, t  # the streaming guarantee, through the exported step
            state, state_eager = out[1:], ref[1:]


@needs_onnx
@pytest.mark.parametrize("name", _grouped(STREAMING))
def test_onnx_step_matches_the_eager_step_under_onnxruntime(exported: Any, name: str) -> None:
    """onnxruntime fed its own state back, frame by frame: scores within 1e-5 of ``step()`` (SGnet's rates exactly),
    spike counts and counters exactly, every other state tensor within 1e-5."""
    e = exported(name)
    run = _onnx(e.file("onnx", "step"))
    flat = StepGraph(e.model, e.spec, BATCH, name)
    exact = {s.index for s in flat.states if s.kind == "counter" or s.path in SPIKE_STATES.get(name, ())}
    assert name not in SPIKE_STATES or len(exact) > sum(s.kind == "counter" for s in flat.states)
    state = state_eager = flat.initial_state()
    own = e.model.init_state(BATCH)
    with torch.no_grad():
        for t in range(STEPS):
            want, own = e.model.step(*e.eager(t), own)
            out, ref = run(*e.frame(t), *state), flat(*e.frame(t), *state_eager)
            if name == "sgnet":
                assert torch.equal(out[0], want), t
            assert _max_diff(out[0], want) <= 1e-5, t
            for s, a, b in zip(flat.states, out[1:], ref[1:]):
                if s.index in exact:
                    assert torch.equal(a, b), (t, s.path, _max_diff(a, b))
                else:
                    assert _max_diff(a, b) <= 1e-5, (t, s.path)
            state, state_eager = tuple(out[1:]), ref[1:]
        if name in SPIKE_STATES:  # the exact comparison saw spikes
            assert any(float(out[1 + s.index].sum()) > 0 for s in flat.states if s.path in SPIKE_STATES[name])


@pytest.mark.parametrize("name", _grouped(STREAMING))
def test_the_initial_state_is_where_the_eager_step_starts(name: str) -> None:
    """The flat-state step that is traced, from the initial values the JSON file gives, computes what ``step()``
    computes from ``init_state``, bit for bit. X-Tacformer also with its frame scorer negated: the running maximum of
    the frame scores starts at -inf, and frames scoring below 0 are where a start at 0 would round differently."""
    model, spec, x, g = _case(name)
    variants = [model]
    if name == "x_tacformer":
        flipped = copy.deepcopy(model)
        with torch.no_grad():
            flipped.temporal.attention.score[-1].weight.neg_()
        variants.append(flipped)
    for m in variants:
        flat = StepGraph(m, spec, BATCH, name)
        state, own = flat.initial_state(), m.init_state(BATCH)
        with torch.no_grad():
            for t in range(STEPS):
                g_t = None if g is None else g[:, t]
                want, own = m.step(x[:, t], g_t, own)
                out = flat(x[:, t], *(() if g_t is None else (g_t,)), *state)
                assert torch.equal(out[0], want), (t, _max_diff(out[0], want))
                state = out[1:]


@pytest.mark.xdist_group("export_x_tacformer")
def test_each_row_of_the_step_is_its_own_stream(exported: Any) -> None:
    """Resetting one row of every state tensor (along its batch dimension) to the initial value starts a new stream
    in that row: its scores are those of a fresh stream, and the other row carries on undisturbed."""
    e = exported("x_tacformer")  # binned (bins of 3 frames), globals, and a state that starts at -inf
    step = torch.jit.load(str(e.file("torchscript", "step")))
    described = e.result.manifest["step"]["state"]
    state, start = initial_state(e.result.manifest), initial_state(e.result.manifest)
    fresh, whole = e.model.init_state(1), e.model.init_state(BATCH)
    with torch.no_grad():
        for t in range(STEPS):
            if t == 1:  # row 1 starts a new grasp, inside the first bin
                state = [s.index_copy(d["batch_dim"], torch.tensor([1]), i.index_select(d["batch_dim"],
                                                                                           torch.tensor([1])))
                         for s, i, d in zip(state, start, described)]
            out = step(*e.frame(t), *state)
            state = out[1:]
            uninterrupted, whole = e.model.step(*e.eager(t), whole)
            assert _max_diff(out[0][:1], uninterrupted[:1]) <= 1e-5, t
            if t >= 1:
                alone, fresh = e.model.step(*e.eager(t, slice(1, 2)), fresh)
                assert _max_diff(out[0][1:], alone) <= 1e-5, t
    assert _max_diff(out[0][1:], uninterrupted[1:]) > 1e-4  # the reset did change row 1


# --------------------------------------------------------------------------------------------------- torch.export
@pytest.mark.parametrize("name", _grouped(MODELS))
def test_torch_export_exports_every_model(name: str) -> None:
    """``torch.export.export`` traces every model (it failed on the graph models while the graph convolution keyed
    its cache on ``data_ptr()``, which fake tensors do not have) and the program computes the eager scores."""
    model, _, x, g = _case(name)
    inputs = (x,) if g is None else (x, g)
    with torch.no_grad():
        want = model(*inputs)  # warms the caches first, as a user's model would be
        program = torch.export.export(model, inputs)
        got = program.module()(*inputs)
    assert _max_diff(got, want) <= 1e-6
    caches = [m.__dict__.get("_kron_cache", {}) for m in model.modules()]
    assert all(type(v) is torch.Tensor for c in caches for entry in c.values() for v in entry)  # no fake left


# ------------------------------------------------------------------------------------------------- description
@pytest.mark.parametrize("name", _grouped(MODELS))
def test_the_json_file_describes_the_files(exported: Any, name: str) -> None:
    e = exported(name)
    desc = e.result.manifest
    assert json.loads(e.result.manifest_path.read_text()) == desc
    n, c, k = e.spec.num_nodes, e.spec.num_channels, e.spec.num_classes
    assert desc["format"] == EXPORT_FORMAT and desc["model"] == name and desc["spec"] == e.spec.to_dict()
    want_in = [{"name": "x", "shape": [BATCH, STEPS, n, c], "dtype": "float32"}]
    if e.g is not None:
        want_in.append({"name": "g", "shape": [BATCH, STEPS, e.spec.num_globals], "dtype": "float32"})
    assert desc["forward"]["inputs"] == want_in
    assert desc["forward"]["outputs"] == [{"name": "scores", "shape": [BATCH, k], "dtype": "float32"}]
    rates = registry.get_model_entry(name).meta["recipe"]["loss"] == "mse_rate"  # SGnet, DeepTactile
    assert desc["scores"] == ("spike_rates" if rates else "logits")
    checks = {key: v for key, v in desc["checks"].items() if key != "tolerance"}
    assert checks and all(v["ok"] for v in checks.values())
    files = {p.name for p in e.result.files.values()}
    assert all((e.result.manifest_path.parent / f).is_file() for f in files)
    if name not in STREAMING:
        assert desc["step"] is None and "does not stream" in desc["step_note"]
        assert not any(graph == "step" for _, graph in e.result.files)
        return
    step = desc["step"]
    states = step["state"]
    assert [i["name"] for i in step["inputs"]] == ["x_t", *(["g_t"] if e.g is not None else []),
                                                   *(f"state_in_{i}" for i in range(len(states)))]
    assert [o["name"] for o in step["outputs"]] == ["scores", *(f"state_out_{i}" for i in range(len(states)))]
    assert step["inputs"][0]["shape"] == [BATCH, n, c]
    # the TorchScript step takes and returns exactly the described tensors
    traced = torch.jit.load(str(e.file("torchscript", "step")))
    with torch.no_grad():
        out = traced(*e.frame(0), *initial_state(desc))
    assert [list(o.shape) for o in out] == [o["shape"] for o in step["outputs"]]
    assert all(s["shape"][s["batch_dim"]] == BATCH for s in states)
    initial = {s["path"]: s["initial"] for s in states}
    assert set(initial.values()) == ({0.0, "-inf"} if name == "x_tacformer" else {0.0})


@pytest.mark.xdist_group("export_x_tacformer")
def test_the_kinds_of_state(exported: Any) -> None:
    """SGnet's state is its LIF membranes, output spike count and step counter; a binned model's adds the open bin."""
    sgnet = [(s["path"], s["kind"]) for s in exported("sgnet", files=False).result.manifest["step"]["state"]]
    assert sgnet == [("mems[0]", "tensor"), ("mems[1]", "tensor"), ("mems[2]", "tensor"), ("mems[3]", "tensor"),
                     ("count", "tensor"), ("steps", "counter")]
    x_tac = exported("x_tacformer").result.manifest["step"]
    assert x_tac["bin_size"] == 3
    assert [s["path"] for s in x_tac["state"]][-3:] == ["pending_x", "pending_g", "pending"]
    assert x_tac["state"][-1]["kind"] == "counter" and x_tac["state"][-1]["shape"] == [BATCH, 1]


@pytest.mark.xdist_group("export_x_tacformer")
def test_initial_state_reads_the_json_file(exported: Any, tmp_path: Path) -> None:
    desc = exported("x_tacformer").result.manifest
    from_file = initial_state(exported("x_tacformer").result.manifest_path)
    assert [tuple(t.shape) for t in from_file] == [tuple(s["shape"]) for s in desc["step"]["state"]]
    assert any(bool(torch.isneginf(t).all()) for t in from_file)
    with pytest.raises(ExportError, match="no step"):
        initial_state(exported("dcnn", files=False).result.manifest)


# ----------------------------------------------------------------------------------------------------- failures
def test_bad_arguments_are_config_errors_naming_them(tmp_path: Path) -> None:
    model, spec, _, _ = _case("dcnn")
    for kwargs, word in (({"formats": ("pdf",)}, "formats"), ({"formats": ()}, "formats"), ({"batch": 0}, "batch"),
                         ({"steps": -1}, "steps"), ({"batch": 1.5}, "batch")):
        with pytest.raises(ConfigError, match=word):
            export_model(model, tmp_path, spec=spec, **kwargs)
    bare = torch.nn.Linear(2, 2)
    with pytest.raises(ConfigError, match="spec"):
        export_model(bare, tmp_path)
    assert not any(tmp_path.iterdir())  # nothing written


def test_an_export_that_differs_from_eager_fails_its_check(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    model, spec, _, _ = _case("dcnn")
    real = torch.jit.load
    monkeypatch.setattr(torch.jit, "load", lambda path: (lambda *a: real(path)(*a) + 1e-3))
    with pytest.raises(ExportError, match="does not reproduce the eager model"):
        export_model(model, tmp_path, spec=spec, formats=("torchscript",))


def test_a_state_that_cannot_be_flattened_is_refused() -> None:
    model, spec, _, _ = _case("sgnet")
    real = model.init_state
    model.init_state = lambda b: replace(real(b), steps=True)  # a bool is no number a tensor can carry
    with pytest.raises(ExportError, match="bool at steps"):
        StepGraph(model, spec, 1, "sgnet")


def test_onnx_without_its_packages_says_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    model, spec, _, _ = _case("dcnn")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda m, *a: None if m == "onnxscript" else real(m, *a))
    with pytest.raises(ExportError, match=r"tactile-zoo\[export\]"):
        export_model(model, tmp_path, spec=spec, formats=("onnx",))


def test_without_onnxruntime_the_onnx_check_is_skipped_and_said(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                                ) -> None:
    if not onnx_available():
        pytest.skip('needs onnx and onnxscript: pip install "tactile-zoo[export]"')
    model, spec, _, _ = _case("dcnn")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda m, *a: None if m == "onnxruntime" else real(m, *a))
    with one_onnx_registry():
        result = export_model(model, tmp_path, spec=spec, formats=("onnx",), steps=STEPS)
    assert result.manifest["checks"]["onnx.forward"]["ok"] is None
    assert "onnxruntime is not installed" in result.manifest["checks"]["onnx.forward"]["skipped"]
    assert np.isfinite(result.manifest["exporters"]["onnx_opset"])
