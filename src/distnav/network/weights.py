"""Consensus weight matrices on a communication graph.

A :class:`ConsensusWeights` stores ``W`` as one weight per directed edge ``j→i`` (the weight ``w_ij`` that
receiver ``i`` gives to sender ``j``'s value) plus a self-weight ``w_ii`` per node. Builders:

* paper 003 Table 1: Protocol 1 ``w_ij = 1/max_u dg_u``, Protocol 2 ``w_ij = 1/n``,
  Protocol 3 (Metropolis) ``w_ij = 1/(1+max(dg_i, dg_j))``, Protocol 4 ``w_ij = 1/2`` (only when every
  node has at most one neighbour); self-weights make each row sum to 1.
* paper 002 eq. (12): Metropolis–Hastings ``W_ij = 1/(1+max(d_i, d_j))`` (identical to Protocol 3), and
  Koppanyi's 2018 variant ``W_ij = min(1/d_i, 1/d_j)``, ``W_ii = Σ_k max(0, 1/d_i − 1/d_k)``.

:func:`check_weights` validates a matrix and reports whether average consensus is guaranteed
(paper 003 eq. (34)).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from distnav._optional import scipy_sparse as sp
from distnav.errors import WeightsError
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart

__all__ = [
    "ConsensusWeights",
    "PartWeights",
    "part_weights",
    "WeightsReport",
    "PROTOCOLS",
    "consensus_weights",
    "protocol_weights",
    "metropolis_hastings",
    "koppanyi_weights",
    "check_weights",
    "second_largest_eigenvalue_modulus",
]


@dataclass(frozen=True, eq=False)
class ConsensusWeights:
    """A weight matrix ``W`` on ``graph``: ``edge_weight[e]`` is ``w_{dst[e], src[e]}``; ``self_weight[i]`` is ``w_ii``.

    Self-loop edges of the graph (if any) carry weight 0 here: the self-weight lives in ``self_weight``.
    """

    graph: Graph
    edge_weight: np.ndarray
    self_weight: np.ndarray
    name: str = "custom"

    def __post_init__(self) -> None:
        ew = np.asarray(self.edge_weight, dtype=float)
        sw = np.asarray(self.self_weight, dtype=float)
        if ew.shape != (self.graph.n_edges,):
            raise WeightsError(f"edge_weight must have shape ({self.graph.n_edges},), got {ew.shape}")
        if sw.shape != (self.graph.n_nodes,):
            raise WeightsError(f"self_weight must have shape ({self.graph.n_nodes},), got {sw.shape}")
        if not (np.all(np.isfinite(ew)) and np.all(np.isfinite(sw))):
            raise WeightsError("weights must be finite")
        object.__setattr__(self, "edge_weight", ew)
        object.__setattr__(self, "self_weight", sw)

    @property
    def n_nodes(self) -> int:
        return self.graph.n_nodes

    def to_sparse(self) -> sp.csr_matrix:
        """``W`` as a CSR matrix (rows = receivers)."""
        g = self.graph
        n = g.n_nodes
        diag = np.arange(n)
        rows = np.concatenate([g.dst, diag])
        cols = np.concatenate([g.src, diag])
        vals = np.concatenate([np.where(g.src == g.dst, 0.0, self.edge_weight), self.self_weight])
        return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))

    def to_dense(self) -> np.ndarray:
        return np.asarray(self.to_sparse().toarray())

    @cached_property
    def slem(self) -> float:
        """Second-largest eigenvalue modulus ``λ_{n−1}`` (paper 003 eq. (38))."""
        return second_largest_eigenvalue_modulus(self.to_dense())

    @classmethod
    def from_matrix(
        cls, graph: Graph, matrix: np.ndarray | sp.spmatrix, *, name: str = "custom", atol: float = 1e-12
    ) -> ConsensusWeights:
        """Wrap a dense/sparse ``n×n`` matrix; entries off the graph's links must be zero."""
        m = sp.csr_matrix(matrix, dtype=float)
        n = graph.n_nodes
        if m.shape != (n, n):
            raise WeightsError(f"matrix must be {n}×{n} for this graph, got {m.shape}")
        coo = m.tocoo()
        off = coo.row != coo.col
        allowed = graph.adjacency().tocsr()
        bad = off & (np.abs(coo.data) > atol) & (np.asarray(allowed[coo.row, coo.col]).ravel() == 0)
        if bad.any():
            k = int(np.argmax(bad))
            raise WeightsError(
                f"W[{coo.row[k]}, {coo.col[k]}] = {coo.data[k]:.3g} but nodes {coo.row[k]} and {coo.col[k]} "
                f"are not linked in the graph"
            )
        ew = np.asarray(m[graph.dst, graph.src]).ravel()
        ew = np.where(graph.src == graph.dst, 0.0, ew)
        return cls(graph, ew, m.diagonal().copy(), name=name)


