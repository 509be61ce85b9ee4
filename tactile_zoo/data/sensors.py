"""Sensors: taxel geometry, the taxel graph for graph models and the image grid for image models.

A :class:`Sensor` is frozen and hashable (tuples, not arrays) so a :class:`~tactile_zoo.data.spec.DatasetSpec` can
carry it and caches can key on it. Four are built in:

``neutouch``
    The NeuTouch fingertip of Ev-Objects / Ev-Containers: 39 taxels, channels = ON/OFF event polarity. The default
    graph is the exact 38-edge tree the TactileSGNet reference trains on (:data:`TACTILESGNET_EDGES`): Prim's tree
    grown from taxel 20, with that code's own order among equal-length edges. :func:`mst_edges` (``"mst"``) builds
    the same tree with a rounding-proof tie rule and differs from it in 2 of 38 edges, each swapped for its mirror
    image of equal length. :data:`NEUTOUCH_HAND_EDGES` is the hand-made 73-edge graph of the same releases, which
    DeepTactile trains on (``edge_index("edges", pairs=NEUTOUCH_HAND_EDGES)``).
``biotac_sp``
    BioTac SP of BioTac-DoS: 24 electrodes in 3-D; the image layout is the 12x11 one of the ConvLSTM source
    (Zapata-Impata et al., Sensors 2019), whose empty cells image models fill with their neighbours' mean twice.
``optoforce3``
    Three OptoForce 3-axis point sensors on a three-finger Jaco gripper (Augment8000): a fully connected 3-node graph
    on a 1x3 grid.
``uskin_allegro``
    Two uSkin fingertips (30 taxels each, a 6x6 grid without its six corner cells) on an Allegro hand
    (ALU-Textures): graph = 4-neighbours on the grid within each fingertip; image = both fingertips side by side, 6x12.

Rasterising free-form positions (NeuTouch) onto an image grid: positions are scaled linearly onto the lattice and
rounded to the nearest cell; a taxel whose cell is taken moves to the nearest free cell (Euclidean distance on the
lattice, ties to the lower row then column), taxels placed in index order. See :func:`rasterize`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ..errors import ConfigError
from ..registry import register_sensor

__all__ = ["Sensor", "TACTILESGNET_EDGES", "NEUTOUCH_HAND_EDGES", "mst_edges", "knn_edges", "radius_edges",
           "rasterize", "NEUTOUCH", "BIOTAC_SP", "OPTOFORCE3", "USKIN_ALLEGRO"]

Pos = tuple[float, ...]


@dataclass(frozen=True)
class Sensor:
    """A tactile sensor array.

    Args:
        name: canonical snake_case name.
        positions: taxel coordinates, 2-D or 3-D, in taxel index order.
        grid_shape: ``(H, W)`` of the image grid image models use.
        grid: ``(row, col)`` per taxel; no two taxels share a cell.
        default_graph: the ``kind`` :meth:`edge_index` builds by default.
        graph_kwargs: keyword arguments of the default graph, as ``((key, value), ...)``.
        groups: per-taxel group id (e.g. fingertip); ``grid`` graphs never connect two groups.
        grid_fill: passes of empty-cell filling (mean of non-empty 8-neighbours) image models apply.
        channels: names of the per-taxel channels the sensor's datasets carry.
    """

    name: str
    positions: tuple[Pos, ...]
    grid_shape: tuple[int, int]
    grid: tuple[tuple[int, int], ...]
    default_graph: str = "knn"
    graph_kwargs: tuple[tuple[str, Any], ...] = ()
    groups: tuple[int, ...] = ()
    grid_fill: int = 0
    channels: tuple[str, ...] = ()
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        # lists or arrays passed in would make the sensor unhashable (and mutable through the caller's reference)
        kwargs = self.graph_kwargs.items() if isinstance(self.graph_kwargs, dict) else self.graph_kwargs
        for attr, value in (
            ("positions", tuple(tuple(float(v) for v in p) for p in self.positions)),
            ("grid_shape", tuple(int(v) for v in self.grid_shape)),
            ("grid", tuple((int(r), int(c)) for r, c in self.grid)),
            ("graph_kwargs", tuple((str(k), v) for k, v in kwargs)),
            ("groups", tuple(int(v) for v in self.groups)),
            ("channels", tuple(str(v) for v in self.channels)),
        ):
            object.__setattr__(self, attr, value)
        if len(self.grid_shape) != 2:
            raise ConfigError(f"sensor {self.name!r}: grid_shape must be (H, W), got {self.grid_shape}")
        n = len(self.positions)
        if n == 0 or len({len(p) for p in self.positions}) != 1:
            raise ConfigError(f"sensor {self.name!r}: positions must be a non-empty list of equal-length tuples")
        if len(self.grid) != n:
            raise ConfigError(f"sensor {self.name!r}: {len(self.grid)} grid cells for {n} taxels")
        h, w = self.grid_shape
        if len(set(self.grid)) != n:
            raise ConfigError(f"sensor {self.name!r}: two taxels share an image-grid cell")
        if any(not (0 <= r < h and 0 <= c < w) for r, c in self.grid):
            raise ConfigError(f"sensor {self.name!r}: a grid cell lies outside the {h}x{w} grid")
        if self.groups and len(self.groups) != n:
            raise ConfigError(f"sensor {self.name!r}: {len(self.groups)} group ids for {n} taxels")

    @property
    def num_nodes(self) -> int:
        return len(self.positions)

    def edge_index(self, kind: str = "default", **kwargs: Any) -> torch.Tensor:
        """The taxel graph as a ``LongTensor [2, E]``: symmetric, no self-loops, no duplicate edges, sorted.

        Kinds: ``mst`` (``threshold=`` adds all pairs closer than it), ``knn`` (``k=``, default 3), ``radius`` (``r=``),
        ``full``, ``grid`` (4-neighbours on the image grid, within a group), ``edges`` (an explicit list,
        ``pairs=((a, b), ...)``), ``default`` (the sensor's own).
        """
        if kind == "default":
            kind, kwargs = self.default_graph, {**dict(self.graph_kwargs), **kwargs}
        return _edge_index_cached(self, kind, tuple(sorted(kwargs.items()))).clone()

    def tiled(self, copies: int) -> Sensor:
        """``copies`` side-by-side copies of this sensor (for scaling studies over N), each its own group."""
        if copies < 1:
            raise ConfigError("copies must be >= 1")
        span = max(p[0] for p in self.positions) - min(p[0] for p in self.positions) + 1.0
        h, w = self.grid_shape
        positions = tuple((p[0] + i * span, *p[1:]) for i in range(copies) for p in self.positions)
        grid = tuple((r, c + i * w) for i in range(copies) for r, c in self.grid)
        base_groups = self.groups or (0,) * self.num_nodes
        n_groups = max(base_groups) + 1
        groups = tuple(g + i * n_groups for i in range(copies) for g in base_groups)
        # an MST over copies stays one tree; other kinds keep their parameters. An explicit edge list describes one
        # copy, so a tiled sensor takes one MST over all copies instead (scaling studies want one connected graph)
        graph, kwargs = self.default_graph, self.graph_kwargs
        if graph == "edges":
            graph, kwargs = "mst", ()
        return Sensor(f"{self.name}_x{copies}", positions, (h, w * copies), grid, graph, kwargs, groups,
                      self.grid_fill, self.channels, self.description)


# ----------------------------------------------------------------------------------------------- graph builders
def _pairs_to_edge_index(pairs: set[tuple[int, int]]) -> torch.Tensor:
    both = sorted({(a, b) for a, b in pairs if a != b} | {(b, a) for a, b in pairs if a != b})
    if not both:
        return torch.empty(2, 0, dtype=torch.long)
    return torch.tensor(both, dtype=torch.long).t().contiguous()


def _distances(positions: tuple[Pos, ...]) -> np.ndarray:
    """Euclidean distance matrix ``(N, N)``, one coordinate at a time (no ``(N, N, D)`` temporary)."""
    pos = np.asarray(positions, dtype=np.float64)  # (N, D)
    sq = np.zeros((len(pos), len(pos)))
    for d in range(pos.shape[1]):
        sq += (pos[:, None, d] - pos[None, :, d]) ** 2  # (N, N)
    return np.sqrt(sq)


def mst_edges(positions: tuple[Pos, ...], root: int | None = None, threshold: float | None = None
              ) -> set[tuple[int, int]]:
    """Prim's minimum spanning tree grown from ``root`` (default: the taxel nearest the centroid).

    Each step adds the shortest Euclidean edge from the visited set to an unvisited taxel. Ties go to the visited
    taxel added earliest, then to the unvisited taxel of lowest index, as in the TactileSGNet reference. Distances
    within 1e-9 (relative) count as tied: geometrically equal distances can differ in their last bits, and the tie
    rule must not depend on rounding. With ``threshold``, every pair closer than it is added as well.

    ``O(N^2)``: each taxel keeps its best edge into the visited set, so tiled sensors of thousands of taxels stay fast.
    """
    n = len(positions)
    dist = _distances(positions)
    if root is None:
        centre = np.asarray(positions, dtype=np.float64).mean(axis=0)
        root = min(range(n), key=lambda i: (math.dist(positions[i], centre), i))
    if not 0 <= root < n:
        raise ConfigError(f"mst root {root} is not a taxel index (0..{n - 1})")
    tol = 1e-9 * max(1.0, float(dist.max()))
    best_d = dist[root].copy()  # per taxel: shortest distance to the visited set ...
    best_src = np.full(n, root)  # ... reached from this visited taxel ...
    best_rank = np.zeros(n, dtype=np.int64)  # ... which was the best_rank-th one visited
    unvisited = np.ones(n, dtype=bool)
    unvisited[root] = False
    pairs: set[tuple[int, int]] = set()
    for rank in range(1, n):
        cand = np.flatnonzero(unvisited)
        near = cand[best_d[cand] <= best_d[cand].min() + tol]
        # updates below only on a strictly shorter edge, so best_src is already the earliest-visited among ties
        b = int(min(near, key=lambda j: (best_rank[j], j)))
        pairs.add((int(best_src[b]), b))
        unvisited[b] = False
        closer = unvisited & (dist[b] < best_d - tol)
        best_d[closer], best_src[closer], best_rank[closer] = dist[b, closer], b, rank
    if threshold is not None:
        pairs |= radius_edges(positions, threshold, strict=True)
    return pairs


#: ``k`` of a ``knn`` graph when none is given: the TactileSGNet reference's (``TactileGraph(k=3, ...)`` in its
#: to_graph.py), the one source among the zoo's that builds a knn taxel graph
KNN_DEFAULT_K = 3


def knn_edges(positions: tuple[Pos, ...], k: int = KNN_DEFAULT_K) -> set[tuple[int, int]]:
    """Each taxel joined to its ``k`` nearest others (ties to the lower index), then symmetrised.

    Args:
        positions: the taxel positions.
        k: neighbours per taxel, ``1 <= k < N`` (default :data:`KNN_DEFAULT_K`, 3).
    """
    n = len(positions)
    if not isinstance(k, int) or not 1 <= k < n:
        raise ConfigError(f"knn graph needs an integer 1 <= k < {n}, got k={k!r}")
    dist = _distances(positions)
    np.fill_diagonal(dist, np.inf)
    nearest = np.argsort(dist, axis=1, kind="stable")[:, :k]  # (N, k); stable keeps the lower index first on ties
    return {(min(a, int(b)), max(a, int(b))) for a in range(n) for b in nearest[a]}


def radius_edges(positions: tuple[Pos, ...], r: float, strict: bool = False) -> set[tuple[int, int]]:
    """All pairs within distance ``r`` (``< r`` if ``strict``)."""
    dist = _distances(positions)
    close = np.triu(dist < r if strict else dist <= r, k=1)
    return {(int(a), int(b)) for a, b in zip(*np.nonzero(close))}


def _grid_edges(sensor: Sensor, diagonal: bool = False) -> set[tuple[int, int]]:
    cell = {rc: i for i, rc in enumerate(sensor.grid)}
    groups = sensor.groups or (0,) * sensor.num_nodes
    steps = [(0, 1), (1, 0)] + ([(1, 1), (1, -1)] if diagonal else [])
    pairs = set()
    for i, (r, c) in enumerate(sensor.grid):
        for dr, dc in steps:
            j = cell.get((r + dr, c + dc))
            if j is not None and groups[i] == groups[j]:
                pairs.add((min(i, j), max(i, j)))
    return pairs


def _explicit_edges(sensor: Sensor, pairs: tuple[tuple[int, int], ...]) -> set[tuple[int, int]]:
    n = sensor.num_nodes
    out = {(min(int(a), int(b)), max(int(a), int(b))) for a, b in pairs}
    bad = sorted(p for p in out if not (0 <= p[0] < n and 0 <= p[1] < n) or p[0] == p[1])
    if bad:
        raise ConfigError(f"sensor {sensor.name!r}: edges {bad[:3]} are self-loops or name no taxel (0..{n - 1})")
    return out


@functools.lru_cache(maxsize=256)
def _edge_index_cached(sensor: Sensor, kind: str, kwargs: tuple[tuple[str, Any], ...]) -> torch.Tensor:
    kw = dict(kwargs)
    try:
        if kind == "mst":
            # one tree per group would leave a tiled sensor disconnected from itself; one tree over all is fine
            pairs = mst_edges(sensor.positions, **kw)
        elif kind == "knn":
            pairs = knn_edges(sensor.positions, **kw)
        elif kind == "radius":
            pairs = radius_edges(sensor.positions, **kw)
        elif kind == "full":
            n = sensor.num_nodes
            pairs = {(a, b) for a in range(n) for b in range(a + 1, n)}
        elif kind == "grid":
            pairs = _grid_edges(sensor, **kw)
        elif kind == "edges":
            pairs = _explicit_edges(sensor, **kw)
        else:
            raise ConfigError(f"unknown graph kind {kind!r} for sensor {sensor.name!r}; "
                              f"choose mst, knn, radius, full, grid, edges or default")
    except TypeError as exc:
        raise ConfigError(f"bad arguments {kw} for a {kind!r} graph of sensor {sensor.name!r}: {exc}") from None
    return _pairs_to_edge_index(pairs)


# ----------------------------------------------------------------------------------------------- image grid
def rasterize(positions: tuple[Pos, ...], grid_shape: tuple[int, int]) -> tuple[tuple[int, int], ...]:
    """Place each taxel on its own cell of an ``(H, W)`` lattice (rule in the module docstring).

    The first coordinate maps to rows, the second to columns.
    """
    h, w = grid_shape
    if h * w < len(positions):
        raise ConfigError(f"a {h}x{w} grid cannot hold {len(positions)} taxels")
    xs, ys = [p[0] for p in positions], [p[1] for p in positions]

    def scale(v: float, lo: float, hi: float, size: int) -> float:
        return 0.0 if hi == lo else (v - lo) / (hi - lo) * (size - 1)

    taken: dict[tuple[int, int], int] = {}
    cells = []
    for i, (x, y) in enumerate(zip(xs, ys)):
        fr, fc = scale(x, min(xs), max(xs), h), scale(y, min(ys), max(ys), w)
        free = [(r, c) for r in range(h) for c in range(w) if (r, c) not in taken]
        r, c = min(free, key=lambda rc: ((rc[0] - fr) ** 2 + (rc[1] - fc) ** 2, rc))
        taken[(r, c)] = i
        cells.append((r, c))
    return tuple(cells)


# ----------------------------------------------------------------------------------------------- built-in sensors
_NEUTOUCH_XY = (
    (-6, 0), (-5.3, -3), (-5.3, 3), (-4.6, -7.8), (-4.6, 7.8), (-3.5, 0), (-3.05, -5.2), (-3.05, 5.2), (-3.1, -1.75),
    (-3.1, 1.75), (-1.6, -8.9), (-1.75, -3), (-1.6, 8.9), (-1.75, 3), (-1.5, 0), (-0.7, -1.3), (-0.7, 1.3), (0, -6),
    (0, 6), (0, -3.5), (0, 0), (0, 3.5), (0.8, -1.3), (0.8, 1.3), (1.6, -8.9), (1.6, 8.9), (1.5, 0), (1.75, 3),
    (1.75, -3), (3.05, -5.2), (3.1, 1.75), (3.05, 5.2), (3.1, -1.75), (3.6, 0), (4.6, -7.8), (4.6, 7.8), (5.3, -3),
    (5.3, 3), (6, 0),
)
_NEUTOUCH_POS = tuple((float(x), float(y)) for x, y in _NEUTOUCH_XY)
#: The 38 undirected edges (0-based taxels) of the graph the TactileSGNet reference code builds for its published
#: runs (clear-nus/TactileSGNet, ``TactileGraph(k=3, useKNN=0)`` in to_graph.py): Prim's tree from taxel 20, where a
#: visited taxel's nearest unvisited one is the first of a ``torch.sort``, an order among exactly equal distances that
#: no rounding-proof rule reproduces, hence the list itself.
TACTILESGNET_EDGES = (
    (0, 5), (1, 8), (2, 9), (3, 6), (3, 10), (4, 7), (4, 12), (5, 8), (5, 9), (6, 11), (7, 13), (9, 13), (11, 19),
    (13, 21), (14, 20), (15, 20), (16, 20), (17, 19), (18, 21), (19, 28), (20, 26), (21, 27), (22, 26), (23, 26),
    (23, 27), (24, 34), (25, 35), (27, 30), (27, 31), (28, 29), (28, 32), (29, 34), (30, 33), (30, 37), (31, 35),
    (32, 33), (32, 36), (33, 38),
)
#: The hand-made NeuTouch graph, 73 undirected edges (0-based taxels): the ``k=0`` branch of ``TactileGraph`` in the
#: to_graph.py of both clear-nus/TactileSGNet and GuoFM/DeepTactile (the same 146 directed pairs, symmetric, without
#: duplicates or self-loops), which DeepTactile's main.py trains on (``k=0, useKNN=False``); graph kind ``"edges"``.
NEUTOUCH_HAND_EDGES = (
    (0, 1), (0, 2), (0, 5), (1, 6), (1, 8), (2, 7), (2, 9), (3, 6), (3, 10), (4, 7), (4, 12), (5, 8), (5, 9), (5, 14),
    (6, 11), (6, 17), (7, 13), (7, 18), (8, 11), (8, 15), (9, 13), (9, 14), (10, 17), (10, 24), (11, 15), (11, 19),
    (12, 18), (12, 25), (13, 16), (13, 21), (14, 15), (14, 16), (14, 20), (15, 20), (15, 22), (16, 20), (16, 23),
    (17, 19), (17, 24), (17, 29), (18, 21), (18, 25), (18, 31), (19, 22), (19, 28), (20, 22), (20, 23), (20, 26),
    (21, 27), (22, 26), (22, 28), (23, 26), (23, 27), (23, 30), (24, 34), (25, 35), (26, 32), (26, 33), (27, 30),
    (27, 31), (28, 29), (28, 32), (29, 34), (29, 36), (30, 33), (30, 37), (31, 35), (31, 37), (32, 33), (32, 36),
    (33, 38), (36, 38), (37, 38),
)
NEUTOUCH = register_sensor(Sensor(
    name="neutouch", positions=_NEUTOUCH_POS, grid_shape=(9, 13), grid=rasterize(_NEUTOUCH_POS, (9, 13)),
    default_graph="edges", graph_kwargs=(("pairs", TACTILESGNET_EDGES),), channels=("on", "off"),
    description="NeuTouch event-based fingertip, 39 taxels (Taunyazov et al., RSS 2020)"))

_BIOTAC_HALF = ((0.386, -0.109, 0.157), (0.319, -0.205, 0.121), (0.087, -0.129, 0.282), (0.084, -0.236, 0.202),
                (-0.019, -0.300, 0.095), (-0.092, -0.120, 0.285), (-0.137, -0.238, 0.187), (-0.223, -0.271, 0.072),
                (-0.321, -0.199, 0.128), (-0.397, -0.100, 0.152))
_BIOTAC_POS = (_BIOTAC_HALF + tuple((x, y, -z) for x, y, z in _BIOTAC_HALF)
               + ((0.259, -0.252, 0.0), (0.170, -0.274, 0.073), (0.170, -0.274, -0.073), (0.075, -0.298, 0.0)))
_BIOTAC_ROWS = (0, 1, 4, 5, 6, 7, 8, 9, 10, 11, 0, 1, 4, 5, 6, 7, 8, 9, 10, 11, 2, 3, 3, 5)
_BIOTAC_COLS = (1, 2, 0, 1, 3, 0, 1, 4, 2, 1, 9, 8, 10, 9, 7, 10, 9, 6, 8, 9, 5, 4, 6, 5)
BIOTAC_SP = register_sensor(Sensor(
    name="biotac_sp", positions=_BIOTAC_POS, grid_shape=(12, 11), grid=tuple(zip(_BIOTAC_ROWS, _BIOTAC_COLS)),
    default_graph="knn", graph_kwargs=(("k", 4),), grid_fill=2, channels=("pressure",),
    description="SynTouch BioTac SP, 24 electrodes (layout from Zapata-Impata et al., Sensors 2019)"))

_OPTO_POS = tuple((round(math.cos(2 * math.pi * i / 3), 6), round(math.sin(2 * math.pi * i / 3), 6)) for i in range(3))
OPTOFORCE3 = register_sensor(Sensor(
    name="optoforce3", positions=_OPTO_POS, grid_shape=(1, 3), grid=((0, 0), (0, 1), (0, 2)), default_graph="full",
    channels=("fx", "fy", "fz", "f_norm"),
    description="Three OptoForce 3-axis sensors on a Jaco three-finger gripper (Maus et al., Augment8000)"))


def _uskin_cells() -> list[tuple[int, int]]:
    """Row-major cells of one fingertip: rows hold 2, 4, 6, 6, 6, 6 taxels (a 6x6 grid without 6 corner cells)."""
    spans = [(2, 4), (1, 5), (0, 6), (0, 6), (0, 6), (0, 6)]
    return [(r, c) for r, (lo, hi) in enumerate(spans) for c in range(lo, hi)]


_USKIN_GRID = tuple((r, c + 6 * tip) for tip in range(2) for r, c in _uskin_cells())
USKIN_ALLEGRO = register_sensor(Sensor(
    name="uskin_allegro", positions=tuple((float(c + tip), float(r)) for tip, (r, c) in
                                          zip([0] * 30 + [1] * 30, _USKIN_GRID)),
    grid_shape=(6, 12), grid=_USKIN_GRID, default_graph="grid", groups=(0,) * 30 + (1,) * 30,
    channels=("x", "y", "z"),
    description="Two Xela uSkin fingertips (30 taxels x 3 axes each) on an Allegro hand"))
