"""Sensors: taxel graphs (MST and its tie rule, knn, radius, grid), image grids, and the frozen Sensor value."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections import deque
from fractions import Fraction

import pytest
import torch
from scipy.sparse.csgraph import minimum_spanning_tree

from tactile_zoo.data.sensors import TACTILESGNET_EDGES, Sensor, knn_edges, mst_edges, radius_edges, rasterize
from tactile_zoo.errors import ConfigError
from tactile_zoo.registry import get_sensor

NEUTOUCH, BIOTAC, OPTO, USKIN = (get_sensor(n) for n in ("neutouch", "biotac_sp", "optoforce3", "uskin_allegro"))

# The BioTac SP image layout of the ConvLSTM source, electrode i (1-based) at (R[i-1], C[i-1]), copied from issue 2.
BIOTAC_R = [0, 1, 4, 5, 6, 7, 8, 9, 10, 11, 0, 1, 4, 5, 6, 7, 8, 9, 10, 11, 2, 3, 3, 5]
BIOTAC_C = [1, 2, 0, 1, 3, 0, 1, 4, 2, 1, 9, 8, 10, 9, 7, 10, 9, 6, 8, 9, 5, 4, 6, 5]


def pairs(edge_index: torch.Tensor) -> list[tuple[int, int]]:
    assert edge_index.dtype == torch.long and edge_index.dim() == 2 and edge_index.shape[0] == 2
    return [(int(a), int(b)) for a, b in edge_index.t()]


def undirected(edge_index: torch.Tensor) -> set[tuple[int, int]]:
    """The undirected edge set, after checking the directed one is symmetric, loop-free and duplicate-free."""
    directed = pairs(edge_index)
    assert len(set(directed)) == len(directed), "duplicate edges"
    assert all(a != b for a, b in directed), "self-loops"
    assert set(directed) == {(b, a) for a, b in directed}, "not symmetric"
    return {(min(a, b), max(a, b)) for a, b in directed}


def components(n: int, edges: set[tuple[int, int]]) -> list[set[int]]:
    adj: dict[int, set[int]] = {i: set() for i in range(n)}
    for a, b in edges:
        adj[a].add(b)
        adj[b].add(a)
    seen: set[int] = set()
    out = []
    for start in range(n):
        if start in seen:
            continue
        comp, todo = {start}, deque([start])
        while todo:
            for nb in adj[todo.popleft()] - comp:
                comp.add(nb)
                todo.append(nb)
        seen |= comp
        out.append(comp)
    return out


def reference_prim(positions, root: int) -> set[tuple[int, int]]:
    """The tie rule of the TactileSGNet reference, literally, in exact arithmetic on the decimal coordinates:
    the shortest edge from the visited set, ties to the earliest-visited taxel, then the lowest unvisited index."""
    pts = [tuple(Fraction(str(c)) for c in p) for p in positions]
    d2 = {(a, b): sum((x - y) ** 2 for x, y in zip(pts[a], pts[b])) for a in range(len(pts)) for b in range(len(pts))}
    visited, todo, edges = [root], set(range(len(pts))) - {root}, set()
    while todo:
        _, _, b, a = min((d2[a, b], rank, b, a) for rank, a in enumerate(visited) for b in todo)
        edges.add((min(a, b), max(a, b)))
        visited.append(b)
        todo.remove(b)
    return edges


# ----------------------------------------------------------------------------------------------- MST
def test_neutouch_default_graph_is_the_reference_tree():
    edges = undirected(NEUTOUCH.edge_index())
    assert NEUTOUCH.num_nodes == 39 and len(edges) == 38
    assert len(components(39, edges)) == 1  # 38 edges + connected = a spanning tree
    assert edges == {tuple(sorted(p)) for p in TACTILESGNET_EDGES}
    assert NEUTOUCH.positions[20] == (0.0, 0.0) and (15, 20) in edges and (16, 20) in edges
    # a minimum spanning tree, like ours from the same root: they differ only in two edges, each swapped for its
    # mirror image of the same length (the reference's order among exactly equal distances)
    ours = undirected(NEUTOUCH.edge_index("mst", root=20))
    assert ours == reference_prim(NEUTOUCH.positions, 20)
    assert sorted(edges - ours) == [(9, 13), (23, 27)] and sorted(ours - edges) == [(8, 11), (22, 28)]
    for a, b in ((9, 13), (23, 27)):
        mirror = {(9, 13): (8, 11), (23, 27): (22, 28)}[a, b]
        assert math.dist(NEUTOUCH.positions[a], NEUTOUCH.positions[b]) == pytest.approx(
            math.dist(NEUTOUCH.positions[mirror[0]], NEUTOUCH.positions[mirror[1]]), rel=1e-12)
    dist = torch.cdist(torch.tensor(NEUTOUCH.positions, dtype=torch.float64),
                       torch.tensor(NEUTOUCH.positions, dtype=torch.float64))
    optimum = minimum_spanning_tree(dist.numpy()).sum()
    assert sum(float(dist[a, b]) for a, b in edges) == pytest.approx(optimum, rel=1e-12)


@pytest.mark.real_data
def test_neutouch_default_graph_equals_the_shared_reference_edge_list(shared_data):
    listed = json.loads((shared_data / "ev_objects" / "reference_mst_edges.json").read_text())["edges"]
    assert undirected(NEUTOUCH.edge_index()) == {tuple(sorted(p)) for p in listed}


def test_explicit_edges_are_checked_and_a_tiled_reference_sensor_is_one_mst():
    with pytest.raises(ConfigError, match="self-loops or name no taxel"):
        NEUTOUCH.edge_index("edges", pairs=((0, 39),))
    assert undirected(NEUTOUCH.edge_index("edges", pairs=((1, 0), (0, 1), (2, 3)))) == {(0, 1), (2, 3)}


def tree_length(positions, edges: set[tuple[int, int]]) -> float:
    return sum(math.dist(positions[a], positions[b]) for a, b in edges)


@pytest.mark.parametrize("positions, root, expected, other_rule", [
    # 1 is equally far (sqrt 5) from the root 3 (visited first) and from 0 (visited second, lower index): the
    # earliest-visited taxel wins, not the lowest index
    (((2, 0), (1, 2), (4, 0), (0, 0)), 3, {(0, 3), (0, 2), (1, 3)}, {(0, 3), (0, 2), (0, 1)}),
    # 1 and 3 tie from the root 2: the lower index, 1, joins first, so 0 (equally far from 1 and 3) hangs from 1
    (((1, 1), (0, 1), (0, 0), (1, 0)), 2, {(1, 2), (2, 3), (0, 1)}, {(1, 2), (2, 3), (0, 3)}),
])
def test_mst_tie_rule(positions, root, expected, other_rule):
    assert {(min(a, b), max(a, b)) for a, b in mst_edges(positions, root=root)} == expected
    assert reference_prim(positions, root) == expected
    assert undirected(Sensor("tie", positions, (4, 4), tuple((i, i) for i in range(4)), "mst",
                             (("root", root),)).edge_index()) == expected
    # another tie rule builds another tree of the same length: the rule, not the geometry, decides
    assert other_rule != expected and len(components(4, other_rule)) == 1
    assert tree_length(positions, other_rule) == pytest.approx(tree_length(positions, expected))


@pytest.mark.parametrize("seed", range(5))
def test_mst_matches_the_reference_rule_on_tie_heavy_layouts(seed):
    gen = torch.Generator().manual_seed(seed)
    cells = torch.randperm(49, generator=gen)[:20].tolist()  # 20 points of a 7x7 lattice: many equal distances
    positions = tuple((float(c // 7), float(c % 7) * 0.5) for c in cells)
    root = int(torch.randint(0, 20, (1,), generator=gen))
    assert {(min(a, b), max(a, b)) for a, b in mst_edges(positions, root=root)} == reference_prim(positions, root)


def test_mst_threshold_adds_the_close_pairs():
    tree = undirected(NEUTOUCH.edge_index("mst", root=20))
    plus = undirected(NEUTOUCH.edge_index("mst", root=20, threshold=2.0))
    close = {(a, b) for a, b in itertools.combinations(range(39), 2)
             if math.dist(NEUTOUCH.positions[a], NEUTOUCH.positions[b]) < 2.0}
    assert plus == tree | close and len(plus) > len(tree)


def test_tiled_sensor_is_one_tree_and_keeps_its_grid():
    tiled = NEUTOUCH.tiled(16)
    assert tiled.num_nodes == 16 * 39 and tiled.grid_shape == (9, 13 * 16)
    edges = undirected(tiled.edge_index())
    assert len(edges) == tiled.num_nodes - 1 and len(components(tiled.num_nodes, edges)) == 1
    assert len(set(tiled.grid)) == tiled.num_nodes


# ----------------------------------------------------------------------------------------------- knn and radius
@pytest.mark.parametrize("sensor, k", [(NEUTOUCH, 1), (NEUTOUCH, 4), (BIOTAC, 4), (USKIN, 3)])
def test_knn_is_symmetric_and_holds_each_taxels_nearest(sensor, k):
    edges = undirected(sensor.edge_index("knn", k=k))
    n = sensor.num_nodes
    expected = set()
    for a in range(n):
        near = sorted(range(n), key=lambda b: (math.dist(sensor.positions[a], sensor.positions[b]), b))
        expected |= {(min(a, b), max(a, b)) for b in [b for b in near if b != a][:k]}
    assert edges == expected
    degree = torch.bincount(sensor.edge_index("knn", k=k)[0], minlength=n)
    assert int(degree.min()) >= k


def test_radius_graph():
    for r in (1.5, 2.0, 3.0):
        edges = undirected(NEUTOUCH.edge_index("radius", r=r))
        assert edges == {(a, b) for a, b in itertools.combinations(range(39), 2)
                         if math.dist(NEUTOUCH.positions[a], NEUTOUCH.positions[b]) <= r}
    assert NEUTOUCH.edge_index("radius", r=0.1).shape == (2, 0)
    assert radius_edges(((0, 0), (1, 0)), 1.0) == {(0, 1)} and radius_edges(((0, 0), (1, 0)), 1.0, strict=True) == set()


def test_full_graph_of_the_optoforce_gripper():
    assert undirected(OPTO.edge_index()) == {(0, 1), (0, 2), (1, 2)}


@pytest.mark.parametrize("kind, kwargs", [("knn", {"k": 0}), ("knn", {"k": 39}), ("radius", {}), ("bogus", {}),
                                          ("mst", {"root": 39})])
def test_bad_graph_arguments_are_config_errors(kind, kwargs):
    with pytest.raises(ConfigError, match="neutouch|k=|root"):
        NEUTOUCH.edge_index(kind, **kwargs)


def test_knn_edges_rejects_bad_k():
    with pytest.raises(ConfigError):
        knn_edges(((0, 0), (1, 1)), 2)


# ----------------------------------------------------------------------------------------------- uSkin
def test_uskin_fingertips_rows_and_grid_graph():
    assert USKIN.num_nodes == 60 and USKIN.grid_shape == (6, 12)
    for tip in range(2):
        cells = USKIN.grid[30 * tip:30 * (tip + 1)]
        rows = [sorted(c - 6 * tip for r, c in cells if r == row) for row in range(6)]
        assert [len(r) for r in rows] == [2, 4, 6, 6, 6, 6]
        assert rows[0] == [2, 3] and rows[1] == [1, 2, 3, 4] and all(r == list(range(6)) for r in rows[2:])
    edges = undirected(USKIN.edge_index())
    assert all((a < 30) == (b < 30) for a, b in edges), "an edge crosses between fingertips"
    for a, b in edges:  # grid neighbours only
        (ra, ca), (rb, cb) = USKIN.grid[a], USKIN.grid[b]
        assert abs(ra - rb) + abs(ca - cb) == 1
    # per fingertip 24 horizontal (1 + 3 + 5 * 4) and 24 vertical (2 + 4 + 6 * 3) neighbour pairs
    assert len(edges) == 2 * 48
    assert sorted(map(min, components(60, edges))) == [0, 30]
    # columns 5 and 6 touch on the image but belong to different fingertips
    cell = {rc: i for i, rc in enumerate(USKIN.grid)}
    assert (cell[(3, 5)], cell[(3, 6)]) not in edges


# ----------------------------------------------------------------------------------------------- image grids
def test_biotac_grid_is_the_convlstm_layout():
    assert BIOTAC.num_nodes == 24 and BIOTAC.grid_shape == (12, 11) and BIOTAC.grid_fill == 2
    assert list(BIOTAC.grid) == list(zip(BIOTAC_R, BIOTAC_C))
    assert len(set(BIOTAC.grid)) == 24
    # electrodes 11..20 mirror 1..10 in z
    assert all(BIOTAC.positions[i + 10] == (x, y, -z) for i, (x, y, z) in enumerate(BIOTAC.positions[:10]))


def test_neutouch_rasterised_grid():
    h, w = NEUTOUCH.grid_shape
    assert len(set(NEUTOUCH.grid)) == 39 and all(0 <= r < h and 0 <= c < w for r, c in NEUTOUCH.grid)
    assert NEUTOUCH.grid == rasterize(NEUTOUCH.positions, (h, w))
    assert NEUTOUCH.grid[20] == ((h - 1) // 2, (w - 1) // 2)  # the centre taxel on the centre cell
    assert NEUTOUCH.grid[0][0] == 0 and NEUTOUCH.grid[38][0] == h - 1  # x = -6 and x = 6 on the first/last row
    # the first coordinate maps to rows and the second to columns, monotonically
    for a, b in itertools.combinations(range(39), 2):
        (xa, ya), (xb, yb) = NEUTOUCH.positions[a], NEUTOUCH.positions[b]
        if xb - xa > 3:
            assert NEUTOUCH.grid[a][0] < NEUTOUCH.grid[b][0]
        if yb - ya > 3:
            assert NEUTOUCH.grid[a][1] < NEUTOUCH.grid[b][1]


def test_rasterize_moves_a_colliding_taxel_to_the_nearest_free_cell():
    # taxel 1 rounds onto taxel 0's cell and moves to the closest free one, (0, 1)
    assert rasterize(((0, 0), (0, 0.1), (1, 1)), (2, 2)) == ((0, 0), (0, 1), (1, 1))
    with pytest.raises(ConfigError, match="cannot hold"):
        rasterize(((0, 0), (1, 1), (2, 2)), (1, 2))


# ----------------------------------------------------------------------------------------------- the Sensor value
def test_sensor_is_frozen_and_hashable():
    twin = Sensor(NEUTOUCH.name, NEUTOUCH.positions, NEUTOUCH.grid_shape, NEUTOUCH.grid, NEUTOUCH.default_graph,
                  NEUTOUCH.graph_kwargs, NEUTOUCH.groups, NEUTOUCH.grid_fill, NEUTOUCH.channels, "other words")
    assert twin == NEUTOUCH and hash(twin) == hash(NEUTOUCH) and {NEUTOUCH: 1}[twin] == 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        NEUTOUCH.name = "x"  # type: ignore[misc]
    # lists in, tuples stored: still hashable, equal to the tuple-built one, and immune to the caller's lists
    positions, grid = [list(p) for p in OPTO.positions], [list(c) for c in OPTO.grid]
    from_lists = Sensor("optoforce3", positions, list(OPTO.grid_shape), grid, "full", channels=list(OPTO.channels))
    positions[0][0] = 99.0
    assert from_lists == OPTO and hash(from_lists) == hash(OPTO) and from_lists.positions[0][0] != 99.0
    assert len({BIOTAC, NEUTOUCH, OPTO, USKIN, twin}) == 4


@pytest.mark.parametrize("kwargs, message", [
    ({"grid": ((0, 0), (0, 0))}, "share"),
    ({"grid": ((0, 0), (5, 5))}, "outside"),
    ({"grid": ((0, 0),)}, "grid cells for 2 taxels"),
    ({"positions": ((0.0, 0.0), (1.0,))}, "equal-length"),
    ({"groups": (0,)}, "group ids"),
])
def test_inconsistent_sensors_are_refused(kwargs, message):
    base = {"name": "bad", "positions": ((0.0, 0.0), (1.0, 0.0)), "grid_shape": (1, 2), "grid": ((0, 0), (0, 1))}
    with pytest.raises(ConfigError, match=message):
        Sensor(**{**base, **kwargs})


def test_edge_index_returns_a_copy():
    first = NEUTOUCH.edge_index()
    reference = first.clone()
    first.zero_()
    first[0, 0] = 7
    assert torch.equal(NEUTOUCH.edge_index(), reference)
    assert NEUTOUCH.edge_index().data_ptr() != NEUTOUCH.edge_index().data_ptr()