def _edge_degrees(graph: Graph) -> tuple[np.ndarray, np.ndarray]:
    dg = graph.degrees.astype(float)
    return dg[graph.dst], dg[graph.src]


def _finish(graph: Graph, edge_weight: np.ndarray, name: str) -> ConsensusWeights:
    edge_weight = np.where(graph.src == graph.dst, 0.0, edge_weight)
    row_sum = np.bincount(graph.dst, weights=edge_weight, minlength=graph.n_nodes)
    return ConsensusWeights(graph, edge_weight, 1.0 - row_sum, name=name)


def protocol_weights(graph: Graph, protocol: int) -> ConsensusWeights:
    """Weights of paper 003 Table 1, Protocol 1–4, on one session graph.

    Protocol 1 is used as printed (``w_ij = 1/max dg``): the highest-degree node gets self-weight 0, which
    :func:`check_weights` reports; it is not silently changed.
    Protocol 4 raises :class:`WeightsError` when a node has more than one neighbour in the session.
    """
    g = graph
    n = g.n_nodes
    if isinstance(protocol, (bool, np.bool_)):
        raise WeightsError(f"protocol must be 1, 2, 3 or 4 (paper 003 Table 1), got {protocol!r} (a bool)")
    if protocol == 1:
        max_dg = max(int(g.degrees.max()), 1)
        w = np.full(g.n_edges, 1.0 / max_dg)
    elif protocol == 2:
        w = np.full(g.n_edges, 1.0 / n)
    elif protocol == 3:
        di, dj = _edge_degrees(g)
        w = 1.0 / (1.0 + np.maximum(di, dj))
    elif protocol == 4:
        crowded = np.flatnonzero(g.degrees > 1)
        if crowded.size:
            raise WeightsError(
                f"protocol 4 needs every node to have at most one neighbour per session; nodes "
                f"{', '.join(g.names[i] for i in crowded[:10])} have {g.degrees[crowded[0]]}+ neighbours"
            )
        w = np.full(g.n_edges, 0.5)
    else:
        raise WeightsError(f"protocol must be 1, 2, 3 or 4 (paper 003 Table 1), got {protocol!r}")
    return _finish(g, w, f"P{protocol}")


def metropolis_hastings(graph: Graph) -> ConsensusWeights:
    """Metropolis–Hastings weights, paper 002 eq. (12): ``W_ij = 1/(1+max(d_i, d_j))`` (= Protocol 3)."""
    out = protocol_weights(graph, 3)
    return ConsensusWeights(graph, out.edge_weight, out.self_weight, name="MH")


def koppanyi_weights(graph: Graph) -> ConsensusWeights:
    """Koppanyi's 2018 MH variant (papers README): ``W_ij = min(1/d_i, 1/d_j)``, ``W_ii = Σ_k max(0, 1/d_i − 1/d_k)``.

    Nodes without neighbours get ``W_ii = 1``.
    """
    g = graph
    di, dj = _edge_degrees(g)
    with np.errstate(divide="ignore"):
        inv_i = np.where(di > 0, 1.0 / np.maximum(di, 1), 0.0)
        inv_j = np.where(dj > 0, 1.0 / np.maximum(dj, 1), 0.0)
    real = g.src != g.dst
    w = np.where(real, np.minimum(inv_i, inv_j), 0.0)
    self_w = np.bincount(g.dst, weights=np.where(real, np.maximum(0.0, inv_i - inv_j), 0.0), minlength=g.n_nodes)
    self_w = np.where(g.degrees == 0, 1.0, self_w)
    return ConsensusWeights(g, w, self_w, name="Koppanyi")


