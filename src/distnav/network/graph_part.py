"""One block's share of a communication graph: what an MPI rank needs of a graph it never builds whole.

A :class:`GraphPart` holds the nodes a rank owns, their incoming edges (senders and *global* edge ids) and the ids
of the reverse edges (the owned nodes' outgoing edges), plus the degrees of the owned nodes and of the halo (the
foreign senders). Global edge ids are those of the whole :class:`~distnav.network.graph.Graph` (edges sorted by
``(dst, src)``), so the seeded fault schedule drops the same messages as on the whole graph and an exchange built
on parts gives results bitwise equal to one built on the whole graph.

Memory is proportional to the owned nodes' links and their halo's. Build a part with :meth:`GraphPart.from_graph`
(tests, small graphs), with a builder that holds no array over the whole network
(:mod:`distnav.network.part_builders`: ring, grid, tiled random geometric), or with one that never makes the whole
edge list but draws every position (:func:`distnav.network.builders.random_geometric_part`); see docs/scale.md for
bytes per node and per link.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav.errors import GraphError
from distnav.network.graph import Graph

__all__ = ["EdgeStart", "GraphPart", "ascending_unique", "edge_starts_from_degrees", "incoming_positions", "owned_rows"]

EdgeStart = Callable[[np.ndarray], np.ndarray]
"""Node ids → global id of each node's first incoming edge (id ``n_nodes`` → the edge count)."""


