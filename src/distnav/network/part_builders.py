"""Builders of one rank's :class:`~distnav.network.graph_part.GraphPart` that hold no array over the whole network.

Each builder makes the part, owned by ``nodes`` (typically one rank's range of ids,
:class:`~distnav.network.partition.NodeRanges`), of a graph whose whole form a companion builder returns — the same
links and the same global edge ids (edges sorted by ``(dst, src)``, :class:`~distnav.network.graph.Graph`), so a run
on parts gives the bits of a run on the whole graph (tested against :meth:`GraphPart.from_graph`). What a rank holds
is proportional to its own nodes and their halo, never to the whole network (issue 30 item 1):

* :func:`ring_part` (:func:`~distnav.network.builders.ring`) and :func:`grid_part`
  (:func:`~distnav.network.builders.grid`): the neighbours and the global edge ids of a node have closed forms;
* :func:`tiled_random_geometric_part` (:func:`tiled_random_geometric`): a random geometric graph whose points are
  drawn *tile by tile* — the unit square cut into ``T × T`` tiles no narrower than the radius, numbered along a
  Hilbert curve, tile ``k`` holding ``⌊n/T²⌋`` or one more points drawn by its own generator
  (``default_rng([seed, k])``), node ids given tile after tile. A rank draws only its tiles and two rings of tiles
  around them (links of its nodes, of its halo, and the degrees that fix the edge ids); the edge offset of every
  tile (``T² ≈ n / tile_nodes`` numbers) is the sum of the edge counts the ranks computed for their own tiles
  (``comm.allgather``; without ``comm`` every tile is counted in turn, in bounded memory). A contiguous range of ids
  is then a compact region of the square, so the ``"block"`` partition (equal ranges) has short boundaries.
  Departure from :func:`~distnav.network.builders.random_geometric`: the points are uniform *per tile* with equal
  counts (a stratified sample of the square), not ``n`` independent uniform points — a different random graph with
  the same mean degree, built for runs at 10⁶–10⁸ nodes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from distnav.errors import GraphError
from distnav.network.builders import _need
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart, ascending_unique, owned_rows

__all__ = [
    "grid_part",
    "radius_for_mean_degree",
    "ring_part",
    "tiled_random_geometric",
    "tiled_random_geometric_part",
]


class AllGather(Protocol):
    """What the tiled builder needs of a communicator (an ``mpi4py`` communicator has it)."""

    def allgather(self, sendobj: Any) -> list[Any]: ...


def _owned(nodes: np.ndarray, n: int) -> np.ndarray:
    own = ascending_unique(nodes)
    if own.size and (own[0] < 0 or own[-1] >= n):
        raise GraphError(f"owned nodes must lie in 0..{n - 1}")
    return own


def _part(
    n: int,
    own: np.ndarray,
    neighbours: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    edge_start: Callable[[np.ndarray], np.ndarray],
    self_loops: bool,
) -> GraphPart:
    """A part from a function listing the links ``(row, neighbour)`` of given rows: the owned rows, then the halo's."""
    r_own, s_own = neighbours(own)
    halo = np.unique(s_own[~owned_rows(own, s_own)[1]]) if own.size else np.zeros(0, np.int64)
    r_halo, s_halo = neighbours(halo)
    rows, nbr = np.concatenate([r_own, r_halo]), np.concatenate([s_own, s_halo])
    return GraphPart.from_neighbours(n, own, rows, nbr, edge_start, self_loops=self_loops)