PROTOCOLS = ("P1", "P2", "P3", "P4", "MH", "Koppanyi")


def consensus_weights(graph: Graph, protocol: str | int) -> ConsensusWeights:
    """Weights by name: ``"P1"``–``"P4"`` (or 1–4), ``"MH"``/``"metropolis"``, ``"Koppanyi"``.

    Examples
    --------
    Metropolis–Hastings weights on a 4-node path: every row of ``W`` sums to one, and the spectrum says how fast
    consensus converges (paper 003 §3, λ_{n−1} below one):

    >>> from distnav.network import builders, consensus_weights
    >>> w = consensus_weights(builders.path(4), "MH")
    >>> w.to_dense().sum(axis=1).round(12).tolist()
    [1.0, 1.0, 1.0, 1.0]
    >>> bool(w.slem < 1)
    True
    """
    key = str(protocol).strip().lower()
    if key in {"1", "2", "3", "4"}:
        return protocol_weights(graph, int(key))
    if key in {"p1", "p2", "p3", "p4"}:
        return protocol_weights(graph, int(key[1]))
    if key in {"mh", "metropolis", "metropolis-hastings"}:
        return metropolis_hastings(graph)
    if key == "koppanyi":
        return koppanyi_weights(graph)
    raise WeightsError(f"unknown consensus protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")


@dataclass(frozen=True, eq=False)
class PartWeights:
    """Consensus weights of one :class:`~distnav.network.graph_part.GraphPart`: ``edge_weight[k]`` on the part's
    incoming edge ``k`` (``w_{dst, src}``), ``self_weight[k]`` of ``part.nodes[k]``. Equal, entry for entry, to the
    whole graph's :class:`ConsensusWeights` of the same protocol on those edges and nodes."""

    graph: GraphPart
    edge_weight: np.ndarray
    self_weight: np.ndarray
    name: str = "custom"


def part_weights(part: GraphPart, protocol: str | int) -> PartWeights:
    """Weights on a graph part, from the degrees it holds: Protocol 2 (``1/n``) and Protocol 3 / Metropolis–Hastings
    (``1/(1+max(dg_i, dg_j))``, paper 003 Table 1, paper 002 eq. (12)) need nothing beyond a node's neighbours;
    the others (the network's largest degree, Koppanyi's sums) are refused rather than approximated."""
    key = str(protocol).strip().lower()
    names = {"2": "P2", "p2": "P2", "3": "P3", "p3": "P3", "mh": "MH", "metropolis": "MH", "metropolis-hastings": "MH"}
    if key not in names:
        raise WeightsError(f"protocol {protocol!r} needs the whole graph; on a graph part use 'P2', 'P3' or 'MH'")
    name = names[key]
    dst_local = np.repeat(np.arange(part.n_local), np.diff(part.in_ptr))
    if name == "P2":
        w = np.full(part.n_local_edges, 1.0 / part.n_nodes)
    else:  # the same expression as protocol_weights on the whole graph: the same numbers, bit for bit
        di = part.degree.astype(float)[dst_local]
        dj = part.sender_degree().astype(float)
        w = 1.0 / (1.0 + np.maximum(di, dj))
    w = np.where(part.src == part.nodes[dst_local], 0.0, w)
    row_sum = np.bincount(dst_local, weights=w, minlength=part.n_local)
    return PartWeights(part, w, 1.0 - row_sum, name=name)


def second_largest_eigenvalue_modulus(matrix: np.ndarray) -> float:
    """``λ_{n−1}``: the second-largest eigenvalue modulus of ``W`` (paper 003 eq. (38)).

    For a symmetric ``W`` uses ``eigvalsh``; otherwise the moduli of ``eigvals``.
    """
    m = np.asarray(matrix, dtype=float)
    if m.shape[0] < 2:
        return 0.0
    if np.allclose(m, m.T, atol=1e-13):
        mod = np.sort(np.abs(np.linalg.eigvalsh(m)))
    else:
        mod = np.sort(np.abs(np.linalg.eigvals(m)))
    return float(mod[-2])


@dataclass(frozen=True)
class WeightsReport:
    """Outcome of :func:`check_weights`. ``ok`` means usable; ``guaranteed`` means average consensus converges."""

    ok: bool
    nonnegative: bool
    row_stochastic: bool
    column_stochastic: bool
    symmetric: bool
    respects_graph: bool
    positive_diagonal: bool
    slem: float | None
    guaranteed: bool
    message: str


