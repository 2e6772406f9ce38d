"""Communication graphs: frozen, directed-edge representation of an undirected network.

A :class:`Graph` holds ``n_nodes`` nodes and every undirected link as *two* directed edges
``(src, dst)``. Edges are sorted by receiver (``dst``) then sender (``src``), so the incoming edges
of node ``i`` form the contiguous slice ``edges_in_ptr[i]:edges_in_ptr[i+1]`` (CSR by receiver),
which is what the exchange layer reduces over. Optional self-loops model a node's own value in a
weighted average (paper 003, eq. (31): the self-weight ``w_ii``).

A :class:`SwitchingGraph` is a sequence of sessions over the same node set (paper 003 §3.1, eq. (29));
each session may be disconnected but the union of the sessions must be connected.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from distnav._checks import affordable_nodes, whole_number
from distnav._optional import scipy_sparse as sp
from distnav.errors import GraphError

__all__ = ["Graph", "SwitchingGraph"]


def _as_int_array(values: Any, what: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.issubdtype(arr.dtype, np.integer):
        if np.issubdtype(arr.dtype, np.floating) and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise GraphError(f"{what} must be integer node ids, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


_EDGE_CHUNK = 1 << 20  # links per pass when the directed edges are placed (a few MB of temporaries)


def _sorted_edges(n_nodes: int, key: np.ndarray, self_loops: bool) -> tuple[np.ndarray, np.ndarray]:
    """Both directions of the links ``key = lo * n + hi`` (sorted, unique; ``lo < hi``), and a self-loop at every
    node if asked, as ``(src, dst)`` sorted by ``(dst, src)`` -- the order a lexsort gives, placed by counting.

    Into receiver ``d`` come, by ascending sender: the links' lower ends ``lo < d`` (links with ``hi = d``), then
    ``d`` itself (a self-loop), then the upper ends ``hi > d`` (links with ``lo = d``). ``key`` lists the links by
    ``(lo, hi)``: the second group is already in order, the first needs a stable sort by ``hi``. The ends are
    recomputed from ``key`` a chunk of links at a time: besides the result, one link-sized ``hi`` and its sort
    order are held (at 10⁶ nodes, mean degree 8: 64 MB instead of ≈ 200 MB of link-sized temporaries)."""
    n = n_nodes
    loop = 1 if self_loops else 0
    hi = key % n
    n_low = np.bincount(hi, minlength=n)  # per receiver: senders below it
    n_high = np.zeros(n, np.int64)  # senders above it
    for a in range(0, key.size, _EDGE_CHUNK):
        n_high += np.bincount(key[a : a + _EDGE_CHUNK] // n, minlength=n)
    counts = n_low + n_high + loop
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(counts, out=ptr[1:])
    # the k-th link (in each group's order) of receiver d lands at first_*[d] + k, k counted over all links
    first_low = ptr[:-1] - np.concatenate([[0], np.cumsum(n_low)[:-1]])
    first_high = ptr[:-1] + n_low + loop - np.concatenate([[0], np.cumsum(n_high)[:-1]])
    del n_high
    src = np.empty(int(ptr[-1]), np.int64)
    by_hi = np.argsort(hi, kind="stable")
    for a in range(0, key.size, _EDGE_CHUNK):
        rows = by_hi[a : a + _EDGE_CHUNK]
        src[np.arange(a, a + rows.size) + first_low[hi[rows]]] = key[rows] // n
    del by_hi, hi
    for a in range(0, key.size, _EDGE_CHUNK):
        k = key[a : a + _EDGE_CHUNK]
        lo = k // n
        src[np.arange(a, a + k.size) + first_high[lo]] = k - lo * n
    if self_loops:
        src[ptr[:-1] + n_low] = np.arange(n, dtype=np.int64)
    dst = np.repeat(np.arange(n, dtype=np.int64), counts)
    return src, dst


@dataclass(frozen=True, eq=False)
class Graph:
    """An undirected communication graph stored as directed edges sorted by receiver.

    Build it with :meth:`from_links` or one of the builders in :mod:`distnav.network.builders`;
    the constructor expects already-validated, sorted arrays.

    Attributes
    ----------
    n_nodes : number of nodes.
    src, dst : int64 arrays of length ``n_edges``, both directions of every link, sorted by ``(dst, src)``.
    names : one name per node (default ``"0"``, ``"1"``, ...; the default tuple is made on first use, not held by
        a graph nobody asks for names: 60 MiB at 10⁶ nodes).
    positions : optional ``(n_nodes, dim)`` coordinates in metres, used for plots and geometric builders.
    self_loops : whether every node also has an edge ``(i, i)``.
    """

    n_nodes: int
    src: np.ndarray
    dst: np.ndarray
    positions: np.ndarray | None = None
    self_loops: bool = False
    _names: tuple[str, ...] | None = None  # None: the default names, made on demand by :attr:`names`
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_links(
        cls,
        n_nodes: int,
        links: Iterable[tuple[int, int]] | np.ndarray,
        *,
        names: Sequence[str] | None = None,
        positions: np.ndarray | None = None,
        self_loops: bool = False,
        allow_duplicates: bool = False,
    ) -> Graph:
        """Build a graph from undirected links ``(i, j)`` given once each (either order).

        Raises :class:`~distnav.errors.GraphError` for out-of-range ids, a link from a node to itself,
        or a link listed twice (unless ``allow_duplicates=True``, which keeps one copy).
        """
        n_nodes = whole_number(n_nodes, "n_nodes (a graph's node count)", error=GraphError)
        if n_nodes < 1:
            raise GraphError(f"a graph needs at least one node, got n_nodes={n_nodes}")
        affordable_nodes(n_nodes, "a graph", error=GraphError)
        arr = np.asarray(list(links) if not isinstance(links, np.ndarray) else links)
        if arr.size == 0:
            arr = np.zeros((0, 2), dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise GraphError(f"links must have shape (n_links, 2), got {arr.shape}")
        arr = _as_int_array(arr, "links").reshape(-1, 2)
        bad = (arr < 0) | (arr >= n_nodes)
        if bad.any():
            row = int(np.argwhere(bad.any(axis=1))[0, 0])
            raise GraphError(f"link #{row} = ({arr[row, 0]}, {arr[row, 1]}) refers to a node outside 0..{n_nodes - 1}")
        loops = arr[:, 0] == arr[:, 1]
        if loops.any():
            row = int(np.argmax(loops))
            raise GraphError(f"link #{row} joins node {arr[row, 0]} to itself; use self_loops=True for self-weights")
        key = np.minimum(arr[:, 0], arr[:, 1])
        key *= n_nodes
        key += np.maximum(arr[:, 0], arr[:, 1])  # lo * n + hi: one int64 per link
        key.sort()
        repeated = key[1:] == key[:-1]
        if repeated.any():
            if not allow_duplicates:
                uniq, counts = np.unique(key, return_counts=True)
                dup = uniq[counts > 1][0]
                raise GraphError(
                    f"link ({dup // n_nodes}, {dup % n_nodes}) is listed {counts[counts > 1][0]} times "
                    f"(pass allow_duplicates=True to merge repeated links)"
                )
            key = key[np.concatenate([[True], ~repeated])]
        del repeated
        src, dst = _sorted_edges(n_nodes, key, self_loops)
        return cls._checked(n_nodes, src, dst, names, positions, self_loops)

    @classmethod
    def _from_link_pairs(
        cls, n_nodes: int, pairs: list[np.ndarray], *, positions: np.ndarray | None, self_loops: bool
    ) -> Graph:
        """A graph from the ``(n_links, 2)`` array in ``pairs`` (a one-item list, emptied here so the array is freed
        once its keys are made: 64 MB less at 10⁶ nodes) of links ``(i, j)`` with ``i < j``, each once and within
        ``0..n_nodes-1`` — what ``cKDTree.query_pairs`` returns; the builders' fast path, not validated."""
        arr = pairs.pop()
        key = arr[:, 0].astype(np.int64)
        key *= n_nodes
        key += arr[:, 1]
        del arr
        key.sort()
        src, dst = _sorted_edges(n_nodes, key, self_loops)
        del key
        return cls._checked(n_nodes, src, dst, None, positions, self_loops)

    @classmethod
    def _checked(
        cls,
        n_nodes: int,
        src: np.ndarray,
        dst: np.ndarray,
        names: Sequence[str] | None,
        positions: np.ndarray | None,
        self_loops: bool,
    ) -> Graph:
        names_t: tuple[str, ...] | None = None
        if names is not None:
            names_t = tuple(str(s) for s in names)
            if len(names_t) != n_nodes:
                raise GraphError(f"got {len(names_t)} names for {n_nodes} nodes")
            if len(set(names_t)) != n_nodes:
                seen: set[str] = set()
                dup = next(s for s in names_t if s in seen or seen.add(s))  # type: ignore[func-returns-value]
                raise GraphError(f"node name {dup!r} is used twice")
        pos = None
        if positions is not None:
            pos = np.array(positions, dtype=float)
            if pos.ndim != 2 or pos.shape[0] != n_nodes:
                raise GraphError(f"positions must have shape (n_nodes={n_nodes}, dim), got {pos.shape}")
            if not np.all(np.isfinite(pos)):
                raise GraphError(f"positions of nodes {np.flatnonzero(~np.isfinite(pos).all(1))} are not finite")
            pos.setflags(write=False)
        src = np.ascontiguousarray(src, dtype=np.int64)
        dst = np.ascontiguousarray(dst, dtype=np.int64)
        src.setflags(write=False)
        dst.setflags(write=False)
        return cls(n_nodes=n_nodes, src=src, dst=dst, positions=pos, self_loops=self_loops, _names=names_t)

    @property
    def names(self) -> tuple[str, ...]:
        """One name per node (see the class docstring)."""
        if self._names is not None:
            return self._names
        made: tuple[str, ...] | None = self._cache.get("names")
        if made is None:
            made = self._cache["names"] = tuple(str(i) for i in range(self.n_nodes))
        return made

    def with_self_loops(self, flag: bool = True) -> Graph:
        """The same links with (or without) a self-loop at every node."""
        if flag == self.self_loops:
            return self
        return Graph.from_links(self.n_nodes, self.links, names=self._names, positions=self.positions, self_loops=flag)

    # ------------------------------------------------------------------ basic facts
    @property
    def n_edges(self) -> int:
        """Number of directed edges (2 per link, plus self-loops)."""
        return int(self.src.size)

    @cached_property
    def links(self) -> np.ndarray:
        """Undirected links as an ``(n_links, 2)`` array with ``i < j``, sorted."""
        # the edges j→i with j > i, in the stored (dst, src) order, are the links (i, j) already sorted
        keep = self.src > self.dst
        return np.stack([self.dst[keep], self.src[keep]], axis=1)

    @property
    def n_links(self) -> int:
        return int(self.links.shape[0])

    @cached_property
    def degrees(self) -> np.ndarray:
        """Number of neighbours of each node, self excluded (``dg_i`` of paper 003 Table 1)."""
        not_self = self.src != self.dst
        return np.bincount(self.dst[not_self], minlength=self.n_nodes).astype(np.int64)

    @cached_property
    def in_ptr(self) -> np.ndarray:
        """CSR pointer over receivers: incoming edges of node i are ``in_ptr[i]:in_ptr[i+1]``."""
        counts = np.bincount(self.dst, minlength=self.n_nodes)
        ptr = np.zeros(self.n_nodes + 1, dtype=np.int64)
        np.cumsum(counts, out=ptr[1:])
        return ptr

    @cached_property
    def reverse_edge(self) -> np.ndarray:
        """For each directed edge ``e = (i→j)`` the index of ``(j→i)`` (self-loops map to themselves)."""
        # Edges are stored by (dst, src); listed by (src, dst) instead (a stable sort by src), the k-th is the
        # pair (s, d) whose reverse (d→s) is the k-th stored edge: the link set is symmetric. The stable sort by
        # src is the transpose of the CSR (rows dst, columns src): scipy's CSR → CSC conversion, a linear-time
        # counting sort (a comparison sort of 1.5 M edges took 0.12 s of the first ADMM set-up at 10⁵ nodes).
        idx = np.int32 if self.n_edges < 2**31 - 1 else np.int64
        by_dst = sp.csr_matrix(
            (np.arange(self.n_edges, dtype=idx), self.src.astype(idx), self.in_ptr.astype(idx)),
            shape=(self.n_nodes, self.n_nodes),
        )
        order = by_dst.tocsc().data
        del by_dst
        out = np.empty(self.n_edges, dtype=np.int64)
        out[order] = np.arange(self.n_edges, dtype=np.int64)
        return out

    def edge_index(self, src: np.ndarray | int, dst: np.ndarray | int) -> np.ndarray:
        """Indices of the directed edges ``src→dst``; raises if one is not an edge."""
        s = np.atleast_1d(np.asarray(src, dtype=np.int64))
        d = np.atleast_1d(np.asarray(dst, dtype=np.int64))
        key = self.dst * self.n_nodes + self.src  # sorted, because edges are sorted by (dst, src)
        want = d * self.n_nodes + s
        pos = np.searchsorted(key, want)
        pos_c = np.minimum(pos, key.size - 1)
        missing = (pos >= key.size) | (key[pos_c] != want)
        if missing.any():
            k = int(np.argmax(missing))
            raise GraphError(f"({s[k]}, {d[k]}) is not an edge of the graph")
        return np.asarray(pos_c)

    def neighbors(self, i: int, *, include_self: bool = False) -> np.ndarray:
        """Sorted neighbours of node ``i`` (``N_i``); with ``include_self`` also ``i`` itself."""
        self._check_node(i)
        nb = self.src[self.in_ptr[i] : self.in_ptr[i + 1]]
        nb = nb[nb != i]
        if include_self:
            nb = np.sort(np.append(nb, i))
        return nb

    def _check_node(self, i: int) -> None:
        if not 0 <= int(i) < self.n_nodes:
            raise GraphError(f"node {i} is outside 0..{self.n_nodes - 1}")

    def node_id(self, name: str) -> int:
        """The integer id of the node called ``name``."""
        try:
            return self._name_index[str(name)]
        except KeyError:
            raise GraphError(f"no node named {name!r}") from None

    @cached_property
    def _name_index(self) -> dict[str, int]:
        return {s: i for i, s in enumerate(self.names)}

    # ------------------------------------------------------------------ matrices
    def adjacency(self, *, include_self: bool = False) -> sp.csr_matrix:
        """Symmetric 0/1 adjacency in CSR (rows = receivers)."""
        n = self.n_nodes
        if not self.self_loops and not include_self:  # edges are already CSR by receiver, senders sorted
            idx = np.int32 if max(n, self.n_edges) < 2**31 - 1 else np.int64
            return sp.csr_matrix((np.ones(self.n_edges), self.src.astype(idx), self.in_ptr.astype(idx)), shape=(n, n))
        keep = np.ones(self.n_edges, bool) if include_self else self.src != self.dst
        a = sp.csr_matrix(
            (np.ones(int(keep.sum())), (self.dst[keep], self.src[keep])), shape=(self.n_nodes, self.n_nodes)
        )
        if include_self and not self.self_loops:
            a = a + sp.identity(self.n_nodes, format="csr")
        return a.tocsr()

    def laplacian(self) -> sp.csr_matrix:
        """Graph Laplacian ``D − A`` (self-loops ignored)."""
        a = self.adjacency()
        return (sp.diags(self.degrees.astype(float)) - a).tocsr()

    # ------------------------------------------------------------------ connectivity
    @cached_property
    def component_labels(self) -> np.ndarray:
        """Connected-component label of every node."""
        from scipy.sparse.csgraph import connected_components  # lazy (import time)

        _, labels = connected_components(self.adjacency(), directed=False)
        return np.asarray(labels)

    @property
    def is_connected(self) -> bool:
        return bool(self.n_nodes == 1 or np.all(self.component_labels == self.component_labels[0]))

    def require_connected(self, what: str = "graph") -> None:
        """Raise a :class:`GraphError` naming the nodes unreachable from node 0."""
        if self.is_connected:
            return
        unreachable = np.flatnonzero(self.component_labels != self.component_labels[0])
        shown = ", ".join(self.names[i] for i in unreachable[:20])
        more = f" and {unreachable.size - 20} more" if unreachable.size > 20 else ""
        raise GraphError(f"{what} is not connected: nodes {shown}{more} are unreachable from node {self.names[0]}")

    # ------------------------------------------------------------------ interop
    def to_networkx(self) -> Any:
        """A ``networkx.Graph`` with node attributes ``name`` and ``pos`` (needs the ``graph`` extra)."""
        from distnav._optional import require

        nx = require("networkx", "graph")
        g = nx.Graph()
        for i in range(self.n_nodes):
            attrs: dict[str, Any] = {"name": self.names[i]}
            if self.positions is not None:
                attrs["pos"] = tuple(float(v) for v in self.positions[i])
            g.add_node(i, **attrs)
        g.add_edges_from((int(a), int(b)) for a, b in self.links)
        return g

    @classmethod
    def from_networkx(cls, g: Any, *, self_loops: bool = False) -> Graph:
        """Build from a ``networkx.Graph``; nodes are relabelled 0..n-1 in iteration order, names kept.

        Node attribute ``pos`` (if present on every node) becomes :attr:`positions`.
        """
        nodes = list(g.nodes)
        index = {v: k for k, v in enumerate(nodes)}
        links = [(index[a], index[b]) for a, b in g.edges if a != b]
        pos = None
        if nodes and all("pos" in g.nodes[v] for v in nodes):
            pos = np.array([g.nodes[v]["pos"] for v in nodes], dtype=float)
        return cls.from_links(len(nodes), links, names=[str(v) for v in nodes], positions=pos, self_loops=self_loops)

    def __repr__(self) -> str:
        return f"Graph(n_nodes={self.n_nodes}, n_links={self.n_links}, self_loops={self.self_loops})"


