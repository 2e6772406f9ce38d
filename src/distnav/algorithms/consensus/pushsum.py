"""Asynchronous push-sum averaging, robust to lost messages by running sums (issue 26 item 5).

Push-sum (Kempe, Dobra & Gehrke 2003): node ``i`` holds a mass ``(y_i, z_i)``, initially ``(x_i, 1)``. When it
*ticks* it keeps ``1/(D_i + 1)`` of its mass and sends ``1/(D_i + 1)`` to each of its ``D_i`` out-neighbours; its
estimate of the network average is the ratio ``y_i / z_i``. The total mass ``(Σ x_i, n)`` never changes, so the
ratios converge to ``Σ x_i / n`` without any node knowing ``n``, and without a global barrier: a node may tick
whenever its own timer fires.

Plain push-sum loses the mass of a lost message, and the ratio is then biased. The running-sum variant
(Hadjicostis, Vaidya & Domínguez-García 2016, "Robust distributed average consensus via exchange of running sums",
IEEE TAC 61(6), eqs. (6)–(8)) sends instead the *cumulative* mass ``σ_i`` node ``i`` has ever pushed on a link; the
receiver keeps the last cumulative value ``ρ_ji`` it got from ``j`` and adds the difference:

* tick of ``i``:   ``σ_i ← σ_i + m_i / (D_i + 1)``,  ``m_i ← m_i / (D_i + 1)``, send ``σ_i`` to every out-neighbour;
* receipt on ``j → i``:  ``m_i ← m_i + (σ_j − ρ_ji)``,  ``ρ_ji ← σ_j``.

A message that is lost changes nothing at the receiver; the next message that arrives on the same link carries the
lost mass as well. Hence the invariant (tested at every tick)::

    Σ_i m_i + Σ_(j→i) (σ_j − ρ_ji) = (Σ_i x_i, n)      (mass at the nodes + mass in flight on the links)

As long as every link delivers a message infinitely often, the mass in flight is bounded and drained, and the
ratios converge to the exact average (the paper's Theorem 1; with i.i.d. losses of probability < 1 this holds with
probability one). Each node sends a single value per tick — its ``σ_i`` is the same on all its out-links — so the
round is a :meth:`~distnav.exchange.base.Exchange.broadcast` restricted to the nodes that tick.

Ticks here are simulated on any exchange (in-process or MPI): in tick ``t`` node ``i`` acts when
``uniform_hash(seed, t, i) < rate_i``, a pure function of ``(seed, t, i)``, so every block agrees on who acts with no
communication, and a node with rate ``r`` ticks ``r`` times as often as one with rate 1. Lost messages come from the
exchange's :class:`~distnav.exchange.faults.FaultSchedule`. With every rate 1 and no losses each tick is one step
``m ← A m`` of ordinary synchronous push-sum (``A_ji = 1/(D_i + 1)`` for ``j`` ∈ out-neighbours of ``i`` and itself).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp

from distnav._checks import real_number, whole_number
from distnav._settings import runs
from distnav.algorithms.result import SolverResult, SolverStatus, TraceBuilder
from distnav.errors import WeightsError
from distnav.exchange import Exchange, make_exchange
from distnav.exchange.faults import uniform_hash
from distnav.network.graph import Graph

__all__ = [
    "Clock",
    "PushSumState",
    "PushSumResult",
    "iterate_push_sum",
    "mass_in_flight",
    "push_sum",
    "PushSumLink",
    "NodeOutcome",
    "run_push_sum_node",
]


@dataclass(frozen=True, eq=False)
class PushSumState:
    """This block's push-sum state after tick ``tick`` (rows follow ``exchange.nodes``).

    ``mass`` is ``(n_local, p + 1)``: the ``p`` payload columns ``y`` then the weight ``z``; ``sent`` the running
    sum σ of each local node (same shape); ``received`` the last running sum ρ got on each incoming edge
    (``exchange.in_edges`` order); ``acted`` which local nodes ticked.
    """

    tick: int
    mass: np.ndarray
    sent: np.ndarray
    received: np.ndarray
    acted: np.ndarray

    @property
    def ratio(self) -> np.ndarray:
        """Each local node's estimate of the average, ``y_i / z_i`` → ``(n_local, p)``."""
        out: np.ndarray = self.mass[:, :-1] / self.mass[:, -1:]
        return out


