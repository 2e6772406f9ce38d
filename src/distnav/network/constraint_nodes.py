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
  removing any chosen node whose neighbours are all chosen. Bound: ``|M| ≤ OPT ≤ |C| ≤ 2|M| ≤ 2·OPT``; the
  lower bound ``|M|`` is reported with the result;
* ``method="auto"`` (default): exact for graphs up to ``exact_max_nodes`` nodes (falls back to the approximation
  if the solver does not prove optimality in time), the approximation beyond.

A vertex cover of a connected graph always satisfies (18). :func:`unused_links` lists the links with no
constraint node at either end: they carry no ADMM message (Fig. 5 right: ``C = {1,3,4,9}`` leaves (5,6), (6,7)).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy.sparse.csgraph import connected_components

from distnav.errors import GraphError
from distnav.network.graph import Graph

__all__ = [
    "ConstraintNodes",
    "ConditionsReport",
    "check_conditions",
    "validate_constraint_nodes",
    "unused_links",
    "minimum_vertex_cover",
    "choose_constraint_nodes",
]

Choice = Literal["all", "min_cover"]


def _names(graph: Graph, ids: Iterable[int], limit: int = 20) -> str:
    ids = list(ids)
    shown = ", ".join(graph.names[int(i)] for i in ids[:limit])
    return shown + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def _as_node_set(graph: Graph, nodes: Any) -> np.ndarray:
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


def check_conditions(graph: Graph, nodes: Any, *, literal: bool = False) -> ConditionsReport:
    """Check conditions (18) of paper 000 for the constraint nodes ``nodes`` (see the module docstring for how
    condition 2 is read). Returns a report; :func:`validate_constraint_nodes` raises instead."""
    C = _as_node_set(graph, nodes)
    inC = _mask(graph, C)
    real = graph.src != graph.dst
    src, dst = graph.src[real], graph.dst[real]
    covered = inC.copy()
    covered[dst[inC[src]]] = True
    uncovered = tuple(int(i) for i in np.flatnonzero(~covered))
    # overlap graph on C: s1–s2 when N_s1 ∩ N_s2 ≠ ∅ ⇔ s1, s2 adjacent or share a neighbour (closed neighbourhoods)
    A = graph.adjacency(include_self=True)
    overlap = (A[C] @ A[:, C]).tocsr()
    _, labels = connected_components(overlap, directed=False)
    groups = tuple(tuple(int(s) for s in C[labels == g]) for g in np.unique(labels))
    unbridged: list[tuple[int, int]] = []
    if literal and C.size > 1:
        O = (overlap.toarray() > 0)
        bridged = (O.astype(np.int64) @ O.astype(np.int64)) > 0
        bad = np.argwhere(~O & ~bridged)
        unbridged = [(int(C[a]), int(C[b])) for a, b in bad if a < b]
    return ConditionsReport(uncovered=uncovered, groups=groups if len(groups) > 1 else (tuple(int(s) for s in C),),
                            unbridged_pairs=tuple(unbridged), literal=literal)


def validate_constraint_nodes(graph: Graph, nodes: Any, *, literal: bool = False) -> np.ndarray:
    """Return the sorted constraint-node ids, or raise :class:`~distnav.errors.GraphError` naming the nodes that
    violate conditions (18) of paper 000."""
    C = _as_node_set(graph, nodes)
    rep = check_conditions(graph, C, literal=literal)
    problems = []
    if rep.uncovered:
        problems.append(f"(18)-1: nodes {_names(graph, rep.uncovered)} have no constraint node in their "
                        f"neighbourhood")
    if len(rep.groups) > 1:
        shown = "; ".join("{" + _names(graph, g, 8) + "}" for g in rep.groups[:4])
        problems.append(f"(18)-2: the constraint nodes split into {len(rep.groups)} groups whose neighbourhoods "
                        f"never overlap: {shown}")
    if rep.unbridged_pairs:
        pairs = ", ".join(f"({graph.names[a]}, {graph.names[b]})" for a, b in rep.unbridged_pairs[:10])
        problems.append(f"(18)-2 (literal): no single constraint node bridges the pairs {pairs}")
    if problems:
        raise GraphError("constraint nodes violate conditions (18) of paper 000: " + "; ".join(problems))
    return C


def unused_links(graph: Graph, nodes: Any) -> np.ndarray:
    """Links ``(i, j)`` (``i < j``) with no constraint node at either end: ADMM sends nothing over them."""
    inC = _mask(graph, _as_node_set(graph, nodes))
    links = graph.links
    if links.size == 0:
        return links
    return np.asarray(links[~(inC[links[:, 0]] | inC[links[:, 1]])])


