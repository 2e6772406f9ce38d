"""Constraint nodes of distributed least squares by ADMM (paper 000 §4.1, eq. (17)–(18), Fig. 5).

A set ``C`` of *constraint nodes* replaces the single consensus state of paper 000 eq. (16): every ``s ∈ C`` holds
a consensus state ``z_s`` with the constraints ``x_i − z_s = 0`` for ``i ∈ N_s`` (eq. (17)), where ``N_s`` is the
*closed* neighbourhood (a node is its own neighbour). ``C`` must satisfy conditions (18):

1. ``⋃_{s∈C} N_s = {1, …, n}`` — every node has a constraint node in its neighbourhood;
2. constraint nodes whose neighbourhoods do not overlap must be bridged by other constraint nodes.

**How condition 2 is read.** Literally, (18)-2 asks for *one* ``s₃`` bridging each disjoint pair ``s₁, s₂``. That
literal reading rejects ``C = {1, …, n}`` on a path of 7 or more nodes (no neighbourhood of 3 consecutive nodes
touches both ends), yet the paper calls ``C = {1, …, n}`` the trivial choice that satisfies (18) on any connected
graph. The conclusion the paper draws from (18) — ``x_i = x_j`` for all ``i, j`` — holds exactly when the *overlap
graph* (constraint nodes linked when their neighbourhoods share a node) is connected, so that is the default test
(``literal=False``); ``literal=True`` applies the one-bridge statement verbatim.

Choices of ``C`` (:func:`choose_constraint_nodes`): ``"all"``, a user set, or ``"min_cover"`` — every link has a
constraint node (paper 000 §4.2: uses every link; Fig. 5 left) with as few constraint nodes as possible, i.e. a
minimum vertex cover:

* ``method="exact"``: an integer program ``min Σ c_i`` s.t. ``c_i + c_j ≥ 1`` per link, ``c ∈ {0,1}`` solved by
  branch and bound (HiGHS via :func:`scipy.optimize.milp`), optimal when it finishes within ``time_limit_s``;
* ``method="approx"``: the classic 2-approximation — both ends of a greedy maximal matching ``M`` — followed by
  removing any chosen node whose neighbours are all chosen (both passes vectorized). Bound:
  ``|M| ≤ LP ≤ OPT ≤ |C| ≤ 2|M| ≤ 2·OPT``; the lower bound ``max(|M|, ⌈LP⌉)`` is reported with the result, so
  ``|C| / lower_bound`` is the stated bound. The LP bound comes from a linear-time matching of the bipartite double
  cover (:func:`matching_lower_bound`) when that reaches ``⌈n/2⌉`` (then it is the LP bound), else from a maximum
  bipartite matching (:func:`lp_lower_bound`) up to ``LP_BOUND_MAX_LINKS`` links, else the cheaper bound is
  reported; ``method`` says which;
* ``method="auto"`` (default): exact for graphs up to ``exact_max_nodes`` (150) nodes, where it is fast (falls
  back to the approximation if the solver does not prove optimality within ``time_limit_s``), the approximation
  beyond: set-up stays under a second at every size (a 1,000-node geometric network took 10 s to *not* finish).

A vertex cover of a connected graph always satisfies (18). :func:`unused_links` lists the links with no
constraint node at either end: they carry no ADMM message (Fig. 5 right: ``C = {1,3,4,9}`` leaves (5,6), (6,7)).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, Literal, TypeAlias

import numpy as np

from distnav._optional import scipy_sparse as sp
from distnav.errors import GraphError
from distnav.network.graph import Graph

__all__ = [
    "lp_lower_bound",
    "matching_lower_bound",
    "LP_BOUND_MAX_LINKS",
    "ConstraintNodes",
    "ConditionsReport",
    "check_conditions",
    "validate_constraint_nodes",
    "unused_links",
    "minimum_vertex_cover",
    "choose_constraint_nodes",
    "ConstraintNodeSpec",
    "NodeIds",
]

Choice = Literal["all", "min_cover"]
#: Node ids (or a boolean mask over the nodes), as the checks here take them.
NodeIds: TypeAlias = Iterable[int] | np.ndarray
#: What the solvers take as ``constraint_nodes``: a choice, node ids, or a :class:`ConstraintNodes` already chosen.
ConstraintNodeSpec: TypeAlias = "ConstraintNodes | Choice | NodeIds"


def _names(graph: Graph, ids: Iterable[int], limit: int = 20) -> str:
    ids = list(ids)
    shown = ", ".join(graph.names[int(i)] for i in ids[:limit])
    return shown + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def _as_node_set(graph: Graph, nodes: NodeIds) -> np.ndarray:
    arr = np.asarray(list(nodes) if not isinstance(nodes, np.ndarray) else nodes)
    if arr.dtype == bool:
        if arr.shape != (graph.n_nodes,):
            raise GraphError(f"a boolean constraint-node mask needs {graph.n_nodes} entries, got {arr.shape}")
        arr = np.flatnonzero(arr)
    if arr.size == 0:
        raise GraphError("the set of constraint nodes is empty; conditions (18) need at least one")
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
        raise GraphError(f"constraint nodes must be a 1-D list of integer node ids, got {arr.dtype} {arr.shape}")
    bad = (arr < 0) | (arr >= graph.n_nodes)
    if bad.any():
        raise GraphError(f"constraint node {int(arr[bad][0])} is outside 0..{graph.n_nodes - 1}")
    uniq, counts = np.unique(arr, return_counts=True)
    if (counts > 1).any():
        raise GraphError(f"constraint node {graph.names[int(uniq[counts > 1][0])]} is listed twice")
    return uniq.astype(np.int64)


def _mask(graph: Graph, nodes: np.ndarray) -> np.ndarray:
    m = np.zeros(graph.n_nodes, bool)
    m[nodes] = True
    return m


@dataclass(frozen=True)
class ConditionsReport:
    """Outcome of checking conditions (18): ``uncovered`` nodes violate (18)-1; ``groups`` are the connected
    groups of constraint nodes in the overlap graph (more than one violates (18)-2); ``unbridged_pairs`` are the
    disjoint pairs with no single bridge (only filled with ``literal=True``)."""

    uncovered: tuple[int, ...]
    groups: tuple[tuple[int, ...], ...]
    unbridged_pairs: tuple[tuple[int, int], ...]
    literal: bool

    @property
    def ok(self) -> bool:
        return not self.uncovered and len(self.groups) <= 1 and not self.unbridged_pairs


def check_conditions(graph: Graph, nodes: NodeIds, *, literal: bool = False) -> ConditionsReport:
    """Check conditions (18) of paper 000 for the constraint nodes ``nodes`` (see the module docstring for how
    condition 2 is read). Returns a report; :func:`validate_constraint_nodes` raises instead."""
    C = _as_node_set(graph, nodes)
    inC = _mask(graph, C)
    real = graph.src != graph.dst
    src, dst = graph.src[real], graph.dst[real]
    covered = inC.copy()
    covered[dst[inC[src]]] = True
    uncovered = tuple(int(i) for i in np.flatnonzero(~covered))
    # overlap graph on C: s1–s2 when N_s1 ∩ N_s2 ≠ ∅. Its components are those of the bipartite graph joining
    # each constraint node s to every node of its closed neighbourhood N_s (paths alternate C, V, C), which is
    # linear in the links instead of the product A[C] A[:, C] (quadratic in the degree).
    k = C.size
    col_of = np.full(graph.n_nodes, -1, np.int64)
    col_of[C] = np.arange(k)
    sel = inC[src]
    b_rows = np.concatenate([np.arange(k), col_of[src[sel]]])
    b_cols = k + np.concatenate([C, dst[sel]])
    B = sp.csr_matrix((np.ones(b_rows.size), (b_rows, b_cols)), shape=(k + graph.n_nodes, k + graph.n_nodes))
    from scipy.sparse.csgraph import connected_components  # lazy (import time)

    _, labels_all = connected_components(B, directed=False)
    labels = labels_all[:k]
    groups = tuple(tuple(C[labels == g].tolist()) for g in np.unique(labels))
    overlap = None
    unbridged: list[tuple[int, int]] = []
    if literal and C.size > 1:
        A = graph.adjacency(include_self=True)
        overlap = (A[C] @ A[:, C]).tocsr()
        O = overlap.toarray() > 0
        bridged = (O.astype(np.int64) @ O.astype(np.int64)) > 0
        bad = np.argwhere(~O & ~bridged)
        unbridged = [(int(C[a]), int(C[b])) for a, b in bad if a < b]
    return ConditionsReport(
        uncovered=uncovered,
        groups=groups if len(groups) > 1 else (tuple(C.tolist()),),
        unbridged_pairs=tuple(unbridged),
        literal=literal,
    )


def validate_constraint_nodes(graph: Graph, nodes: NodeIds, *, literal: bool = False) -> np.ndarray:
    """Return the sorted constraint-node ids, or raise :class:`~distnav.errors.GraphError` naming the nodes that
    violate conditions (18) of paper 000."""
    C = _as_node_set(graph, nodes)
    rep = check_conditions(graph, C, literal=literal)
    problems = []
    if rep.uncovered:
        problems.append(f"(18)-1: nodes {_names(graph, rep.uncovered)} have no constraint node in their neighbourhood")
    if len(rep.groups) > 1:
        shown = "; ".join("{" + _names(graph, g, 8) + "}" for g in rep.groups[:4])
        problems.append(
            f"(18)-2: the constraint nodes split into {len(rep.groups)} groups whose neighbourhoods "
            f"never overlap: {shown}"
        )
    if rep.unbridged_pairs:
        pairs = ", ".join(f"({graph.names[a]}, {graph.names[b]})" for a, b in rep.unbridged_pairs[:10])
        problems.append(f"(18)-2 (literal): no single constraint node bridges the pairs {pairs}")
    if problems:
        raise GraphError("constraint nodes violate conditions (18) of paper 000: " + "; ".join(problems))
    return C


def unused_links(graph: Graph, nodes: NodeIds) -> np.ndarray:
    """Links ``(i, j)`` (``i < j``) with no constraint node at either end: ADMM sends nothing over them."""
    inC = _mask(graph, _as_node_set(graph, nodes))
    links = graph.links
    if links.size == 0:
        return links
    return np.asarray(links[~(inC[links[:, 0]] | inC[links[:, 1]])])


# ----------------------------------------------------------------------------------------------- vertex cover
_SEQUENTIAL_TAIL = 2000  # when fewer candidates than this remain, finish a greedy pass in a plain loop
_SEQUENTIAL_TAIL_LINKS = 1000  # per chunk of the matching: its loop is cheap per link (no array slicing)
_MATCH_CHUNK = 1 << 16  # links (in greedy order) matched per chunk


def _small(key: np.ndarray) -> np.ndarray:
    """Non-negative integer sort keys in 16 bits where they fit: numpy's stable sort is then a radix sort (the
    same permutation, ~5× faster on the degree keys here)."""
    return key.astype(np.uint16) if key.size and 0 <= int(key.min()) and int(key.max()) < 2**16 else key


def _min_at(n: int, index: np.ndarray, values: np.ndarray) -> np.ndarray:
    out = np.full(n, np.iinfo(np.int64).max, np.int64)
    np.minimum.at(out, index, values)
    return out


def _maximal_matching(graph: Graph) -> np.ndarray:
    """Greedy maximal matching (links in order, lowest-degree endpoints first); ``(|M|, 2)``.

    The sequential greedy pass is computed in vectorized rounds: a link whose rank is the smallest among the
    remaining links at both its ends is one greedy would take, so each round takes all of them at once (the
    same matching as the one-link-at-a-time loop, which finishes the last few links). The links are taken in
    chunks of ``_MATCH_CHUNK`` ranks: greedy's choice among the first ranks does not depend on the later ones,
    so each chunk is matched given the nodes the earlier chunks used, and links at used nodes are dropped before
    any round looks at them (a round then scans a chunk's live links, not every remaining link of the graph)."""
    links = graph.links
    if links.size == 0:
        return links
    n = graph.n_nodes
    deg = graph.degrees
    lo_deg, hi_deg = deg[links[:, 0]], deg[links[:, 1]]
    # rank by (degree sum, larger degree, link order): one integer key, one stable sort
    key = (lo_deg + hi_deg) * (int(deg.max()) + 1) + np.maximum(lo_deg, hi_deg)
    order = np.argsort(_small(key), kind="stable")
    ranked = links[order]  # one row gather (both ends at once)
    a_all, b_all = ranked[:, 0], ranked[:, 1]
    used = np.zeros(n, bool)
    taken_a: list[np.ndarray] = []
    taken_b: list[np.ndarray] = []
    big = np.iinfo(np.int64).max
    best = np.full(n, big, np.int64)
    for start in range(0, a_all.size, _MATCH_CHUNK):
        a, b = a_all[start : start + _MATCH_CHUNK], b_all[start : start + _MATCH_CHUNK]
        live = ~(used[a] | used[b])
        a, b = a[live], b[live]
        rank = np.flatnonzero(live)
        while a.size > _SEQUENTIAL_TAIL_LINKS:
            np.minimum.at(best, a, rank)
            np.minimum.at(best, b, rank)
            pick = (best[a] == rank) & (best[b] == rank)
            best[a] = big  # reset only the entries this round wrote
            best[b] = big
            pa, pb = a[pick], b[pick]
            taken_a.append(pa)
            taken_b.append(pb)
            used[pa] = True
            used[pb] = True
            keep = ~(used[a] | used[b])
            a, b, rank = a[keep], b[keep], rank[keep]
        if a.size:  # the chunk's last links in a plain loop (ranks ascending, as greedy takes them)
            tail_a, tail_b = [], []
            free = {u: True for u in np.concatenate([a, b]).tolist()}  # all free: dead links were dropped
            for u, v in zip(a.tolist(), b.tolist(), strict=True):
                if free[u] and free[v]:
                    free[u] = free[v] = False
                    tail_a.append(u)
                    tail_b.append(v)
            ta, tb = np.asarray(tail_a, np.int64), np.asarray(tail_b, np.int64)
            used[ta] = True
            used[tb] = True
            taken_a.append(ta)
            taken_b.append(tb)
    if not taken_a:  # pragma: no cover - a graph with links always matches one
        return links[:0]
    return np.stack([np.concatenate(taken_a), np.concatenate(taken_b)], axis=1).astype(links.dtype, copy=False)


def _prune(graph: Graph, inC: np.ndarray) -> np.ndarray:
    """Drop chosen nodes whose neighbours are all chosen (the result stays a vertex cover), lowest degree first.

    Only nodes whose neighbours are all chosen at the start can ever be dropped, and dropping one makes its
    neighbours undroppable: the sequential pass is a greedy independent set among those candidates in
    ``(degree, id)`` order, computed in vectorized rounds like :func:`_maximal_matching`."""
    inC = inC.copy()
    n = graph.n_nodes
    real = graph.src != graph.dst
    src, dst = graph.src[real], graph.dst[real]
    has_free_nbr = np.bincount(dst, weights=~inC[src], minlength=n) > 0
    cand = inC & ~has_free_nbr & (graph.degrees > 0)
    deg = graph.degrees
    rank = np.empty(n, np.int64)
    rank[np.argsort(_small(deg), kind="stable")] = np.arange(n)  # by (degree, id)
    alive = cand.copy()
    # the rounds only look at links between candidates (alive nodes are candidates), shrunk to the alive ones
    ce = cand[src] & cand[dst]
    cs, cd = src[ce], dst[ce]
    while int(alive.sum()) > _SEQUENTIAL_TAIL:
        e = alive[cs] & alive[cd]
        cs, cd = cs[e], cd[e]
        best_nbr = _min_at(n, cd, rank[cs])
        pick = alive & (rank < best_nbr)
        inC[pick] = False
        blocked = np.zeros(n, bool)
        blocked[cd[pick[cs]]] = True
        alive &= ~pick & ~blocked
    ptr = graph.in_ptr
    gsrc = graph.src
    for v in sorted(np.flatnonzero(alive).tolist(), key=lambda k: (deg[k], k)):
        nb = gsrc[ptr[v] : ptr[v + 1]]
        nb = nb[nb != v]
        if nb.size and inC[nb].all():
            inC[v] = False
    return inC


def lp_lower_bound(graph: Graph) -> int:
    """``⌈ν/2⌉`` with ν a maximum matching of the bipartite double cover: the optimum of the vertex-cover LP
    relaxation (half-integral), hence a lower bound on the minimum cover, at least the greedy matching's size."""
    from scipy.sparse.csgraph import maximum_bipartite_matching

    if graph.n_links == 0:
        return 0
    match = maximum_bipartite_matching(graph.adjacency().tocsr(), perm_type="column")
    return int(-(-int((match >= 0).sum()) // 2))


#: Above this many links the exact LP bound (a Hopcroft–Karp matching, 0.13–0.18 s at 7.5 × 10⁵ links) is not
#: computed when the cheaper matching bound of :func:`matching_lower_bound` falls short of it.
LP_BOUND_MAX_LINKS = 100_000


def matching_lower_bound(graph: Graph, matching: np.ndarray) -> tuple[int, bool]:
    """A lower bound on the minimum vertex cover from a matching of the bipartite double cover built in linear time.

    The double cover has a left and a right copy of every node and the edges ``u_L–v_R`` of every link. A matching
    of it of size μ is a fractional matching of the graph of value μ/2 (each link weighted by half the number of its
    matched copies; every node's copies are matched at most once each), so ``⌈μ/2⌉ ≤ LP ≤`` the minimum cover
    (weak LP duality). The matching starts from both copies of every link of the greedy maximal matching ``M``
    (μ = 2|M|) and adds one augmenting path ``u_L → v_R ⇒ w_L → u_R`` for each free node ``u`` on a triangle
    ``u, v, w`` with ``(v, w) ∈ M``, the free nodes and the ``v`` used all distinct (then the paths are
    vertex-disjoint). Returns ``(⌈μ/2⌉, is_lp)``: ``is_lp`` when ``⌈μ/2⌉`` reaches ``⌈n/2⌉``, the most the LP bound
    :func:`lp_lower_bound` can be (ν ≤ n), so the bound *is* the LP bound (on the random geometric networks of the
    benchmarks it always is: 500 at 10³ nodes, 50,000 at 10⁵)."""
    n = graph.n_nodes
    mate = np.full(n, -1, np.int64)
    if matching.size:
        mate[matching[:, 0]] = matching[:, 1]
        mate[matching[:, 1]] = matching[:, 0]
    free = np.flatnonzero((mate < 0) & (graph.degrees > 0))
    t = 0
    if free.size:
        ptr = graph.in_ptr
        lengths = ptr[free + 1] - ptr[free]
        u = np.repeat(free, lengths)  # every in-edge v→u of a free node, grouped by u, v ascending
        first = np.repeat(ptr[free] - np.cumsum(lengths) + lengths, lengths)
        v = graph.src[first + np.arange(u.size)]
        keep = v != u
        u, v = u[keep], v[keep]
        w = mate[v]  # every neighbour of a free node is matched (M is maximal)
        keys = u * n + v  # sorted: grouped by u, v ascending
        pos = np.minimum(np.searchsorted(keys, u * n + w), keys.size - 1)
        tri = (w >= 0) & (keys[pos] == u * n + w)  # w is a neighbour of u too
        u, v = u[tri], v[tri]
        used_v = np.zeros(n, bool)
        done = np.zeros(n, bool)
        for _ in range(3):  # a few rounds: each free node takes its first triangle whose v is still unused
            ok = ~done[u] & ~used_v[v]
            cu, cv = u[ok], v[ok]
            if cu.size == 0:
                break
            _, first_u = np.unique(cu, return_index=True)
            cu, cv = cu[first_u], cv[first_u]
            _, first_v = np.unique(cv, return_index=True)
            cu, cv = cu[first_v], cv[first_v]
            done[cu] = True
            used_v[cv] = True
            t += int(cu.size)
    bound = -(-(2 * int(matching.shape[0]) + t) // 2)
    return bound, bound >= -(-n // 2)  # the LP bound ⌈ν/2⌉ is at most ⌈n/2⌉ (ν ≤ n)


def minimum_vertex_cover(
    graph: Graph,
    *,
    method: Literal["auto", "exact", "approx"] = "auto",
    exact_max_nodes: int = 150,
    time_limit_s: float = 2.0,
) -> tuple[np.ndarray, bool, int, str]:
    """A (minimum) vertex cover: every link gets at least one chosen node.

    Returns ``(nodes, optimal, lower_bound, method_used)``. ``"auto"`` runs the integer program only on graphs
    of at most ``exact_max_nodes`` nodes (HiGHS proves a 100-node geometric network optimal in ≈ 0.4 s, a
    400-node one takes ≈ 3 s and a 1,000-node one does not finish in 20 s), the vectorized 2-approximation
    beyond. ``time_limit_s`` caps the integer program: if it does not prove optimality in time, the better of
    its incumbent and the approximation is returned with ``optimal=False`` (``"exact"`` raises instead).
    ``lower_bound`` is ``|C|`` when optimal, else the largest of the matching size ``|M|``, the LP bound
    (:func:`lp_lower_bound`) and the solver's dual bound, so ``|C| / lower_bound`` bounds how far from the
    minimum the returned cover can be (≤ 2 always).
    """
    if method not in ("auto", "exact", "approx"):
        raise GraphError(f"unknown vertex-cover method {method!r}; choose 'auto', 'exact' or 'approx'")
    n = graph.n_nodes
    links = graph.links
    if links.size == 0:
        return np.zeros(0, np.int64), True, 0, "no links"
    incumbent: np.ndarray | None = None
    dual = 0
    if method == "exact" or (method == "auto" and n <= exact_max_nodes):
        from scipy.optimize import Bounds, LinearConstraint, milp
        from scipy.sparse import csr_matrix

        L = links.shape[0]
        rows = np.repeat(np.arange(L), 2)
        M = csr_matrix((np.ones(2 * L), (rows, links.ravel())), shape=(L, n))
        res = milp(
            c=np.ones(n),
            integrality=np.ones(n),
            bounds=Bounds(0, 1),
            constraints=LinearConstraint(M, lb=np.ones(L), ub=np.inf),
            options={"time_limit": float(time_limit_s)},
        )
        if res.x is not None and res.status == 0:
            chosen = np.flatnonzero(res.x > 0.5)
            return chosen.astype(np.int64), True, int(chosen.size), "exact (integer program, HiGHS branch and bound)"
        if method == "exact":
            raise GraphError(
                f"the exact vertex cover did not finish in {time_limit_s} s ({res.message}); use method='approx'"
            )
        import logging  # only here: an MPI job's start-up does not import logging for this module

        logging.getLogger(__name__).warning(
            "exact vertex cover not proven within %.3g s on %d nodes; using the best cover found", time_limit_s, n
        )
        if res.x is not None:
            incumbent = np.flatnonzero(res.x > 0.5).astype(np.int64)
        bound = getattr(res, "mip_dual_bound", None)
        if bound is not None and np.isfinite(bound):
            dual = int(np.ceil(float(bound) - 1e-9))
    matching = _maximal_matching(graph)
    inC = np.zeros(n, bool)
    inC[matching.ravel()] = True
    inC = _prune(graph, inC)
    chosen = np.flatnonzero(inC).astype(np.int64)
    bound, is_lp = matching_lower_bound(graph, matching)
    if not is_lp and links.shape[0] <= LP_BOUND_MAX_LINKS:
        bound, is_lp = max(bound, lp_lower_bound(graph)), True
    lower = max(int(matching.shape[0]), bound, dual)
    how = "LP relaxation" if is_lp else "fractional matching (the LP relaxation not computed: too large)"
    if incumbent is not None and incumbent.size < chosen.size:
        return (
            incumbent,
            False,
            lower,
            f"integer program stopped at its time limit (best cover found); lower bound: {how}",
        )
    return chosen, False, lower, f"2-approximation (maximal matching, pruned); lower bound: {how}"


@dataclass(frozen=True, eq=False)
class ConstraintNodes:
    """A validated set of constraint nodes on ``graph`` (paper 000 §4).

    ``nodes`` sorted global ids; ``mask`` per node; ``method`` how they were chosen; ``optimal`` whether the set is
    a proven minimum vertex cover (None when not a cover choice); ``lower_bound`` a lower bound on the minimum
    cover size (None when not a cover choice); ``unused_links`` links without a constraint node at either end.
    """

    graph: Graph
    nodes: np.ndarray
    method: str
    optimal: bool | None = None
    lower_bound: int | None = None

    @property
    def ratio_bound(self) -> float | None:
        """``|C| / lower_bound``: the returned cover is at most this many times the minimum (1 when optimal)."""
        if self.lower_bound is None or self.lower_bound == 0:
            return None
        return self.size / self.lower_bound

    @property
    def mask(self) -> np.ndarray:
        return _mask(self.graph, self.nodes)

    @property
    def size(self) -> int:
        return int(self.nodes.size)

    @property
    def unused_links(self) -> np.ndarray:
        return unused_links(self.graph, self.nodes)

    @property
    def per_node_count(self) -> np.ndarray:
        """``|N_i ∩ C|``: how many consensus states each node is constrained to (a fresh copy)."""
        return self._per_node_count.copy()

    @cached_property
    def _per_node_count(self) -> np.ndarray:  # a set-up reads it several times: counted once per set
        inC = self.mask
        real = self.graph.src != self.graph.dst
        return inC.astype(np.int64) + np.bincount(
            self.graph.dst[real], weights=inC[self.graph.src[real]], minlength=self.graph.n_nodes
        ).astype(np.int64)

    def summary(self) -> dict[str, Any]:
        ul = self.unused_links
        return {
            "n_constraint_nodes": self.size,
            "nodes": self.nodes.tolist(),
            "method": self.method,
            "optimal": self.optimal,
            "lower_bound": self.lower_bound,
            "n_unused_links": int(ul.shape[0]),
            "unused_links": ul.tolist(),
        }


def choose_constraint_nodes(
    graph: Graph,
    choice: Choice | Iterable[int] | np.ndarray = "min_cover",
    *,
    method: Literal["auto", "exact", "approx"] = "auto",
    exact_max_nodes: int = 150,
    time_limit_s: float = 2.0,
    literal: bool = False,
) -> ConstraintNodes:
    """Choose and validate constraint nodes: ``"all"``, ``"min_cover"`` (every link has a constraint node, as few
    as possible) or a user set of node ids (or a boolean mask). Raises :class:`~distnav.errors.GraphError` if the
    graph is not connected or the set violates conditions (18)."""
    graph.require_connected("the communication graph")
    if isinstance(choice, str):
        if choice == "all":
            nodes = np.arange(graph.n_nodes, dtype=np.int64)
            out = ConstraintNodes(graph, nodes, "all nodes")
        elif choice == "min_cover":
            if graph.n_nodes == 1:
                return ConstraintNodes(graph, np.zeros(1, np.int64), "single node", True, 1)
            nodes, optimal, lb, used = minimum_vertex_cover(
                graph, method=method, exact_max_nodes=exact_max_nodes, time_limit_s=time_limit_s
            )
            out = ConstraintNodes(graph, nodes, used, optimal, lb)
        else:
            raise GraphError(f"unknown constraint-node choice {choice!r}; use 'all', 'min_cover' or a set of node ids")
    else:
        out = ConstraintNodes(graph, _as_node_set(graph, choice), "user set")
    if isinstance(choice, str) and not literal:
        # all nodes, or a vertex cover, of a connected graph satisfy (18) (module doc): check the cover property
        # (linear) instead of the overlap graph
        inC = out.mask
        if graph.n_links and not (inC[graph.links[:, 0]] | inC[graph.links[:, 1]]).all():
            raise GraphError("internal error: the chosen constraint nodes leave a link uncovered")
        return out
    validate_constraint_nodes(graph, out.nodes, literal=literal)
    return out


if TYPE_CHECKING:
    from distnav.network.graph_part import GraphPart


def part_cover(part: GraphPart) -> np.ndarray:
    """Constraint nodes decided by one graph part alone (no whole-network array, no message): a mask over
    ``part.nodes``. Every node is a constraint node but the *local minima* of a fixed hash of the global ids (a node
    whose hash is below all its neighbours'): those form an independent set, so the rest is a vertex cover of the
    whole graph and conditions (18) hold. The hash of a halo node comes from its id, so the choice does not depend
    on how the graph is split into parts (the same set on every partition and in-process: the union over the ranks'
    parts is the rule on the whole graph) and costs one pass over the part's edges — no rounds (the greedy matching
    of ``"min_cover"`` needs rounds along chains of links, 6 s at 2.5·10⁵ nodes of a grid). The price: a larger set
    than the matching's (a node is a local minimum with probability ``1/(deg + 1)``: ≈ 89 % of nodes at degree 8
    against ≈ 75 % for ``"min_cover"`` on a grid); a node without neighbours is left out (a split graph)."""
    from distnav.network.graph_part import owned_rows

    n = part.n_local
    # every node's hash once (owned and halo), each in-edge's sender's by its position: not one hash per edge
    h_own = _id_hash(part.nodes)
    k, own = owned_rows(part.nodes, part.src)
    prio = h_own[k]
    foreign = np.flatnonzero(~own)
    del k, own
    if foreign.size:
        prio[foreign] = _id_hash(part.halo)[np.searchsorted(part.halo, part.src[foreign])]
    del foreign
    if part.self_loops:  # a self-loop is no neighbour
        dst_local = np.repeat(np.arange(n), np.diff(part.in_ptr))
        prio[part.src == part.nodes[dst_local]] = np.iinfo(np.uint64).max
        del dst_local
    lowest = np.full(n, np.iinfo(np.uint64).max, np.uint64)
    has = np.diff(part.in_ptr) > 0
    if prio.size:
        lowest[has] = np.minimum.reduceat(prio, part.in_ptr[:-1][has])
    return ~(h_own < lowest)


def _id_hash(ids: np.ndarray) -> np.ndarray:
    """SplitMix64's finalizer of the ids (a bijection of 64-bit words: no two nodes tie)."""
    z = np.asarray(ids).astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))