def incoming_positions(ptr: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Positions of the entries of CSR rows ``rows`` (pointer ``ptr``), row after row in the order of ``rows``."""
    return _ranges(ptr[rows], ptr[rows + 1])


@dataclass(frozen=True, eq=False)
class GraphPart:
    """The owned nodes of one block and their links (see the module docstring).

    Attributes
    ----------
    n_nodes, n_edges : node and directed-edge counts of the *whole* graph.
    nodes : owned global node ids, ascending.
    in_ptr : CSR pointer over ``nodes``: the incoming edges of ``nodes[k]`` are ``in_ptr[k]:in_ptr[k+1]``.
    src : global sender of each incoming edge (ascending within a receiver, as in the whole graph).
    edge_ids : global id of each incoming edge.
    out_edge_ids : global id of its reverse edge (the owned receiver's message to that sender).
    degree : neighbours of each owned node (self excluded).
    (``src``, the edge ids and the degrees are int32 where every id fits, else int64.)
    halo, halo_degree : the foreign senders (ascending) and their degrees.
    self_loops : whether every node has an edge to itself (as :attr:`Graph.self_loops`).
    """

    n_nodes: int
    n_edges: int
    nodes: np.ndarray
    in_ptr: np.ndarray
    src: np.ndarray
    edge_ids: np.ndarray
    out_edge_ids: np.ndarray
    degree: np.ndarray
    halo: np.ndarray
    halo_degree: np.ndarray
    self_loops: bool = False

    def __post_init__(self) -> None:
        n_in = int(self.src.size)
        if self.in_ptr.shape != (self.nodes.size + 1,) or int(self.in_ptr[-1]) != n_in:
            raise GraphError("graph part: in_ptr does not match its nodes and edges")
        if self.edge_ids.shape != (n_in,) or self.out_edge_ids.shape != (n_in,):
            raise GraphError("graph part: edge_ids and out_edge_ids need one entry per incoming edge")
        if self.nodes.size > 1 and not bool((np.diff(self.nodes) > 0).all()):
            raise GraphError("graph part: nodes must be ascending and distinct")

    @property
    def n_local(self) -> int:
        return int(self.nodes.size)

    @property
    def n_local_edges(self) -> int:
        """Incoming edges of the owned nodes."""
        return int(self.src.size)

    @property
    def dst(self) -> np.ndarray:
        """Global receiver of each incoming edge."""
        return np.repeat(self.nodes, np.diff(self.in_ptr))

    @property
    def nbytes(self) -> int:
        """Bytes held by the part's arrays."""
        return sum(
            int(getattr(self, f).nbytes)
            for f in ("nodes", "in_ptr", "src", "edge_ids", "out_edge_ids", "degree", "halo", "halo_degree")
        )

    @property
    def is_range(self) -> bool:
        """Whether the owned nodes are a range of ids (then their in-edges' ids are a range too)."""
        return self.n_local > 0 and int(self.nodes[-1]) - int(self.nodes[0]) + 1 == self.n_local

    def owned_positions(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position in :attr:`nodes` of each id (clipped into range where not owned) and whether it is owned: by a
        subtraction when the owned nodes are a range of ids, else by binary search (:func:`owned_rows`)."""
        return owned_rows(self.nodes, np.asarray(ids, np.int64))

    def sender_degree(self) -> np.ndarray:
        """Degree of the sender of each incoming edge (owned or halo)."""
        src = self.src
        out = np.empty(src.size, np.int64)
        k, own = self.owned_positions(src)
        out[own] = self.degree[k[own]]
        if (~own).any():
            out[~own] = self.halo_degree[np.searchsorted(self.halo, src[~own])]
        return out

    @classmethod
    def from_graph(cls, graph: Graph, nodes: np.ndarray) -> GraphPart:
        """The part of ``graph`` owned by ``nodes`` (any order; stored ascending)."""
        own = ascending_unique(nodes)
        if own.size and (own[0] < 0 or own[-1] >= graph.n_nodes):
            raise GraphError(f"graph part: node ids must lie in 0..{graph.n_nodes - 1}")
        ptr = graph.in_ptr
        e = incoming_positions(ptr, own)
        counts = ptr[own + 1] - ptr[own]
        in_ptr = np.zeros(own.size + 1, np.int64)
        np.cumsum(counts, out=in_ptr[1:])
        idx = _index_dtype(graph.n_edges, graph.n_nodes)
        src = graph.src[e].astype(idx)
        is_own = np.zeros(graph.n_nodes, bool)
        is_own[own] = True
        halo = np.unique(src[~is_own[src]]).astype(np.int64)
        deg = graph.degrees
        return cls(
            n_nodes=graph.n_nodes,
            n_edges=graph.n_edges,
            nodes=own,
            in_ptr=in_ptr,
            src=src,
            edge_ids=e.astype(idx),
            out_edge_ids=graph.reverse_edge[e].astype(idx),
            degree=deg[own].astype(idx),
            halo=halo,
            halo_degree=deg[halo].astype(idx),
            self_loops=graph.self_loops,
        )

    @classmethod
    def from_neighbours(
        cls,
        n_nodes: int,
        nodes: np.ndarray,
        rows: np.ndarray,
        nbr: np.ndarray,
        edge_start: EdgeStart,
        *,
        self_loops: bool = False,
    ) -> GraphPart:
        """Assemble a part from neighbour lists, without the whole edge list or any array over the whole graph.

        ``(rows, nbr)``: every link ``rows[k]–nbr[k]`` (both directions listed) for every row node that is owned
        *or* a neighbour of an owned node (the halo's own neighbour lists give the ids of the owned nodes' outgoing
        edges and the halo's degrees). ``edge_start(ids)``: the global id of the first incoming edge of each node
        of ``ids`` (owned nodes, the node after each owned node, and halo nodes; id ``n_nodes`` gives the edge
        count) — the edges into ``u`` start at ``Σ_{v<u} (deg v + self)`` and are ordered by sender, the self-loop
        at its place. Builders with a closed form give it directly (:mod:`~distnav.network.part_builders`);
        :func:`edge_starts_from_degrees` makes one from every node's degree.
        """
        n = int(n_nodes)
        own = ascending_unique(nodes)
        key = _sorted_link_keys(n, own, rows, nbr, self_loops)
        is_range = own.size > 0 and int(own[-1]) - int(own[0]) + 1 == own.size
        if is_range:  # one call for every start: the node after an owned node is the next owned one
            starts = np.asarray(edge_start(np.append(own, own[-1] + 1)), np.int64)
            own_start, next_start = starts[:-1], starts[1:]
            lo, counts, src_all = _range_rows(key, n, own)
        else:
            own_start = np.asarray(edge_start(own), np.int64)
            next_start = np.asarray(edge_start(own + 1), np.int64)
            lo = np.searchsorted(key, own * n)
            counts = np.searchsorted(key, own * n + n) - lo
        _check_row_lengths(own, counts, next_start - own_start)
        del next_start
        n_edges = int(np.asarray(edge_start(np.array([n], np.int64)))[0])
        in_ptr = np.zeros(own.size + 1, np.int64)
        np.cumsum(counts, out=in_ptr[1:])
        idx = _index_dtype(n_edges, n)
        # a row's k-th entry is the edge start[row] + k (the edges into a node are ordered by sender)
        if is_range:  # the rows are one slice of the keys, and their edges one range of ids (rows checked above)
            edge_ids = np.arange(int(own_start[0]), int(own_start[0]) + int(in_ptr[-1]), dtype=idx)
            src = src_all.astype(idx)
            del src_all
            foreign = src < own[0]
            foreign |= src > own[-1]
            halo = np.unique(src[foreign]).astype(np.int64)
            del foreign
        else:
            pos = _ranges(lo, lo + counts)
            edge_ids = (pos + np.repeat(own_start - lo, counts)).astype(idx)
            src = (key[pos] % n).astype(idx)
            del pos
            k = np.minimum(np.searchsorted(own, src), max(own.size - 1, 0))
            halo = np.unique(src[own[k] != src]).astype(np.int64) if own.size else np.zeros(0, np.int64)
            del k
        out_edge_ids = _reverse_edge_ids(key, n, own, src, counts, (lo, own_start), edge_start)
        loop = 1 if self_loops else 0
        halo_len = np.searchsorted(key, halo * n + n) - np.searchsorted(key, halo * n)
        return cls(
            n_nodes=n,
            n_edges=n_edges,
            nodes=own,
            in_ptr=in_ptr,
            src=src,
            edge_ids=edge_ids,
            out_edge_ids=out_edge_ids.astype(idx),
            degree=(counts - loop).astype(idx),
            halo=halo,
            halo_degree=(halo_len - loop).astype(idx),
            self_loops=bool(self_loops),
        )

    def __repr__(self) -> str:
        return (
            f"GraphPart(n_nodes={self.n_nodes}, owned={self.n_local}, in_edges={self.n_local_edges}, "
            f"halo={self.halo.size})"
        )


def edge_starts_from_degrees(degree_all: np.ndarray, *, self_loops: bool = False) -> EdgeStart:
    """``edge_start`` for :meth:`GraphPart.from_neighbours` from the degree of every node (self excluded): an
    array over the whole graph, for builders that hold one anyway (:func:`~distnav.network.builders.
    random_geometric_part`) and for tests."""
    deg = np.asarray(degree_all, dtype=np.int64)
    start = np.zeros(deg.size + 1, np.int64)
    np.cumsum(deg + (1 if self_loops else 0), out=start[1:])
    return lambda ids: start[np.asarray(ids, np.int64)]


def _sorted_link_keys(n: int, own: np.ndarray, rows: np.ndarray, nbr: np.ndarray, self_loops: bool) -> np.ndarray:
    """``row * n + neighbour`` of every listed link (with each row node's self-loop when the graph has them),
    sorted: rows ascending, senders ascending within a row — the whole graph's edge order."""
    r, s = np.asarray(rows, np.int64), np.asarray(nbr, np.int64)
    if self_loops:  # every row node's self-loop, at its place in the sender order
        uniq = np.union1d(r, own)
        r, s = np.concatenate([r, uniq]), np.concatenate([s, uniq])
    key = r * n
    key += s
    del r, s
    key.sort()
    if key.size > 1 and bool((key[1:] == key[:-1]).any()):
        raise GraphError("graph part: a link is listed twice in the neighbour lists")
    return key


def _range_rows(key: np.ndarray, n: int, own: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For owned nodes that are a range of ids: each row's first position in the sorted ``key``, its length and
    every entry's neighbour. The rows are one slice of the keys: one division over it instead of two binary
    searches per owned node (and one per entry to tell the halo)."""
    first, last = int(own[0]), int(own[-1])
    lo_b, hi_b = (int(v) for v in np.searchsorted(key, [first * n, (last + 1) * n]))
    block = key[lo_b:hi_b]
    row = block // n
    row -= first
    counts = np.bincount(row, minlength=own.size)
    row += first
    row *= n
    np.subtract(block, row, out=row)  # the neighbour of every entry
    lo = np.full(own.size, lo_b, np.int64)
    if own.size > 1:
        lo[1:] += np.cumsum(counts[:-1])
    return lo, counts, row


def _check_row_lengths(own: np.ndarray, counts: np.ndarray, expected: np.ndarray) -> None:
    """Every owned node's list is as long as its edge range says (its degree, plus its self-loop)."""
    if not bool((counts == expected).all()):
        k = int(np.flatnonzero(counts != expected)[0])
        raise GraphError(
            f"graph part: node {int(own[k])} has {int(counts[k])} entries in the neighbour lists, "
            f"its edge range holds {int(expected[k])}"
        )


def _reverse_edge_ids(
    key: np.ndarray,
    n: int,
    own: np.ndarray,
    src: np.ndarray,
    counts: np.ndarray,
    own_rows: tuple[np.ndarray, np.ndarray],
    edge_start: EdgeStart,
) -> np.ndarray:
    """Global id of the reverse of every incoming edge: the edge ``dst → src`` is entry ``dst`` of row ``src``.

    The reverse edges are exactly the listed entries whose neighbour is owned; in key order they are sorted by
    ``(row, owned neighbour)``, the incoming edges by ``(owned receiver, sender)``: one is the transpose of the other,
    made by scipy's linear-time CSR → CSC conversion (a stable counting sort by the owned node, no comparison sort),
    then checked entry by entry against the incoming edges. ``own_rows``: each owned row's first position in ``key``
    and its first edge id (known already: only the halo rows' are looked up)."""
    import scipy.sparse as sp

    nbr = key % n
    if own.size and int(own[-1]) - int(own[0]) + 1 == own.size:
        nbr_owned = nbr >= own[0]
        nbr_owned &= nbr <= own[-1]
        rev = np.flatnonzero(nbr_owned)
        del nbr_owned
        col = nbr[rev] - own[0]
    else:
        at = np.minimum(np.searchsorted(own, nbr), max(own.size - 1, 0))
        rev = np.flatnonzero(own[at] == nbr) if own.size else np.zeros(0, np.int64)
        col = at[rev]
        del at
    del nbr
    if rev.size != src.size:
        raise GraphError("graph part: a halo node's neighbour list is missing")
    row_of = key[rev] // n  # the rows (senders), ascending: each row's start looked up once, not once per entry
    first = np.flatnonzero(np.diff(row_of, prepend=-1))
    row = row_of[first]
    del row_of
    counts_row = np.diff(np.append(first, rev.size))
    # each row's first key position minus its first edge id: an entry's position minus it is its edge id
    k, mine = owned_rows(own, row)
    base = np.empty(row.size, np.int64)
    base[mine] = own_rows[0][k[mine]] - own_rows[1][k[mine]]
    halo = row[~mine]
    base[~mine] = np.searchsorted(key, halo * n) - np.asarray(edge_start(halo), np.int64)
    del k, mine, halo
    rev -= np.repeat(base, counts_row)  # now the reverse edges' global ids
    ptr = np.zeros(row.size + 1, np.int64)
    np.cumsum(counts_row, out=ptr[1:])
    idx = np.int32 if max(row.size, own.size, rev.size) < 2**31 - 1 else np.int64
    ids = rev.astype(np.int32) if rev.size == 0 or int(rev.max()) < 2**31 - 1 else rev  # the part keeps int32 ids
    del rev
    by_row = sp.csr_matrix((ids, col.astype(idx), ptr.astype(idx)), shape=(row.size, own.size))
    del ids, col, ptr
    by_owned = by_row.tocsc()
    del by_row
    if not (np.array_equal(np.diff(by_owned.indptr), counts) and np.array_equal(row[by_owned.indices], src)):
        raise GraphError("graph part: a halo node's neighbour list is missing")
    return np.asarray(by_owned.data)


def owned_rows(own: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position in ``own`` (ascending owned ids) of each id, clipped into range where not owned, and whether it is
    owned: by a subtraction when ``own`` is a range of ids (a builder's part: no binary search over the edges), else
    by binary search."""
    if own.size == 0:
        return np.zeros(ids.size, np.int64), np.zeros(ids.size, bool)
    first, last = int(own[0]), int(own[-1])
    if last - first + 1 == own.size:
        mine = ids >= first
        mine &= ids <= last
        k = np.asarray(ids, np.int64) - first
        np.clip(k, 0, own.size - 1, out=k)
        return k, mine
    k = np.minimum(np.searchsorted(own, ids), own.size - 1)
    return k, own[k] == ids


def ascending_unique(values: np.ndarray) -> np.ndarray:
    """``np.unique`` as int64, without the sort when the ids are already ascending and distinct (a partition's)."""
    a = np.asarray(values, dtype=np.int64)
    if a.ndim == 1 and (a.size < 2 or bool((a[1:] > a[:-1]).all())):
        return a
    return np.unique(a)


def _index_dtype(n_edges: int, n_nodes: int) -> type[np.signedinteger[Any]]:
    """int32 for per-edge ids and senders where every id fits (half the part's memory), else int64."""
    return np.int32 if max(n_edges, n_nodes) < 2**31 - 1 else np.int64


def _ranges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(lo[k], hi[k])``."""
    counts = hi - lo
    total = int(counts.sum())
    offsets = np.zeros(lo.size, np.int64)
    if lo.size > 1:
        np.cumsum(counts[:-1], out=offsets[1:])
    return np.asarray(np.repeat(lo - offsets, counts) + np.arange(total, dtype=np.int64))