# ----------------------------------------------------------------------------------------------- vertex cover
def _maximal_matching(graph: Graph) -> np.ndarray:
    """Greedy maximal matching (links in order, lowest-degree endpoints first); ``(|M|, 2)``."""
    links = graph.links
    if links.size == 0:
        return links
    deg = graph.degrees
    order = np.lexsort((np.maximum(deg[links[:, 0]], deg[links[:, 1]]), deg[links[:, 0]] + deg[links[:, 1]]))
    used = np.zeros(graph.n_nodes, bool)
    out = []
    for a, b in links[order].tolist():
        if not used[a] and not used[b]:
            used[a] = used[b] = True
            out.append((a, b))
    return np.asarray(out, dtype=np.int64).reshape(-1, 2)


def _prune(graph: Graph, inC: np.ndarray) -> np.ndarray:
    """Drop chosen nodes whose neighbours are all chosen (the result stays a vertex cover)."""
    inC = inC.copy()
    ptr = graph.in_ptr
    src = graph.src
    deg = graph.degrees
    for v in sorted(np.flatnonzero(inC).tolist(), key=lambda k: (deg[k], k)):
        nb = src[ptr[v]:ptr[v + 1]]
        nb = nb[nb != v]
        if nb.size and inC[nb].all():
            inC[v] = False
    return inC


def minimum_vertex_cover(graph: Graph, *, method: Literal["auto", "exact", "approx"] = "auto",
                         exact_max_nodes: int = 1000, time_limit_s: float = 10.0
                         ) -> tuple[np.ndarray, bool, int, str]:
    """A (minimum) vertex cover: every link gets at least one chosen node.

    Returns ``(nodes, optimal, lower_bound, method_used)``. See the module docstring for the methods and the
    approximation bound ``|C| ≤ 2·OPT`` (``lower_bound = |M|`` for the approximation, ``|C|`` when exact).
    """
    if method not in ("auto", "exact", "approx"):
        raise GraphError(f"unknown vertex-cover method {method!r}; choose 'auto', 'exact' or 'approx'")
    n = graph.n_nodes
    links = graph.links
    if links.size == 0:
        return np.zeros(0, np.int64), True, 0, "no links"
    matching = _maximal_matching(graph)
    if method == "exact" or (method == "auto" and n <= exact_max_nodes):
        from scipy.optimize import Bounds, LinearConstraint, milp
        from scipy.sparse import csr_matrix

        L = links.shape[0]
        rows = np.repeat(np.arange(L), 2)
        M = csr_matrix((np.ones(2 * L), (rows, links.ravel())), shape=(L, n))
        res = milp(c=np.ones(n), integrality=np.ones(n), bounds=Bounds(0, 1),
                   constraints=LinearConstraint(M, lb=np.ones(L), ub=np.inf),
                   options={"time_limit": float(time_limit_s)})
        if res.x is not None and res.status == 0:
            chosen = np.flatnonzero(res.x > 0.5)
            return chosen.astype(np.int64), True, int(chosen.size), "exact (integer program, HiGHS branch and bound)"
        if method == "exact":
            raise GraphError(f"the exact vertex cover did not finish in {time_limit_s} s ({res.message}); "
                             f"use method='approx'")
    inC = np.zeros(n, bool)
    inC[matching.ravel()] = True
    inC = _prune(graph, inC)
    chosen = np.flatnonzero(inC).astype(np.int64)
    return chosen, False, int(matching.shape[0]), "2-approximation (maximal matching, pruned)"


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
        """``|N_i ∩ C|``: how many consensus states each node is constrained to."""
        inC = self.mask
        real = self.graph.src != self.graph.dst
        return inC.astype(np.int64) + np.bincount(self.graph.dst[real], weights=inC[self.graph.src[real]],
                                                  minlength=self.graph.n_nodes).astype(np.int64)

    def summary(self) -> dict[str, Any]:
        ul = self.unused_links
        return {"n_constraint_nodes": self.size, "nodes": self.nodes.tolist(), "method": self.method,
                "optimal": self.optimal, "lower_bound": self.lower_bound, "n_unused_links": int(ul.shape[0]),
                "unused_links": ul.tolist()}


def choose_constraint_nodes(graph: Graph, choice: Choice | Iterable[int] | np.ndarray = "min_cover", *,
                            method: Literal["auto", "exact", "approx"] = "auto", exact_max_nodes: int = 1000,
                            time_limit_s: float = 10.0, literal: bool = False) -> ConstraintNodes:
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
            nodes, optimal, lb, used = minimum_vertex_cover(graph, method=method, exact_max_nodes=exact_max_nodes,
                                                            time_limit_s=time_limit_s)
            out = ConstraintNodes(graph, nodes, used, optimal, lb)
        else:
            raise GraphError(f"unknown constraint-node choice {choice!r}; use 'all', 'min_cover' or a set of node ids")
    else:
        out = ConstraintNodes(graph, _as_node_set(graph, choice), "user set")
    validate_constraint_nodes(graph, out.nodes, literal=literal)
    return out
