"""Graph builders: ring, path, complete, star, grid, ladder, random geometric, k-nearest neighbours.

All builders return a :class:`~distnav.network.graph.Graph`. Random builders take a
``numpy.random.Generator`` (never global state). Geometric builders store node positions in metres.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav._checks import affordable_nodes, whole_number
from distnav._settings import resolve_options
from distnav.errors import GraphError
from distnav.network.graph import Graph

if TYPE_CHECKING:
    from distnav.network.graph_part import GraphPart

__all__ = [
    "ring",
    "path",
    "complete",
    "star",
    "grid",
    "ladder",
    "random_geometric",
    "connected_random_geometric",
    "PointOptions",
    "k_nearest",
    "from_edges",
]


def _need(n: int, minimum: int, what: str) -> int:
    n = whole_number(n, f"the number of nodes of {what}", error=GraphError)
    if n < minimum:
        raise GraphError(f"{what} needs at least {minimum} nodes, got {n}")
    affordable_nodes(n, what, error=GraphError)
    return n


def ring(n_nodes: int, *, self_loops: bool = False) -> Graph:
    """Cycle 0-1-...-(n-1)-0.

    Examples
    --------
    >>> from distnav.network import builders
    >>> g = builders.ring(5)
    >>> g.n_nodes, len(g.links), g.degrees.tolist()
    (5, 5, [2, 2, 2, 2, 2])
    """
    n = _need(n_nodes, 3, "a ring")
    i = np.arange(n)
    return Graph.from_links(n, np.stack([i, (i + 1) % n], 1), self_loops=self_loops)


def path(n_nodes: int, *, self_loops: bool = False) -> Graph:
    """Chain 0-1-...-(n-1)."""
    n = _need(n_nodes, 1, "a path")
    i = np.arange(n - 1)
    return Graph.from_links(n, np.stack([i, i + 1], 1), self_loops=self_loops)


def complete(n_nodes: int, *, self_loops: bool = False) -> Graph:
    """Every pair of nodes linked."""
    n = _need(n_nodes, 1, "a complete graph")
    affordable_nodes(n * (n - 1) // 2, "a complete graph", error=GraphError, items="links")
    a, b = np.triu_indices(n, 1)
    return Graph.from_links(n, np.stack([a, b], 1), self_loops=self_loops)


def star(n_nodes: int, *, self_loops: bool = False) -> Graph:
    """Node 0 linked to every other node."""
    n = _need(n_nodes, 2, "a star")
    leaves = np.arange(1, n)
    return Graph.from_links(n, np.stack([np.zeros_like(leaves), leaves], 1), self_loops=self_loops)


def grid(rows: int, cols: int, *, spacing_m: float = 1.0, neighbourhood: int = 4, self_loops: bool = False) -> Graph:
    """A ``rows × cols`` grid (node ``r*cols + c`` at ``(c*spacing_m, r*spacing_m)``).

    ``neighbourhood=4`` links horizontal/vertical neighbours; ``8`` also the diagonals
    (paper 002 class G: 10 m grid, 8-neighbourhood).
    """
    if neighbourhood not in (4, 8):
        raise GraphError(f"neighbourhood must be 4 or 8, got {neighbourhood}")
    rows = whole_number(rows, "rows of a grid", error=GraphError)
    cols = whole_number(cols, "cols of a grid", error=GraphError)
    if rows < 1 or cols < 1 or rows * cols < 2:
        raise GraphError(f"a grid needs at least 2 nodes, got {rows}×{cols}")
    affordable_nodes(rows * cols, f"a {rows}×{cols} grid", error=GraphError)
    idx = np.arange(rows * cols).reshape(rows, cols)
    parts = [
        np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
        np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1),
    ]
    if neighbourhood == 8:
        parts.append(np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1))
        parts.append(np.stack([idx[:-1, 1:].ravel(), idx[1:, :-1].ravel()], 1))
    rr, cc = np.divmod(np.arange(rows * cols), cols)
    pos = np.stack([cc * spacing_m, rr * spacing_m], 1).astype(float)
    return Graph.from_links(rows * cols, np.concatenate(parts), positions=pos, self_loops=self_loops)


def ladder(n_nodes: int, *, spacing_m: float = 1.0, diagonals: bool = True, self_loops: bool = False) -> Graph:
    """A two-row ladder of ``n_nodes`` (even) nodes: rails, rungs and (optionally) one diagonal per cell.

    Node ``2k`` is at ``(k*spacing_m, 0)``, node ``2k+1`` at ``(k*spacing_m, spacing_m)``. With
    ``diagonals=True`` every node has degree at most 5 (paper 002 class L).
    """
    n = whole_number(n_nodes, "the number of nodes of a ladder", error=GraphError)
    if n < 4 or n % 2:
        raise GraphError(f"a ladder needs an even number of nodes ≥ 4, got {n}")
    affordable_nodes(n, "a ladder", error=GraphError)
    k = n // 2
    bottom, top = np.arange(k) * 2, np.arange(k) * 2 + 1
    parts = [
        np.stack([bottom[:-1], bottom[1:]], 1),
        np.stack([top[:-1], top[1:]], 1),
        np.stack([bottom, top], 1),
    ]
    if diagonals:
        # alternate the diagonal direction so that no node exceeds degree 5
        cells = np.arange(k - 1)
        a = np.where(cells % 2 == 0, bottom[:-1], top[:-1])
        b = np.where(cells % 2 == 0, top[1:], bottom[1:])
        parts.append(np.stack([a, b], 1))
    pos = np.stack([np.repeat(np.arange(k), 2) * spacing_m, np.tile([0.0, 1.0], k) * spacing_m], 1)
    return Graph.from_links(n, np.concatenate(parts), positions=pos, self_loops=self_loops)


@dataclass(frozen=True, kw_only=True)
class PointOptions:
    """Options of the random geometric builders (house style: :mod:`distnav._settings`; default in brackets).

    Fields
    ------
    dim : [2] coordinates per point (the connected builder sets its radius for 2 or 3).
    size : [1.0] points uniform in ``[0, size]^dim`` (metres when the radius is).
    self_loops : [False] as for :class:`~distnav.network.graph.Graph`.
    """

    dim: int = 2
    size: float = 1.0
    self_loops: bool = False

    def __post_init__(self) -> None:
        whole_number(self.dim, "dim", minimum=1, error=GraphError)
        if not (isinstance(self.size, (int, float, np.integer, np.floating)) and 0 < self.size < np.inf):
            raise GraphError(f"size must be a finite number > 0, got {self.size!r}")


def random_geometric(
    n_nodes: int, radius: float, *, rng: np.random.Generator, options: PointOptions | None = None, **changes: Any
) -> Graph:
    """Nodes uniform in ``[0, size]^dim``, linked when closer than ``radius`` (same units as ``size``); options
    :class:`PointOptions` (``options=`` and/or keyword changes to it).

    Uses a k-d tree, so 10⁶ nodes build in seconds. The result may be disconnected; see
    :func:`connected_random_geometric`.
    """
    n = _need(n_nodes, 1, "a random geometric graph")
    if not radius > 0:
        raise GraphError(f"radius must be positive, got {radius}")
    opt = resolve_options(PointOptions, options, changes)
    pos = rng.uniform(0.0, opt.size, size=(n, opt.dim))
    from scipy.spatial import cKDTree  # lazy: scipy.spatial is a third of the import time of the MPI path

    pairs = [cKDTree(pos).query_pairs(float(radius), output_type="ndarray")]  # i < j, each pair once
    return Graph._from_link_pairs(n, pairs, positions=pos, self_loops=opt.self_loops)


def connected_random_geometric(
    n_nodes: int,
    *,
    mean_degree: float,
    rng: np.random.Generator,
    max_tries: int = 50,
    options: PointOptions | None = None,
    **changes: Any,
) -> Graph:
    """A *connected* random geometric graph whose expected mean degree is ``mean_degree`` (options
    :class:`PointOptions`, ``options=`` and/or keyword changes to it).

    The radius is set from the expected degree of a Poisson point process, ``d = n π r² / size²`` (2-D) or
    ``d = n (4/3) π r³ / size³`` (3-D); redrawn up to ``max_tries`` times until connected.
    """
    n = _need(n_nodes, 2, "a connected random geometric graph")
    opt = resolve_options(PointOptions, options, changes)
    dim, size = opt.dim, opt.size
    if dim == 2:
        radius = size * np.sqrt(mean_degree / (np.pi * n))
    elif dim == 3:
        radius = size * np.cbrt(mean_degree / (4.0 / 3.0 * np.pi * n))
    else:
        raise GraphError(f"dim must be 2 or 3, got {dim}")
    for _ in range(max_tries):
        g = random_geometric(n, radius, rng=rng, options=opt)
        if g.is_connected:
            return g
    raise GraphError(
        f"no connected graph in {max_tries} draws with n={n}, mean degree {mean_degree}: raise mean_degree"
    )


def k_nearest(positions: np.ndarray, k: int, *, self_loops: bool = False) -> Graph:
    """Link every node to its ``k`` nearest neighbours (symmetrised: a link if either picks the other)."""
    pos = np.asarray(positions, dtype=float)
    if pos.ndim != 2:
        raise GraphError(f"positions must be (n_nodes, dim), got shape {pos.shape}")
    n = pos.shape[0]
    if not 1 <= k < n:
        raise GraphError(f"k must be in 1..{n - 1} for {n} nodes, got {k}")
    from scipy.spatial import cKDTree

    _, idx = cKDTree(pos).query(pos, k=k + 1)
    src = np.repeat(np.arange(n), k)
    dst = idx[:, 1:].ravel()
    return Graph.from_links(n, np.stack([src, dst], 1), positions=pos, allow_duplicates=True, self_loops=self_loops)


def from_edges(
    edges: Iterable[tuple[int, int]] | Iterable[tuple[str, str]] | np.ndarray,
    *,
    n_nodes: int | None = None,
    names: Sequence[str] | None = None,
    positions: np.ndarray | None = None,
    self_loops: bool = False,
    allow_duplicates: bool = False,
) -> Graph:
    """Build a graph from an edge list of integer ids or of node names.

    With string names and no ``names`` given, nodes are named in order of first appearance.
    """
    if isinstance(edges, np.ndarray):
        if edges.size and (edges.ndim != 2 or edges.shape[1] != 2):
            raise GraphError(f"edges must be pairs (shape (n_edges, 2)), got shape {edges.shape}")
        edge_list = edges.tolist()
    else:
        edge_list = list(edges)
        bad = next(
            (k for k, e in enumerate(edge_list) if isinstance(e, str) or not hasattr(e, "__len__") or len(e) != 2), None
        )
        if bad is not None:
            raise GraphError(f"edge #{bad} is {edge_list[bad]!r}, not a pair of node ids or names")
    if edge_list and all(isinstance(v, str) for e in edge_list for v in e):
        if names is None:
            order: dict[str, int] = {}
            for a, b in edge_list:
                order.setdefault(a, len(order))
                order.setdefault(b, len(order))
            names = list(order)
        index = {s: i for i, s in enumerate(names)}
        missing = [v for e in edge_list for v in e if v not in index]
        if missing:
            raise GraphError(f"edge list names node {missing[0]!r}, which is not among the node names")
        ids = [(index[a], index[b]) for a, b in edge_list]
        return Graph.from_links(
            len(names), ids, names=names, positions=positions, self_loops=self_loops, allow_duplicates=allow_duplicates
        )
    arr = np.asarray(edge_list) if edge_list else np.zeros((0, 2), int)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise GraphError(f"edges must be pairs (shape (n_edges, 2)), got shape {arr.shape}")
    if n_nodes is None:
        n_nodes = len(names) if names is not None else (int(arr.max()) + 1 if arr.size else 1)
    return Graph.from_links(
        n_nodes, arr, names=names, positions=positions, self_loops=self_loops, allow_duplicates=allow_duplicates
    )


def random_geometric_part(
    n_nodes: int,
    radius: float,
    *,
    rng: np.random.Generator,
    nodes: np.ndarray,
    options: PointOptions | None = None,
    **changes: Any,
) -> GraphPart:
    """The part owned by ``nodes`` of the graph :func:`random_geometric` builds from the same arguments (the same
    positions, the same links, the same global edge ids), without the whole edge list: what one MPI rank builds.

    Every node's position is drawn (the same random stream) and one k-d tree holds them all; the links are found
    only around the owned nodes and their halo, the degrees of all nodes are counted without listing their links.
    Memory: the positions, the tree and a degree per node, plus the owned and halo nodes' links.
    """
    from scipy.spatial import cKDTree

    from distnav.network.graph_part import GraphPart, ascending_unique, edge_starts_from_degrees

    n = _need(n_nodes, 1, "a random geometric graph")
    if not radius > 0:
        raise GraphError(f"radius must be positive, got {radius}")
    opt = resolve_options(PointOptions, options, changes)
    pos = rng.uniform(0.0, opt.size, size=(n, opt.dim))
    tree = cKDTree(pos)
    r, step = float(radius), 1 << 16
    own = ascending_unique(nodes)
    if own.size and (own[0] < 0 or own[-1] >= n):
        raise GraphError(f"owned nodes must lie in 0..{n - 1}")

    def ball_pairs(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Links of ``rows`` as (row, neighbour) pairs, by the same distance test as ``query_pairs`` (a chunk of
        rows at a time: the k-d tree's structured output, 24 bytes a pair, stays small)."""
        out_i, out_j = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for a in range(0, rows.size, step):
            chunk = rows[a : a + step]
            found = cKDTree(pos[chunk]).sparse_distance_matrix(tree, r, output_type="ndarray")
            i, j = chunk[found["i"]], found["j"].astype(np.int64)
            del found
            keep = i != j
            out_i.append(i[keep])
            out_j.append(j[keep])
        return np.concatenate(out_i), np.concatenate(out_j)

    # degree of every node, a chunk of nodes at a time (counts only: no edge list of the whole graph is held), the
    # chunks taken in the tree's own order: spatially compact, so each query visits few cells (1.7× faster)
    degree = np.zeros(n, np.int64)
    in_tree_order = np.asarray(tree.indices, dtype=np.int64)
    for a in range(0, n, step):
        chunk = in_tree_order[a : a + step]
        found = cKDTree(pos[chunk]).sparse_distance_matrix(tree, r, output_type="ndarray")
        row = found["i"].astype(np.int64)
        degree[chunk] = np.bincount(row[chunk[row] != found["j"]], minlength=chunk.size)
    del in_tree_order

    r_own, s_own = ball_pairs(own)
    is_own = np.zeros(n, bool)
    is_own[own] = True
    halo = np.unique(s_own[~is_own[s_own]])
    del is_own
    r_halo, s_halo = ball_pairs(halo)
    rows, nbr = np.concatenate([r_own, r_halo]), np.concatenate([s_own, s_halo])
    del r_own, s_own, r_halo, s_halo
    start = edge_starts_from_degrees(degree, self_loops=opt.self_loops)
    return GraphPart.from_neighbours(n, own, rows, nbr, start, self_loops=opt.self_loops)