@dataclass(frozen=True, eq=False)
class SwitchingGraph:
    """A switching interaction topology: sessions ``G_1..G_ko`` over the same nodes (paper 003 eq. (29)).

    Round ``k`` (0-based) of an iterative protocol uses session ``k mod ko``. Sessions may be
    disconnected; their union must be connected, else a :class:`GraphError` names the stranded nodes.
    """

    sessions: tuple[Graph, ...]

    def __post_init__(self) -> None:
        if len(self.sessions) == 0:
            raise GraphError("a switching graph needs at least one session")
        n = self.sessions[0].n_nodes
        for k, g in enumerate(self.sessions):
            if g.n_nodes != n:
                raise GraphError(f"session {k} has {g.n_nodes} nodes, session 0 has {n}")
        self.union.require_connected("union of the sessions")

    @property
    def n_nodes(self) -> int:
        return self.sessions[0].n_nodes

    @property
    def n_sessions(self) -> int:
        return len(self.sessions)

    @cached_property
    def union(self) -> Graph:
        """The union graph; its edges carry every message of every session."""
        g0 = self.sessions[0]
        links = np.concatenate([g.links for g in self.sessions], axis=0)
        return Graph.from_links(g0.n_nodes, links, names=g0._names, positions=g0.positions, allow_duplicates=True)

    def session(self, round_index: int) -> Graph:
        return self.sessions[round_index % self.n_sessions]

    @cached_property
    def session_edge_masks(self) -> tuple[np.ndarray, ...]:
        """For each session, a boolean mask over the union's directed edges that the session uses."""
        u = self.union
        masks = []
        for g in self.sessions:
            m = np.zeros(u.n_edges, bool)
            if g.n_links:
                real = g.src != g.dst
                m[u.edge_index(g.src[real], g.dst[real])] = True
            masks.append(m)
        return tuple(masks)

    @classmethod
    def from_graphs(cls, sessions: Sequence[Graph]) -> SwitchingGraph:
        return cls(tuple(sessions))

    def __repr__(self) -> str:
        return f"SwitchingGraph(n_nodes={self.n_nodes}, links per session={[g.n_links for g in self.sessions]})"
