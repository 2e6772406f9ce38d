"""Average consensus (paper 003 §3): protocols over static and switching graphs, product matrices, measures.

* :func:`consensus_schedule` — the per-round weight matrices (one per session) on the union graph.
* :func:`iterate_average_consensus` / :func:`average_consensus` — ``k_n`` rounds of eq. (31),
  ``r_i^(k) = Σ_j w_ij^(k) r_j^(k−1)``, on scalars, vectors or matrices, through the exchange.
* :func:`consensus_product` — ``L = W_(k_n) ⋯ W_(1)`` (eq. (33)); row ``l_i`` feeds the CKF variance recursion.
* :func:`second_largest_eigenvalue_modulus` — ``λ_{n−1}`` (eq. (38)).
* :func:`consensus_probability` — the probabilistic measure of eqs. (39)–(40) by vectorized Monte Carlo.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from distnav._checks import real_array, whole_number
from distnav._settings import runs
from distnav.algorithms.result import SolverResult, TraceBuilder, stopping_fields
from distnav.errors import WeightsError
from distnav.exchange import Exchange, make_exchange
from distnav.network.graph import Graph, SwitchingGraph
from distnav.network.weights import (
    ConsensusWeights,
    check_weights,
    consensus_weights,
    second_largest_eigenvalue_modulus,
)

__all__ = [
    "ConsensusResult",
    "ConsensusWarning",
    "ConsensusSchedule",
    "ConsensusState",
    "consensus_schedule",
    "iterate_average_consensus",
    "average_consensus",
    "consensus_product",
    "consensus_probability",
    "second_largest_eigenvalue_modulus",
]


class ConsensusWarning(UserWarning):
    """Consensus weights that are valid but do not guarantee convergence to the average."""


@dataclass(frozen=True, eq=False)
class ConsensusSchedule:
    """Weights of every session, expressed on the union graph, with each session's active-edge mask.

    Round ``k`` (0-based) uses ``weights[k % n_sessions]`` and ``active[k % n_sessions]``.
    """

    graph: Graph
    weights: tuple[ConsensusWeights, ...]
    active: tuple[np.ndarray | None, ...]

    @property
    def n_sessions(self) -> int:
        return len(self.weights)

    def matrix(self, round_index: int) -> np.ndarray:
        """Dense ``W`` used in round ``round_index``."""
        return self.weights[round_index % self.n_sessions].to_dense()


def _on_union(union: Graph, session_w: ConsensusWeights, mask: np.ndarray) -> ConsensusWeights:
    sg = session_w.graph
    ew = np.zeros(union.n_edges)
    real = sg.src != sg.dst
    if real.any():
        ew[union.edge_index(sg.src[real], sg.dst[real])] = session_w.edge_weight[real]
    return ConsensusWeights(union, ew, session_w.self_weight, name=session_w.name)


def consensus_schedule(
    graph: Graph | SwitchingGraph,
    protocol: str | int | ConsensusWeights | Sequence[ConsensusWeights] = "P3",
    *,
    validate: bool = True,
) -> ConsensusSchedule:
    """Per-session consensus weights for a static or switching graph.

    ``protocol`` is a name (``"P1"``–``"P4"``, ``"MH"``, ``"Koppanyi"``) applied to every session, or
    ready-made weights (one, or one per session). With ``validate`` the weights must be doubly stochastic
    and non-negative; for a static graph where consensus is not guaranteed (:func:`check_weights` explains why)
    a :class:`ConsensusWarning` is issued: the run goes ahead with the protocol as given, never silently changed.
    """
    if isinstance(graph, SwitchingGraph):
        union = graph.union
        sessions = list(graph.sessions)
        masks: list[np.ndarray | None] = list(graph.session_edge_masks)
    else:
        union = graph
        sessions = [graph]
        masks = [None]
    if isinstance(protocol, ConsensusWeights):
        given: list[ConsensusWeights] = [protocol]
    elif isinstance(protocol, (list, tuple)):
        given = list(protocol)
    else:
        given = [consensus_weights(s, protocol) for s in sessions]  # type: ignore[arg-type]
    if len(given) != len(sessions):
        raise WeightsError(f"got {len(given)} weight matrices for {len(sessions)} sessions")
    out: list[ConsensusWeights] = []
    for k, (w, s, m) in enumerate(zip(given, sessions, masks, strict=True)):
        if w.graph.n_nodes != s.n_nodes:
            raise WeightsError(f"weights of session {k} are for {w.graph.n_nodes} nodes, graph has {s.n_nodes}")
        if validate:
            rep = check_weights(w)
            if not (rep.nonnegative and rep.row_stochastic and rep.column_stochastic):
                raise WeightsError(f"weights of session {k} ({w.name}) unusable: {rep.message}")
            if len(sessions) == 1 and not rep.guaranteed:
                warnings.warn(f"weights {w.name}: {rep.message}", ConsensusWarning, stacklevel=2)
        out.append(
            w
            if m is None and w.graph is union
            else _on_union(union, w, m if m is not None else np.ones(union.n_edges, bool))
        )
    return ConsensusSchedule(graph=union, weights=tuple(out), active=tuple(masks))


@dataclass(frozen=True, eq=False)
class ConsensusState:
    """State after ``round`` consensus rounds: this block's values ``(n_local, ...)``."""

    round: int
    values: np.ndarray