def ring_part(n_nodes: int, nodes: np.ndarray, *, self_loops: bool = False) -> GraphPart:
    """The part owned by ``nodes`` of :func:`~distnav.network.builders.ring` ``(n_nodes)``: node ``u`` linked to
    ``u ± 1 (mod n)``, its in-edges starting at ``u (2 + self)``."""
    n = _need(n_nodes, 3, "a ring")
    own = _owned(nodes, n)
    loop = 1 if self_loops else 0

    def neighbours(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.repeat(rows, 2), np.stack([(rows - 1) % n, (rows + 1) % n], 1).ravel()

    return _part(n, own, neighbours, lambda ids: np.asarray(ids, np.int64) * (2 + loop), self_loops)


def grid_part(
    rows: int, cols: int, nodes: np.ndarray, *, neighbourhood: int = 4, self_loops: bool = False
) -> GraphPart:
    """The part owned by ``nodes`` of :func:`~distnav.network.builders.grid` ``(rows, cols)`` (node ``r·cols + c``).

    Degrees have a closed form: ``h(c) = [c > 0] + [c < cols−1]`` links along the row, ``v(r)`` likewise across
    rows, a node's degree ``h + v`` (4-neighbourhood) or ``h + v (1 + h)`` (8); the in-edges of node ``u`` start at
    the sum of the degrees below ``u``, summed in closed form over whole rows and the row's first ``c`` columns."""
    if neighbourhood not in (4, 8):
        raise GraphError(f"neighbourhood must be 4 or 8, got {neighbourhood}")
    n = _need(rows * cols, 2, f"a {rows}×{cols} grid")
    R, C = int(rows), int(cols)
    own = _owned(nodes, n)
    loop = 1 if self_loops else 0
    steps = [(0, -1), (0, 1), (-1, 0), (1, 0)]
    if neighbourhood == 8:
        steps += [(-1, -1), (-1, 1), (1, -1), (1, 1)]

    def neighbours(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, c = np.divmod(ids, C)
        out_r, out_s = [], []
        for dr, dc in steps:
            ok = (r + dr >= 0) & (r + dr < R) & (c + dc >= 0) & (c + dc < C)
            out_r.append(ids[ok])
            out_s.append(ids[ok] + dr * C + dc)
        return np.concatenate(out_r), np.concatenate(out_s)

    def prefix(k: np.ndarray | int, size: int) -> np.ndarray:  # Σ_{j<k} ([j > 0] + [j < size − 1])
        return np.asarray(np.maximum(np.asarray(k) - 1, 0) + np.minimum(k, size - 1))

    def edge_start(ids: np.ndarray) -> np.ndarray:
        u = np.asarray(ids, np.int64)
        r, c = np.divmod(u, C)
        v_r = (r > 0).astype(np.int64) + (r < R - 1)
        h_row, v_below, h_c = prefix(C, C), prefix(r, R), prefix(c, C)
        if neighbourhood == 4:
            below = r * h_row + C * v_below + h_c + c * v_r
        else:
            below = r * h_row + v_below * (C + h_row) + h_c + v_r * (c + h_c)
        return np.asarray(below + u * loop)

    return _part(n, own, neighbours, edge_start, self_loops)


def radius_for_mean_degree(n_nodes: int, mean_degree: float) -> float:
    """The radius giving an expected mean degree ``d = n π r²`` in the unit square (edge effects aside)."""
    return float(np.sqrt(mean_degree / (np.pi * n_nodes)))


_BATCH_POINTS = 1 << 16  # points per batch of tiles when every tile is counted here (no communicator)


@dataclass(frozen=True)
class _Tiling:
    """The tiles of :func:`tiled_random_geometric`: ``side × side`` (a power of two), along a Hilbert curve."""

    n: int
    radius: float
    seed: int
    side: int
    cell_of: np.ndarray = field(repr=False)  # tile k (curve order) → cell iy·side + ix
    tile_of_cell: np.ndarray = field(repr=False)

    @classmethod
    def make(cls, n: int, radius: float, seed: int, tile_nodes: int) -> _Tiling:
        if not radius > 0:
            raise GraphError(f"radius must be positive, got {radius}")
        if tile_nodes < 1:
            raise GraphError(f"tile_nodes must be positive, got {tile_nodes}")
        widest = min(np.sqrt(n / tile_nodes), 1.0 / (radius * (1 + 1e-9)))  # a tile no narrower than the radius
        bits = max(int(np.floor(np.log2(max(widest, 1.0)))), 0)
        side = 1 << bits
        if bits == 0:
            keys = np.zeros(1, np.int64)
        else:
            from distnav.network.partition import _hilbert_keys

            iy, ix = np.divmod(np.arange(side * side, dtype=np.int64), side)
            keys = _hilbert_keys(ix, iy, bits)
        cell_of = np.empty(side * side, np.int64)
        cell_of[keys] = np.arange(side * side)
        return cls(n, float(radius), int(seed), side, cell_of, keys)

    @property
    def n_tiles(self) -> int:
        return self.side * self.side

    def first(self, k: np.ndarray) -> np.ndarray:
        """First node id of tiles ``k`` (``k = n_tiles`` gives ``n``)."""
        base, extra = divmod(self.n, self.n_tiles)
        k = np.asarray(k, np.int64)
        return np.asarray(k * base + np.minimum(k, extra))

    def tile(self, ids: np.ndarray) -> np.ndarray:
        """Tile of each node id."""
        base, extra = divmod(self.n, self.n_tiles)
        ids = np.asarray(ids, np.int64)
        big = extra * (base + 1)
        return np.where(ids < big, ids // (base + 1), extra + (ids - big) // base)

    def around(self, tiles: np.ndarray) -> np.ndarray:
        """``tiles`` and the tiles touching them (8-neighbourhood), ascending."""
        iy, ix = np.divmod(self.cell_of[tiles], self.side)
        out = [tiles]
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                ok = (iy + dy >= 0) & (iy + dy < self.side) & (ix + dx >= 0) & (ix + dx < self.side)
                out.append(self.tile_of_cell[(iy[ok] + dy) * self.side + ix[ok] + dx])
        return np.unique(np.concatenate(out))

    def points(self, tiles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Node ids (ascending) and positions of the points of ``tiles`` (ascending): each tile's own draw."""
        lo, hi = self.first(tiles), self.first(tiles + 1)
        pos = np.empty((int((hi - lo).sum()), 2))
        at = 0
        for k, a, b in zip(tiles.tolist(), lo.tolist(), hi.tolist(), strict=True):
            iy, ix = divmod(int(self.cell_of[k]), self.side)
            u = np.random.default_rng([self.seed, k]).random((b - a, 2))
            pos[at : at + b - a, 0] = (ix + u[:, 0]) / self.side
            pos[at : at + b - a, 1] = (iy + u[:, 1]) / self.side
            at += b - a
        ids = np.repeat(lo - np.concatenate([[0], np.cumsum(hi - lo)[:-1]]), hi - lo) + np.arange(at)
        return ids, pos


def tiled_random_geometric(
    n_nodes: int, radius: float, *, seed: int, tile_nodes: int = 4096, self_loops: bool = False
) -> Graph:
    """The whole graph of :func:`tiled_random_geometric_part` (module docstring): points drawn tile by tile in the
    unit square, linked when at most ``radius`` apart (the test of ``cKDTree.query_pairs``)."""

    n = _need(n_nodes, 1, "a tiled random geometric graph")
    til = _Tiling.make(n, radius, seed, tile_nodes)
    _, pos = til.points(np.arange(til.n_tiles))
    pairs = [_tree(pos).query_pairs(til.radius, output_type="ndarray")]  # i < j, each pair once
    return Graph._from_link_pairs(n, pairs, positions=pos, self_loops=self_loops)


def _tree(pos: np.ndarray) -> Any:
    """A k-d tree split at the midpoints, not the medians: built and queried 1.5× faster on uniform points (the
    same pairs: the tree's shape changes which boxes are compared, not the distance test of a pair)."""
    from scipy.spatial import cKDTree

    return cKDTree(pos, balanced_tree=False, compact_nodes=False)


class _Region:
    """The points of some tiles (node ids ascending), their links ``(i, j)`` (region positions, ``i < j``, by
    ``cKDTree.query_pairs`` as in :func:`tiled_random_geometric`) and each point's degree among them (its true degree
    where the region holds the tiles around the point's tile)."""

    def __init__(self, til: _Tiling, tiles: np.ndarray) -> None:

        self.ids, pos = til.points(tiles)
        pairs = _tree(pos).query_pairs(til.radius, output_type="ndarray")
        del pos
        self.i, self.j = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
        del pairs
        self.degree = np.bincount(self.i, minlength=self.ids.size) + np.bincount(self.j, minlength=self.ids.size)

    def index(self, ids: np.ndarray) -> np.ndarray:
        return np.asarray(np.searchsorted(self.ids, ids))

    def lists(self, own: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(row, neighbour)`` id pairs of every owned node and of every neighbour of one (the halo); their
        neighbourhoods must lie in the region."""
        is_own = np.zeros(self.ids.size, bool)
        is_own[self.index(own)] = True
        is_row = is_own.copy()
        touch = is_own[self.i] | is_own[self.j]
        is_row[self.i[touch]] = True  # the halo: the other end of an owned node's link
        is_row[self.j[touch]] = True
        del touch, is_own
        from_i, from_j = is_row[self.i], is_row[self.j]
        rows = np.concatenate([self.i[from_i], self.j[from_j]])
        nbr = np.concatenate([self.j[from_i], self.i[from_j]])
        return self.ids[rows], self.ids[nbr]


def _tile_edges(
    til: _Tiling, tiles: np.ndarray, loop: int, region: _Region | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For ``tiles`` (ascending): the ids of their points, each point's in-edge count (degree + self) and each
    tile's sum. ``region`` must hold the tiles and the tiles around them (made here when not given)."""
    region = _Region(til, til.around(tiles)) if region is None else region
    lo, hi = til.first(tiles), til.first(tiles + 1)
    ids = np.concatenate([np.arange(a, b) for a, b in zip(lo.tolist(), hi.tolist(), strict=True)])
    row_len = region.degree[region.index(ids)] + loop
    bounds = np.zeros(tiles.size, np.int64)
    np.cumsum((hi - lo)[:-1], out=bounds[1:])
    return ids, row_len, np.add.reduceat(row_len, bounds)


def _tile_offsets(
    til: _Tiling, own_tiles: np.ndarray, own_counts: np.ndarray, comm: AllGather | None, loop: int
) -> np.ndarray:
    """First global edge id of every tile (``n_tiles + 1`` numbers): the ranks' counts of their own tiles gathered,
    or, without a communicator, every tile counted here a batch of tiles at a time."""
    counts = np.full(til.n_tiles, -1, np.int64)
    if comm is not None:
        for tiles, c in comm.allgather((own_tiles, own_counts)):
            counts[np.asarray(tiles, np.int64)] = c
    else:
        batch = max(1, _BATCH_POINTS * 4 // max(til.n // til.n_tiles, 1))
        for a in range(0, til.n_tiles, batch):
            tiles = np.arange(a, min(a + batch, til.n_tiles))
            counts[tiles] = _tile_edges(til, tiles, loop)[2]
    if (counts < 0).any():
        raise GraphError(
            f"tiled graph part: no rank counted tile {int(np.flatnonzero(counts < 0)[0])}: the ranks' nodes do not "
            "cover the graph"
        )
    offsets = np.zeros(til.n_tiles + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets


def tiled_random_geometric_part(
    n_nodes: int,
    radius: float,
    *,
    seed: int,
    nodes: np.ndarray,
    tile_nodes: int = 4096,
    self_loops: bool = False,
    comm: AllGather | None = None,
) -> GraphPart:
    """The part owned by ``nodes`` of :func:`tiled_random_geometric` from the same arguments (module docstring).

    Under MPI every rank calls it with its own ``nodes`` and the communicator (one ``allgather`` of the tile edge
    counts; the ranks' nodes must cover the graph). Memory: the points of the rank's tiles and two rings of tiles
    around them, the links of its nodes and halo, ``n / tile_nodes`` tile offsets.
    """
    n = _need(n_nodes, 1, "a tiled random geometric graph")
    til = _Tiling.make(n, radius, seed, tile_nodes)
    own = _owned(nodes, n)
    loop = 1 if self_loops else 0
    own_tiles = np.unique(til.tile(own))
    ring1 = til.around(own_tiles)
    region = _Region(til, til.around(ring1))  # the rank's tiles and two rings around them
    ids1, row_len1, per_tile1 = _tile_edges(til, ring1, loop, region)
    counted = own_tiles[np.isin(til.first(own_tiles), own)]  # tiles whose first node is ours: we report them
    offsets = _tile_offsets(til, counted, per_tile1[np.searchsorted(ring1, counted)], comm, loop)
    # first in-edge of every ring-1 node: its tile's offset plus the rows before it in the tile
    tile1 = til.tile(ids1)
    within = np.cumsum(row_len1) - row_len1
    within -= within[np.searchsorted(ids1, til.first(tile1))]
    start1 = offsets[tile1] + within

    def edge_start(ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, np.int64)
        out = np.full(ids.size, offsets[-1], np.int64)  # id n: the edge count
        inner = ids < n
        k = np.searchsorted(ids1, ids[inner])
        if not bool((ids1[np.minimum(k, ids1.size - 1)] == ids[inner]).all()):
            raise GraphError("tiled graph part: a node outside the rank's two rings of tiles was asked for")
        out[inner] = start1[k]
        return out

    rows, nbr = region.lists(own)
    del region
    return GraphPart.from_neighbours(n, own, rows, nbr, edge_start, self_loops=self_loops)