@dataclass(frozen=True, eq=False, kw_only=True)
class PushSumResult(SolverResult):
    """Result of :func:`push_sum`. ``estimates`` are the ratios ``(n_nodes, p)``; ``average`` is the true average
    of the initial values (monitoring, no node holds it); ``ticks_per_node`` how often each node acted;
    ``mass_error`` the largest violation of the mass invariant seen (rounding only)."""

    average: np.ndarray
    ticks_per_node: np.ndarray
    mass_error: float


@dataclass(frozen=True, eq=False)
class Clock:
    """When nodes tick in a simulated asynchronous run: in tick ``t`` node ``i`` acts when
    ``uniform_hash(seed, t, i) < rates[i]`` (``rates`` one number for all nodes or one per node, in (0, 1])."""

    rates: float | np.ndarray = 1.0
    seed: int = 0

    def per_node(self, n_nodes: int) -> np.ndarray:
        """The rate of every node, checked: a rate outside (0, 1] names its node."""
        r = np.broadcast_to(np.asarray(self.rates, dtype=float), (n_nodes,)).copy()
        bad_rate = np.flatnonzero(~((r > 0) & (r <= 1)))
        if bad_rate.size:
            i = int(bad_rate[0])
            raise WeightsError(f"tick rate of node {i} must be in (0, 1], got {r[i]!r}")
        return r

    def acts(self, tick: int, nodes: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """Which of ``nodes`` (global ids, with their checked ``rates``) act in tick ``tick``."""
        return np.asarray(uniform_hash(self.seed, tick, np.asarray(nodes)) < rates)


def _node_values(values: np.ndarray, n_nodes: int) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 0 or arr.shape[0] != n_nodes:
        raise WeightsError(f"values must have one row per node (leading axis {n_nodes}), got shape {arr.shape}")
    flat = arr.reshape(n_nodes, -1)
    if not np.all(np.isfinite(flat)):
        bad = np.flatnonzero(~np.isfinite(flat).all(axis=1))
        raise WeightsError(f"values of nodes {bad[:10].tolist()} are not finite")
    return flat


def iterate_push_sum(
    values: np.ndarray, *, graph: Graph, ticks: int, clock: Clock = Clock(), exchange: Exchange | None = None
) -> Iterator[PushSumState]:
    """Yield the state after ticks 0 (initial), 1, …, ``ticks`` of running-sum push-sum (module docstring).

    ``values`` ``(n_nodes, ...)`` are the initial values (flattened to ``(n_nodes, p)``); ``clock`` says which nodes
    act in each tick. Only this block's rows are used.
    """
    ticks = whole_number(ticks, "ticks", error=WeightsError)
    flat, rate = _node_values(values, graph.n_nodes), clock.per_node(graph.n_nodes)
    ex = exchange if exchange is not None else make_exchange(graph)
    if ex.n_edges != graph.n_edges or ex.n_nodes != graph.n_nodes:
        raise WeightsError("the exchange was built on a different graph")
    nodes = ex.nodes
    real_out = ex.out_dst != nodes[ex.out_src]
    real_in = ex.in_src != nodes[ex.in_dst]
    share = 1.0 / (np.bincount(ex.out_src[real_out], minlength=ex.n_local) + 1.0)  # 1/(D_i + 1)
    to_receiver = sp.csr_matrix(
        (real_in.astype(float), (ex.in_dst, np.arange(ex.in_edges.size))), shape=(ex.n_local, ex.in_edges.size)
    )
    mass = np.concatenate([ex.local(flat), np.ones((ex.n_local, 1))], axis=1)
    sent = np.zeros_like(mass)
    received = np.zeros((ex.in_edges.size, mass.shape[1]))
    active = np.zeros(ex.n_edges, bool)
    rate_local, rate_src = rate[nodes], rate[ex.in_src]
    yield PushSumState(0, mass.copy(), sent.copy(), received.copy(), np.zeros(ex.n_local, bool))
    for t in range(1, ticks + 1):
        acted = clock.acts(t, nodes, rate_local)
        # only ticking senders transmit: the edge mask over this block's out- and in-edges (senders' ticks are a
        # pure function of (seed, t, node), so a receiver knows them without a message)
        active[ex.out_edges] = acted[ex.out_src]
        active[ex.in_edges] = clock.acts(t, ex.in_src, rate_src)
        kept = mass[acted] * share[acted, None]
        sent[acted] += kept
        mass[acted] = kept
        inbox = ex.broadcast(sent, active=active)
        got = inbox.delivered & real_in
        delta = np.where(got[:, None], inbox.values - received, 0.0)
        received[got] = inbox.values[got]
        mass += to_receiver @ delta
        yield PushSumState(t, mass.copy(), sent.copy(), received.copy(), acted)


def mass_in_flight(state: PushSumState, exchange: Exchange) -> np.ndarray:
    """Mass pushed by the senders of this block's incoming edges and not yet received: ``Σ_(j→i) (σ_j − ρ_ji)``.

    Needs each sender's σ, so it is a monitoring value: in-process (one block) it is exact; under MPI it gathers the
    senders' running sums."""
    sent_all = exchange.gather_nodes(state.sent)
    real_in = exchange.in_src != exchange.nodes[exchange.in_dst]
    out: np.ndarray = (sent_all[exchange.in_src[real_in]] - state.received[real_in]).sum(axis=0)
    return out


@runs(iterate_push_sum, adds=("tol",))
def push_sum(
    values: np.ndarray,
    *,
    graph: Graph,
    ticks: int,
    clock: Clock = Clock(),
    tol: float = 1e-10,
    exchange: Exchange | None = None,
) -> PushSumResult:
    """Run running-sum push-sum until every node's ratio agrees within ``tol`` (relative) or ``ticks`` ticks.

    ``status`` is ``converged`` when, for every payload entry, ``max_i r_i − min_i r_i ≤ tol·(1 + max|r|)``
    (agreement; the invariant makes the common value the true average once the mass in flight is drained);
    otherwise ``max_iterations``. The agreement test is a monitoring reduction (``allreduce``), as in the other
    solvers' stopping rules. Trace per tick: ``spread``, ``max_abs_deviation`` (vs the true average) and
    ``mass_error`` (invariant violation).

    Examples
    --------
    Four nodes on a ring agree on the mean of their values (4.0):

    >>> import numpy as np
    >>> from distnav.algorithms.consensus.pushsum import push_sum
    >>> from distnav.network import builders
    >>> res = push_sum(np.array([1.0, 2.0, 3.0, 10.0]), graph=builders.ring(4), ticks=500)
    >>> res.converged, res.estimates.round(6).ravel().tolist()
    (True, [4.0, 4.0, 4.0, 4.0])
    """
    ticks = whole_number(ticks, "ticks", error=WeightsError)
    tol = real_number(tol, "tol", positive=True, error=WeightsError)
    flat = _node_values(values, graph.n_nodes)
    clock.per_node(graph.n_nodes)
    ex = exchange if exchange is not None else make_exchange(graph)
    mean = flat.mean(axis=0)
    total = np.concatenate([flat.sum(axis=0), [float(graph.n_nodes)]])
    scale = 1.0 + float(np.abs(total).max())
    tb = TraceBuilder()
    ticks_done = np.zeros(ex.n_local, np.int64)
    status: SolverStatus = "max_iterations"
    worst = 0.0
    last: PushSumState | None = None
    for state in iterate_push_sum(flat, graph=graph, ticks=ticks, clock=clock, exchange=ex):
        ticks_done += state.acted
        r = state.ratio
        hi = np.asarray(ex.allreduce(r.max(axis=0, initial=-np.inf), "max"))  # per payload entry
        lo = np.asarray(ex.allreduce(r.min(axis=0, initial=np.inf), "min"))
        spread = float((hi - lo).max())
        dev = float(ex.allreduce(np.abs(r - mean).max(initial=0.0), "max"))
        held = np.asarray(ex.allreduce(state.mass.sum(axis=0), "sum")) + mass_in_flight(state, ex)
        err = float(np.abs(held - total).max()) / scale
        worst = max(worst, err)
        tb.add(spread=spread, max_abs_deviation=dev, mass_error=err)
        last = state
        if state.tick > 0 and spread <= tol * (1.0 + float(np.abs(hi).max())):
            status = "converged"
            break
    assert last is not None
    final = ex.gather_nodes(last.ratio)
    return PushSumResult(
        estimates=final,
        converged=status == "converged",
        iterations=last.tick,
        status=status,
        message=f"{status} after {last.tick} ticks, spread {float(np.ptp(final, axis=0).max()):.3g}",
        trace=tb.build(),
        comm=ex.comm_totals(),
        average=mean,
        ticks_per_node=ex.gather_nodes(ticks_done),
        mass_error=worst,
    )


# --------------------------------------------------------------------------- one node on its own timer (field)
class PushSumLink(Protocol):
    """What a node running on its own timer needs from the network (no rounds, no barrier).

    ``post`` sends this node's running sum, stamped with its own tick count, to every out-neighbour without
    waiting; ``drain`` returns the ``(sender, tick, running_sum)`` messages that have arrived, waiting at most
    ``timeout_s`` for the first one. A message may be lost, late or overtaken: the running sums make that harmless.
    """

    def post(self, tick: int, running_sum: np.ndarray) -> None: ...

    def drain(self, timeout_s: float) -> list[tuple[int, int, np.ndarray]]: ...


@dataclass(frozen=True, eq=False)
class NodeOutcome:
    """How one node's asynchronous run ended: its ratio (estimate of the average), its own tick count, the final
    mass and running sum, and per in-neighbour the last tick whose running sum it used; ``refused`` counts
    messages not used (``stale``: an older running sum than one already used; ``shape``; ``not_a_neighbour``)."""

    ratio: np.ndarray
    ticks: int
    mass: np.ndarray
    sent: np.ndarray
    last_tick_from: dict[int, int]
    refused: dict[str, int] = field(default_factory=dict)


def run_push_sum_node(
    value: np.ndarray,
    *,
    out_degree: int,
    in_neighbours: list[int],
    link: PushSumLink,
    period_s: float,
    duration_s: float,
    now: Callable[[], float] = time.monotonic,
) -> NodeOutcome:
    """Running-sum push-sum (module docstring) at one node, ticking every ``period_s`` seconds of its own clock for
    ``duration_s`` seconds, with no barrier: between ticks it uses whatever running sums have arrived.

    A received running sum older than the last one used from that sender (reordered or replayed) is skipped: its
    mass is contained in the newer one already used. ``out_degree`` is the number of out-neighbours ``D_i``.
    """
    if not period_s > 0 or not duration_s > 0:
        raise WeightsError(f"period_s and duration_s must be > 0, got {period_s}, {duration_s}")
    mass = np.concatenate([np.asarray(value, dtype=float).reshape(-1), [1.0]])
    sent = np.zeros_like(mass)
    share = 1.0 / (int(out_degree) + 1.0)
    known = set(in_neighbours)
    received: dict[int, np.ndarray] = {}
    last: dict[int, int] = {}
    refused = {"stale": 0, "shape": 0, "not_a_neighbour": 0}
    start = now()
    end, next_tick, tick = start + duration_s, start, 0
    while (t := now()) < end:
        if t >= next_tick:
            tick += 1
            mass *= share
            sent += mass
            link.post(tick, sent.copy())
            next_tick = max(next_tick + period_s, t)  # a late timer does not make up ticks in a burst
        for sender, k, arr in link.drain(max(0.0, min(next_tick, end) - now())):
            reason = (
                "not_a_neighbour"
                if sender not in known
                else "shape"
                if arr.shape != mass.shape
                else "stale"
                if k <= last.get(sender, 0)
                else ""
            )
            if reason:
                refused[reason] += 1
                continue
            mass += arr - received.get(sender, 0.0)
            received[sender], last[sender] = arr, k
    return NodeOutcome(mass[:-1] / mass[-1], tick, mass, sent, last, refused)