def _as_node_array(values: np.ndarray, n_nodes: int) -> np.ndarray:
    arr = real_array(values, "values", error=WeightsError)
    if arr.ndim == 0 or arr.shape[0] != n_nodes:
        raise WeightsError(f"values must have one row per node (leading axis {n_nodes}), got shape {arr.shape}")
    if arr.size == 0:
        raise WeightsError(f"values hold nothing to average: shape {arr.shape} has a zero-length axis")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr.reshape(n_nodes, -1)).all(axis=1))
        raise WeightsError(f"values of nodes {bad[:10].tolist()} are not finite")
    return arr


def iterate_average_consensus(
    values: np.ndarray,
    *,
    graph: Graph | SwitchingGraph,
    protocol: str | int | ConsensusWeights | Sequence[ConsensusWeights] = "P3",
    rounds: int,
    exchange: Exchange | None = None,
    schedule: ConsensusSchedule | None = None,
) -> Iterator[ConsensusState]:
    """Yield the state after rounds 0 (initial), 1, …, ``rounds`` of eq. (31).

    ``values`` has a leading node axis (``n_nodes``) and any payload shape (scalars, vectors, matrices).
    On an MPI exchange only this block's rows are used and yielded, in the order of ``exchange.nodes``; without
    ``exchange`` the run makes an in-process one in the user's order, so the states' rows are the user's nodes.
    """
    rounds = whole_number(rounds, "rounds", error=WeightsError)
    sched = schedule if schedule is not None else consensus_schedule(graph, protocol)
    ex = exchange if exchange is not None else make_exchange(sched.graph)
    if ex.graph.n_edges != sched.graph.n_edges:
        raise WeightsError("the exchange was built on a different graph than the consensus schedule")
    x = ex.local(_as_node_array(values, sched.graph.n_nodes))
    mixers = [ex.mixer(w, active=a) for w, a in zip(sched.weights, sched.active, strict=True)]
    yield ConsensusState(0, x)
    for k in range(rounds):
        x = mixers[k % len(mixers)].apply(x)
        yield ConsensusState(k + 1, x)


@dataclass(frozen=True, eq=False, kw_only=True)
class ConsensusResult(SolverResult):
    """Result of :func:`average_consensus`: ``average`` is the true network average r̄ (the reference the trace's
    ``max_abs_deviation`` is measured against; a monitoring value no node holds)."""

    average: np.ndarray


