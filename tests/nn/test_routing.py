"""Top-k routing between neighbouring columns: the nearest-neighbour table, the read written as the released
indexing does it (every neighbour's populations gathered, then the selected groups), and where gradients go."""

from __future__ import annotations

import torch

from tactile_zoo.nn.routing import NeighbourTopKRouter, nearest_neighbours


def test_nearest_neighbours_rank_by_distance_and_skip_the_taxel_itself() -> None:
    line = torch.tensor([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [7.0, 0.0]])
    assert nearest_neighbours(line, 2).tolist() == [[1, 2], [0, 2], [1, 0], [2, 1]]


def _router() -> NeighbourTopKRouter:
    torch.manual_seed(0)
    pos = torch.rand(6, 2)
    return NeighbourTopKRouter(5, nearest_neighbours(pos, 3), populations=4, size=2, ratio=0.25, gate_hidden=7)


def test_the_read_equals_gathering_every_neighbour_then_the_selected_groups() -> None:
    router = _router()
    assert router.select_num == 3  # int(3 neighbours * 4 populations * 0.25)
    torch.manual_seed(1)
    x, spikes = torch.randn(2, 6, 5), torch.rand(2, 6, 4 * 2)
    index = router.select(x)
    scores = router.gate_w2 @ torch.nn.functional.gelu(torch.nn.functional.layer_norm(
        x @ router.gate_w1.T + router.gate_b1, (7,), router.gate_ln_w, router.gate_ln_b)).unsqueeze(-1)
    assert torch.equal(index, (scores.squeeze(-1) + router.gate_b2).topk(3, dim=-1)[1])
    groups = spikes[:, router.neighbours, :].reshape(2, 6, 3 * 4, 2)  # (B, N, k * P, S): neighbour-major
    picked = groups.gather(2, index.unsqueeze(-1).expand(-1, -1, -1, 2)).reshape(2, 6, -1)
    torch.testing.assert_close(router(spikes, index), router.norm(router.aggregate(picked)))


def test_the_gate_is_fixed_and_the_read_learns() -> None:
    router = _router()
    names = {n for n, _ in router.named_parameters()}
    assert names == {"aggregate.weight", "aggregate.bias", "norm.weight", "norm.bias"}
    assert {"gate_w1", "gate_b1", "gate_ln_w", "gate_ln_b", "gate_w2", "gate_b2"} <= set(router.state_dict())
    x, spikes = torch.randn(2, 6, 5), torch.rand(2, 6, 8, requires_grad=True)
    router(spikes, router.select(x)).pow(2).sum().backward()
    assert router.aggregate.weight.grad.abs().sum() > 0 and spikes.grad.abs().sum() > 0


def test_the_read_is_the_gather_it_replaced_and_so_are_its_gradients() -> None:
    """The read selects whole rows of a (B * N * P, S) table; revision 1 of the model gathered along dim 1 with the
    index expanded over S. The same values (bit for bit) and the same gradients (within 1e-5 of the largest), shared
    rows included (a group read by several columns sums their gradients)."""
    router = _router()
    torch.manual_seed(2)
    x, spikes = torch.randn(3, 6, 5), (torch.rand(3, 6, 8) < 0.3).float().requires_grad_(True)
    index = router.select(x)
    rows = router.neighbours[torch.arange(6)[:, None], index // 4] * 4 + index % 4  # (B, N, m)
    assert any(len(set(r)) < len(r) for r in rows.reshape(3, -1).tolist())  # a group read twice in a sample
    gathered = spikes.reshape(3, 24, 2).gather(1, rows.reshape(3, -1, 1).expand(-1, -1, 2)).reshape(3, 6, -1)
    old = router.norm(router.aggregate(gathered))
    new = router(spikes, index)
    assert torch.equal(new, old)
    weight = torch.randn_like(new)
    (g_old,) = torch.autograd.grad((old * weight).sum(), spikes)
    (g_new,) = torch.autograd.grad((new * weight).sum(), spikes)
    assert float((g_new - g_old).abs().max()) <= 1e-5 * float(g_old.abs().max())
