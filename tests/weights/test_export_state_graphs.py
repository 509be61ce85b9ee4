"""The streaming step as an export takes it (:class:`tactile_zoo.export.graphs.StepGraph`) for a model whose state is
not a binned core: a dict of a tensor and a Python number, and the states it refuses, each with its message; and the
plain LIF the exported graphs hold, with the subtract reset. All in memory, no file written."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest
import torch
from torch import nn

from tactile_zoo.errors import ExportError
from tactile_zoo.export.graphs import StepGraph, _for_export, _PlainLIF
from tactile_zoo.nn.lif import MultiStepLIF

SPEC = SimpleNamespace(num_globals=0, num_nodes=3, num_channels=2)


class DictState(nn.Module):
    """A streaming model whose state is ``{"mem": (B, N, C) tensor, "seen": number}``; ``init`` and ``after`` make
    its initial and its next state something else, to plant what the export refuses."""

    def __init__(self, init: Any = None, after: Any = None) -> None:
        super().__init__()
        self.head = nn.Linear(SPEC.num_channels, 4)
        self.init, self.after = init, after

    def init_state(self, batch: int) -> Any:
        if self.init is not None:
            return self.init(batch)
        return {"mem": torch.zeros(batch, SPEC.num_nodes, SPEC.num_channels), "seen": 0}

    def step(self, x_t: torch.Tensor, g_t: torch.Tensor | None, state: Any) -> tuple[torch.Tensor, Any]:
        mem = state["mem"] * 0.5 + x_t
        new = {"mem": mem, "seen": 1} if self.after is None else self.after(state, mem)
        return self.head(mem.mean(1)), new


def test_a_dict_state_with_a_number_becomes_named_tensors_and_a_counter() -> None:
    model = DictState().eval()
    graph = StepGraph(model, SPEC, batch_size=2, name="no_such_registered_model")  # no initial-value overrides
    assert [(s.path, s.shape, s.kind, s.initial, s.batch_dim) for s in graph.states] == [
        ("mem", (2, 3, 2), "tensor", 0.0, 0), ("seen", (2, 1), "counter", 0.0, 0)]
    assert graph.input_names == ["x_t", "state_in_0", "state_in_1"]
    x_t = torch.rand(2, 3, 2, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        scores, mem, seen = graph(x_t, *graph.initial_state())
        want_scores, want_state = model.step(x_t, None, model.init_state(2))
    torch.testing.assert_close(scores, want_scores)
    torch.testing.assert_close(mem, want_state["mem"])
    assert seen.shape == (2, 1) and seen.dtype == torch.float32 and bool((seen == 1).all())  # the number as a counter


def test_a_model_without_a_step_does_not_stream() -> None:
    with pytest.raises(ExportError, match="^plainnet has no init_state/step methods: it does not stream$"):
        StepGraph(nn.Linear(2, 2), SPEC, name="plainnet")
    with pytest.raises(ExportError, match="^Linear has no init_state/step methods"):
        StepGraph(nn.Linear(2, 2), SPEC)


@pytest.mark.parametrize(("init", "message"), [
    (lambda b: {"mem": torch.zeros(b, 3, 2), "seen": {1, 2}},
     "the streaming state holds a set at seen; exportable states are tensors and numbers in tuples, lists, dicts"),
    (lambda b: {"mem": torch.zeros(3)}, r"state tensor mem \(3,\) has no single batch dimension"),
    (lambda b: {"mem": torch.zeros(b, 0)}, "state tensor mem is empty; zero-size inputs do not export"),
    (lambda b: {"mem": torch.arange(float(b * 2)).reshape(b, 2)},
     "the initial state tensor mem is not constant; the export describes each initial state by one value"),
])
def test_a_state_the_export_cannot_describe_is_refused_naming_its_path(init: Any, message: str) -> None:
    with pytest.raises(ExportError, match=message):
        StepGraph(DictState(init=init), SPEC, batch_size=2)


@pytest.mark.parametrize(("after", "message"), [
    (lambda state, mem: {"mem": mem}, "the streaming state changed structure at the top"),
    (lambda state, mem: {"mem": None, "seen": 1}, "the streaming state changed structure: mem was a tensor, now "
                                                  "NoneType"),
    (lambda state, mem: {"mem": mem, "seen": True}, "seen was a tensor, now bool"),
    (lambda state, mem: [mem, 1], "the streaming state changed structure at the top"),
])
def test_a_step_that_changes_the_state_structure_is_refused(after: Any, message: str) -> None:
    graph = StepGraph(DictState(after=after).eval(), SPEC, batch_size=1)
    with pytest.raises(ExportError, match=message), torch.no_grad():
        graph(torch.zeros(1, 3, 2), *graph.initial_state())


def test_a_none_or_a_list_in_the_state_must_stay_one() -> None:
    def init(b: int) -> Any:
        return {"mem": torch.zeros(b, 3, 2), "spare": None, "pair": [torch.zeros(b, 1), 0]}

    keep = StepGraph(DictState(init=init, after=lambda s, mem: {**s, "mem": mem}).eval(), SPEC, batch_size=1)
    assert [s.path for s in keep.states] == ["mem", "pair[0]", "pair[1]"]
    with torch.no_grad():
        assert len(keep(torch.zeros(1, 3, 2), *keep.initial_state())) == 4
    for after, message in ((lambda s, mem: {**s, "mem": mem, "spare": mem}, "spare was None, now Tensor"),
                           (lambda s, mem: {**s, "mem": mem, "pair": [mem]}, r"changed structure at pair$")):
        graph = StepGraph(DictState(init=init, after=after).eval(), SPEC, batch_size=1)
        with pytest.raises(ExportError, match=message), torch.no_grad():
            graph(torch.zeros(1, 3, 2), *graph.initial_state())


def test_the_exported_lif_with_the_subtract_reset_follows_the_neuron_equation() -> None:
    # U[t] = beta * U[t-1] + I[t] - R[t] * U_thr, R[t] = [U[t-1] > U_thr], S[t] = [U[t] > U_thr] (tactile_zoo.nn.lif)
    lif = MultiStepLIF(beta=0.8, threshold=0.3, reset="subtract", input_scale=0.5)
    plain = _for_export(nn.Sequential(lif))[0]
    assert type(plain) is _PlainLIF and type(lif) is MultiStepLIF  # a copy: the model itself is left as it is
    x = torch.rand(12, 2, 5, generator=torch.Generator().manual_seed(3)) * 2  # (T, B, N): several spikes and resets
    mem, want = torch.zeros(2, 5), []
    for x_t in x * 0.5:
        mem = (mem * 0.8 + x_t) - (mem > 0.3).float() * 0.3
        want.append((mem > 0.3).float())
    with torch.no_grad():
        spikes, last = plain(x, return_mem=True)
    assert 0 < float(spikes.sum()) < spikes.numel()
    torch.testing.assert_close(spikes, torch.stack(want), rtol=0, atol=0)
    torch.testing.assert_close(last, mem, rtol=0, atol=0)