@runs(iterate_average_consensus, drops=("schedule",), adds=("record_values",))
def average_consensus(
    values: np.ndarray,
    *,
    graph: Graph | SwitchingGraph,
    protocol: str | int | ConsensusWeights | Sequence[ConsensusWeights] = "P3",
    rounds: int,
    exchange: Exchange | None = None,
    record_values: bool = False,
) -> ConsensusResult:
    """Run ``rounds`` of average consensus; returns per-node values after the last round.

    Trace: ``max_abs_deviation`` (round 0..rounds, max over nodes and entries of |r_i^(k) − r̄|) and, with
    ``record_values``, ``values`` (rounds+1 × n_nodes × payload). ``converged`` is True when the final
    deviation is below 1e-9 × (1 + max |r̄|).

    Results are in the user's node order at every size. Without ``exchange`` the run makes one with the locality
    order (``order="auto"``: RCM from 10⁴ nodes on) and gathers back; an ``exchange`` of any order works the same,
    ``make_exchange(graph, order="auto")`` being the fast one on large networks (docs/scale.md).

    Examples
    --------
    Five nodes on a ring agree on the mean of their values (4.0) with the Metropolis weights (P3); each round is
    one message per direction of every link:

    >>> import numpy as np
    >>> from distnav.algorithms.consensus.averaging import average_consensus
    >>> from distnav.network import builders
    >>> res = average_consensus(np.array([1.0, 2.0, 3.0, 4.0, 10.0]), graph=builders.ring(5), rounds=60)
    >>> res.converged, res.estimates.round(6).tolist(), res.comm.messages
    (True, [4.0, 4.0, 4.0, 4.0, 4.0], 600)
    """
    arr = _as_node_array(values, graph.n_nodes)
    rounds = whole_number(rounds, "rounds", error=WeightsError)
    mean = arr.mean(axis=0)
    sched = consensus_schedule(graph, protocol)
    # its own exchange keeps the locality order inside: every value handed out goes through gather_nodes
    ex = exchange if exchange is not None else make_exchange(sched.graph, order="auto")
    tb = TraceBuilder()
    last = None
    for state in iterate_average_consensus(arr, graph=graph, rounds=rounds, exchange=ex, schedule=sched):
        dev = np.abs(state.values - mean).max() if state.values.size else 0.0
        tb.add(max_abs_deviation=ex.allreduce(dev, "max"))
        if record_values:
            tb.add(values=ex.gather_nodes(state.values))
        last = state
    assert last is not None
    final = ex.gather_nodes(last.values)
    dev_final = float(np.abs(final - mean).max())
    tol = 1e-9 * (1 + float(np.abs(mean).max()))
    converged = dev_final <= tol
    message = f"{rounds} rounds, max |r_i − r̄| = {dev_final:.3g}"
    return ConsensusResult(
        estimates=final, **stopping_fields(converged, rounds, message, tb, ex.comm_totals()), average=mean
    )


def consensus_product(schedule: ConsensusSchedule | ConsensusWeights, rounds: int) -> np.ndarray:
    """``L = W_(rounds) ⋯ W_(2) W_(1)`` as a dense ``n×n`` array (paper 003 eq. (33)).

    After ``rounds`` rounds every node holds ``r^(k_n) = L r``; row ``l_i`` of ``L`` is what the CKF error-variance
    recursion needs (paper 003 Fig. 7).
    """
    rounds = whole_number(rounds, "rounds", error=WeightsError)
    if isinstance(schedule, ConsensusWeights):
        schedule = ConsensusSchedule(schedule.graph, (schedule,), (None,))
    n = schedule.graph.n_nodes
    mats = [w.to_sparse() for w in schedule.weights]
    out = np.eye(n)
    for k in range(int(rounds)):
        out = np.asarray(mats[k % len(mats)] @ out)
    return out


def consensus_probability(
    product: np.ndarray,
    q: np.ndarray,
    *,
    samples: int = 100_000,
    rng: np.random.Generator,
    chunk: int = 20_000,
) -> np.ndarray:
    """Probabilistic convergence measure, paper 003 eq. (40): ``P(max_i |r_i^(k_n) − r̄| ≤ q σ)``.

    The ``r_i`` are i.i.d. ``N(μ, σ²)``; the deviation ``r^(k_n) − r̄ e = (L − eeᵀ/n) r`` does not depend on μ
    and scales with σ, so σ = 1 is simulated. Returns one probability per entry of ``q``.
    """
    L = np.asarray(product, dtype=float)
    n = L.shape[0]
    if L.shape != (n, n):
        raise WeightsError(f"product must be square, got {L.shape}")
    D = (L - np.full((n, n), 1.0 / n)).T
    maxdev = np.empty(samples)
    for start in range(0, samples, chunk):
        stop = min(samples, start + chunk)
        r = rng.standard_normal((stop - start, n))
        maxdev[start:stop] = np.abs(r @ D).max(axis=1)
    maxdev.sort()
    qs = np.asarray(q, dtype=float)
    return np.searchsorted(maxdev, qs, side="right") / samples