def check_weights(weights: ConsensusWeights, *, atol: float = 1e-10, raise_on_error: bool = False) -> WeightsReport:
    """Validate ``W`` and say whether average consensus ``W^k → (1/n) e eᵀ`` is guaranteed (paper 003 eq. (34)).

    Checks: non-negative entries, row and column sums 1, symmetry, and sparsity of the graph (by construction
    of :class:`ConsensusWeights`). A positive diagonal on a connected graph is sufficient for convergence; when
    a diagonal entry is zero (Protocol 1 as printed gives the highest-degree node self-weight 0) the spectrum
    decides: converges iff ``λ_{n−1} < 1`` (fails e.g. on regular bipartite graphs, eigenvalue −1).
    With ``raise_on_error`` a violated requirement raises :class:`WeightsError` with the same message.
    """
    w = weights
    g = w.graph
    problems: list[str] = []
    real = g.src != g.dst
    neg_e = real & (w.edge_weight < -atol)
    neg_s = w.self_weight < -atol
    nonneg = not (neg_e.any() or neg_s.any())
    if neg_e.any():
        k = int(np.argmax(neg_e))
        problems.append(f"W[{g.dst[k]}, {g.src[k]}] = {w.edge_weight[k]:.3g} is negative")
    if neg_s.any():
        k = int(np.argmax(neg_s))
        problems.append(f"self-weight of node {g.names[k]} is {w.self_weight[k]:.3g} < 0")
    ew = np.where(real, w.edge_weight, 0.0)
    rows = np.bincount(g.dst, weights=ew, minlength=g.n_nodes) + w.self_weight
    cols = np.bincount(g.src, weights=ew, minlength=g.n_nodes) + w.self_weight
    row_ok = bool(np.all(np.abs(rows - 1) <= atol))
    col_ok = bool(np.all(np.abs(cols - 1) <= atol))
    if not row_ok:
        k = int(np.argmax(np.abs(rows - 1)))
        problems.append(f"row {g.names[k]} sums to {rows[k]:.12g}, not 1")
    if not col_ok:
        k = int(np.argmax(np.abs(cols - 1)))
        problems.append(f"column {g.names[k]} sums to {cols[k]:.12g}, not 1 (average not preserved)")
    symmetric = bool(np.allclose(w.edge_weight, w.edge_weight[g.reverse_edge], atol=atol, rtol=0))
    pos_diag = bool(np.all(w.self_weight > atol))
    connected = g.is_connected
    if not connected:
        problems.append("graph is not connected: consensus cannot reach the network average")
    slem: float | None = None
    ok = nonneg and row_ok and col_ok and connected
    notes: list[str] = []
    if ok:
        if pos_diag:
            guaranteed = True
            notes.append("doubly stochastic, positive diagonal, connected graph: average consensus guaranteed")
            if g.n_nodes <= 3000:
                slem = w.slem
        else:
            zero = np.flatnonzero(w.self_weight <= atol)
            slem = w.slem
            guaranteed = slem < 1 - 1e-12
            who = ", ".join(g.names[i] for i in zero[:10])
            if guaranteed:
                notes.append(
                    f"self-weight is zero at node(s) {who}; a positive diagonal would be sufficient, but the "
                    f"spectrum decides: λ_(n-1) = {slem:.4f} < 1, so average consensus still converges"
                )
            else:
                notes.append(
                    f"self-weight is zero at node(s) {who} and λ_(n-1) = {slem:.4f} = 1 (e.g. a regular bipartite "
                    f"graph oscillates): average consensus is NOT guaranteed with these weights"
                )
    else:
        guaranteed = False
    message = "; ".join(problems + notes)
    if raise_on_error and (not ok or not guaranteed):
        raise WeightsError(f"{w.name} weights unusable: {message}")
    return WeightsReport(
        ok=ok,
        nonnegative=nonneg,
        row_stochastic=row_ok,
        column_stochastic=col_ok,
        symmetric=symmetric,
        respects_graph=True,
        positive_diagonal=pos_diag,
        slem=slem,
        guaranteed=guaranteed,
        message=message,
    )
