"""Consensus-based Kalman filter (CKF) and its error-variance recursion — paper 003 §4, Figs. 5–7.

Every node ``i`` runs its own information filter. At epoch ``t`` it computes its normals ``(N_i,t, r_i,t)``
(eq. (24)), runs ``k_n`` average-consensus rounds on them with its neighbours through the exchange (eq. (31),
any protocol of Table 1, static or switching graph), and updates (Fig. 6)::

    I_i,t|t = I_i,t|t−1 + n N_i,t^(k_n),      i_i,t|t = i_i,t|t−1 + n r_i,t^(k_n)

followed by the same time update as the information filter (Fig. 1, eqs. (19)–(21)). ``k_n`` follows from the
two time scales (Fig. 5): sampling interval ``Δ`` and sending interval ``δ``, ``k_n = ⌊Δ/δ⌋``
(Δ = 60 s, δ = 15, 10, 5 s → k_n = 4, 6, 12 in §5.2).

Error variance (Fig. 7, eqs. (41)–(45)): ``I_i,t|t⁻¹`` is *not* the error variance of ``x̂_i,t|t``; with
``L = W_(k_n)⋯W_(1)`` (eq. (33)) and ``l_ij`` its entries,
``P_i,t|t = I_i,t|t⁻¹ (I_i,t|t−1 P_i,t|t−1 I_i,t|t−1 + n² Σ_j l_ij² N_j,t) I_i,t|t⁻¹``,
``P_i,t|t−1 = Φ_t P_i,t−1|t−1 Φ_tᵀ + S_t``. distnav propagates the equivalent information-error variance
``Q_i = D(I_i x_t − i_i) = I_i P_i I_i`` (see :class:`distnav.algorithms.kalman.InformationKernel`), which stays finite
while ``I_i`` is still singular (BLUP start, unobserved entries); ``P_i = I_i⁺ Q_i I_i⁺`` on the estimable entries.
The extra term ``Σ_j l_ij² N_j,t`` is information no node has (the paper says so): it is assembled with
``ex.gather_nodes`` as an analysis quantity. :func:`ckf_error_variance` runs the recursion alone (no data, no
messages) as the a-priori design tool of §4.2.

Consensus sessions of a switching graph restart at session 0 every epoch, so every epoch uses the same ``L``.
With message faults the actual product differs from the nominal one; the CKF then carries the rows of ``L``
along in the consensus payload (paid for in bytes) so that Fig. 7 uses the product actually applied.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._settings import option_names, resolve_options, runs
from distnav.algorithms.consensus.averaging import ConsensusSchedule, consensus_product, consensus_schedule
from distnav.algorithms.kalman import (
    DynamicModel,
    FilterResult,
    FilterSeries,
    InformationKernel,
    MeasurementSeries,
    check_model,
    masked_std,
    pseudo_inverse_psd,
)
from distnav.algorithms.kalman.ckf_design import alpha_factor, ckf_error_variance, ckf_std_ratio, consensus_rounds
from distnav.algorithms.kalman.ckf_options import (
    CKFOptions,
    CKFRunOptions,
    ConsensusProtocol,
    LocalPrecision,
)
from distnav.algorithms.kalman.ckf_qc import (
    InnovationCollector,
    NodeEpochTest,
    innovation_test,
    local_extra_bound,
    local_extra_exact,
)
from distnav.algorithms.kalman.relay import RelayPlan, relay_setup, relayed_payload
from distnav.algorithms.result import Precision, TraceBuilder
from distnav.algorithms.statistics import critical_value
from distnav.errors import ModelError
from distnav.exchange import Exchange, Mixer, make_exchange
from distnav.exchange.core import CommTotals
from distnav.network.graph import Graph, SwitchingGraph
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = [
    "consensus_rounds",
    "alpha_factor",
    "CKFOptions",
    "CKFRunOptions",
    "CKFState",
    "iterate_ckf",
    "ckf",
    "ckf_error_variance",
    "ckf_std_ratio",
]


def _schedule(
    graph: Graph | SwitchingGraph | None, protocol: ConsensusProtocol, schedule: ConsensusSchedule | None, n_nodes: int
) -> ConsensusSchedule:
    if schedule is None:
        if graph is None:
            raise ModelError("give a graph (static or switching) or a consensus schedule")
        schedule = consensus_schedule(graph, protocol)
    if schedule.graph.n_nodes != n_nodes:
        raise ModelError(f"the graph has {schedule.graph.n_nodes} nodes, the measurements {n_nodes}")
    return schedule


def _triu(p: int) -> tuple[IntArray, IntArray]:
    return np.triu_indices(p)


def _symmetric(tri: FloatArray, up: IntArray, lo: IntArray, k: int, p: int) -> FloatArray:
    """Rebuild symmetric (k, p, p) matrices from their upper triangles (flat indices ``up``, mirror ``lo``): one
    gather by the position of every entry in the triangle (made once per ``p``)."""
    where = _TRI_POSITION.get(p)
    if where is None:
        where = np.empty(p * p, np.int64)
        where[lo] = np.arange(lo.size)
        where[up] = np.arange(up.size)
        _TRI_POSITION[p] = where
    out: FloatArray = tri[:, where].reshape(k, p, p)
    return out


_TRI_POSITION: dict[int, IntArray] = {}


@dataclass(frozen=True, eq=False)
class CKFState:
    """The CKF after the measurement update of ``epoch``, for this exchange block's nodes (rows).

    information, info_vector : ``I_i,t|t`` (k×p×p), ``i_i,t|t`` (k×p).
    estimates : ``x̂_i,t|t`` (NaN where not estimable); estimable : (k×p).
    covariance : ``P_i,t|t`` from Fig. 7 (k×p×p) or ``None`` without the variance recursion.
    local_covariance : the node-local ``P_i,t|t`` (exact or bound, :mod:`distnav.algorithms.kalman.ckf_qc`) or ``None``.
    tests : per local node, its innovation tests at this epoch (``None``: nothing tested); empty without tests.
    nominal_covariance : ``I_i,t|t⁺``. consensus_deviation : max over local nodes and entries of
    ``|N_i^(k_n) − N̄|``, ``|r_i^(k_n) − r̄|`` (monitoring).
    """

    epoch: int
    nodes: IntArray
    information: FloatArray
    info_vector: FloatArray
    estimates: FloatArray
    estimable: BoolArray
    covariance: FloatArray | None
    nominal_covariance: FloatArray
    consensus_deviation: float
    local_covariance: FloatArray | None = None
    tests: tuple[NodeEpochTest | None, ...] = ()


@dataclass(frozen=True, eq=False)
class _CKFSetup:
    """Everything :func:`iterate_ckf` fixes before the first epoch (validated options, mixers, index maps)."""

    ex: Exchange
    kn: int
    mixers: list[Mixer]
    p: int
    up: IntArray  # flat indices of the upper triangle of a p×p matrix
    lo: IntArray  # and of its mirror
    variance: bool
    monitor: bool
    local_precision: LocalPrecision | None
    critical: float | None
    track_L: bool
    L2_nominal: FloatArray | None
    relay: tuple[RelayPlan, FloatArray] | None
    n_err: int

    @property
    def n_tri(self) -> int:
        return int(self.up.size)


def _prepare_ckf(
    measurements: MeasurementSeries,
    graph: Graph | SwitchingGraph | None,
    exchange: Exchange | None,
    schedule: ConsensusSchedule | None,
    options: CKFOptions,
) -> _CKFSetup:
    """Build the mixers, the relay plan and the nominal ``L`` rows of this block from validated options."""
    kn = options.k_n
    n = measurements.n_nodes
    sched = _schedule(graph, options.protocol, schedule, n)
    ex = exchange if exchange is not None else make_exchange(sched.graph)
    if ex.graph.n_edges != sched.graph.n_edges or ex.graph.n_nodes != n:
        raise ModelError("the exchange was built on a different graph than the consensus schedule")
    variance, local_precision = bool(options.variance), options.local_precision
    critical = _critical_level(measurements, local_precision, options.test_level)
    relay = relay_setup(sched, ex, kn) if options.transport == "relay" else None
    mixers = (
        [] if relay is not None else [ex.mixer(w, active=a) for w, a in zip(sched.weights, sched.active, strict=True)]
    )
    L_nominal = consensus_product(sched, kn) if (variance and not ex.faults.active) else None
    iu = _triu(measurements.n_states)
    p = measurements.n_states
    return _CKFSetup(
        ex=ex,
        kn=kn,
        mixers=mixers,
        p=p,
        up=iu[0] * p + iu[1],
        lo=iu[1] * p + iu[0],
        variance=variance,
        monitor=bool(options.monitor),
        local_precision=local_precision,
        critical=critical,
        track_L=(variance and ex.faults.active) or local_precision is not None,
        L2_nominal=L_nominal[ex.nodes] ** 2 if L_nominal is not None else None,  # once, not every epoch
        relay=relay,
        n_err=int(variance) + int(local_precision is not None),
    )


def _critical_level(
    measurements: MeasurementSeries, local_precision: LocalPrecision | None, test_level: float | None
) -> float | None:
    """The innovation tests' critical value, or a :class:`ModelError` when they cannot run."""
    if test_level is None:
        return None
    if local_precision is None:
        raise ModelError(
            "innovation tests need the node-local precision: give local_precision='exact' or 'bound' with test_level"
        )
    if type(measurements).observations is MeasurementSeries.observations:
        raise ModelError(
            f"innovation tests need the raw observations; {type(measurements).__name__} holds "
            f"normal equations only (use an ObservationSeries)"
        )
    return critical_value(test_level)


def iterate_ckf(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    graph: Graph | SwitchingGraph | None = None,
    exchange: Exchange | None = None,
    schedule: ConsensusSchedule | None = None,
    options: CKFOptions | None = None,
    **changes: Any,
) -> Iterator[CKFState]:
    """Yield the CKF state (paper 003 Fig. 6) of this block's nodes after every epoch; options
    :class:`~distnav.algorithms.kalman.ckf_options.CKFOptions` (``options=`` and/or keyword changes to it, validated
    before the first epoch).

    Each consensus round sends one message per directed edge holding the upper triangle of ``N_i^(k)`` and
    ``r_i^(k)`` (p(p+1)/2 + p floats). ``local_precision`` ("exact" or "bound") runs the node-local form of Fig. 7
    from the messages alone (:mod:`distnav.algorithms.kalman.ckf_qc`; it adds ``n (p(p+1)/2 + 1)`` resp. ``n``
    floats to every message). ``test_level`` makes every node test its predicted residuals at that level and reject
    outliers before they enter its consensus.

    ``transport="relay"`` (static graph, no faults, a series with :meth:`~MeasurementSeries.records`): the same
    ``k_n`` consensus rounds evaluated by every node from the raw observation records of the nodes within ``k_n``
    hops, relayed hop by hop (20 B per record; :mod:`distnav.algorithms.kalman.relay`) instead of the mixed
    matrices: the same filter (to the rounding of the sums) for far fewer bytes when a node's observations are
    fewer than its normals' entries (issue 27). Node-local precision then costs no bytes (``l_i`` is static, the
    ``N_j`` are rebuilt from the records); an observation an innovation test removed is not sent.
    """
    o = resolve_options(CKFOptions, options, changes)
    check_model(dynamics, measurements)
    s = _prepare_ckf(measurements, graph, exchange, schedule, o)
    ex, nodes = s.ex, s.ex.nodes
    ker = InformationKernel(nodes.size, s.p, track_error=s.n_err > 0, n_errors=max(s.n_err, 1))
    i_local = int(s.variance)  # index of the node-local variance in ker.Qs
    for t in range(measurements.n_epochs):
        if t > 0:
            ker.time_update(dynamics, t)
        N, r = measurements.normals(t, nodes)
        tests: tuple[NodeEpochTest | None, ...] = ()
        if s.critical is not None:
            N, r, tests = _tested_normals(ker, measurements, t, nodes, N, r, i_local, s.critical)
        tri = N.reshape(nodes.size, s.p * s.p)[:, s.up]
        payload = _consensus(s, measurements, t, tri, r, tests)
        Nk = _symmetric(payload[:, : s.n_tri], s.up, s.lo, nodes.size, s.p)
        rk = payload[:, s.n_tri : s.n_tri + s.p]
        _measurement_update(s, ker, payload, tri, Nk, rk)
        dev = _consensus_deviation(ex, N, r, Nk, rk) if s.monitor else 0.0
        x, est, inv, P = ker.estimates()
        P_local = ker.error_covariance(inv, i_local) if s.local_precision is not None else None
        yield CKFState(t, nodes, ker.I, ker.i, x, est, P if s.variance else None, inv, dev, P_local, tests)


def _consensus(
    s: _CKFSetup,
    measurements: MeasurementSeries,
    t: int,
    tri: FloatArray,
    r: FloatArray,
    tests: tuple[NodeEpochTest | None, ...],
) -> FloatArray:
    """The payload after the epoch's ``k_n`` rounds: ``[tri(N^(k_n)), r^(k_n)]``, then (when tracked) the rows of
    ``L`` and, for the exact node-local precision, the tagged normals."""
    if s.relay is not None:
        return _relayed_consensus(s, measurements, t, tests)
    nodes = s.ex.nodes
    n, k_loc = measurements.n_nodes, nodes.size
    parts = [tri, r]
    if s.track_L:
        parts.append(np.eye(n)[nodes])
    if s.local_precision == "exact":
        tagged = np.zeros((k_loc, n, s.n_tri))
        tagged[np.arange(k_loc), nodes] = tri
        parts.append(tagged.reshape(k_loc, n * s.n_tri))
    payload = np.concatenate(parts, axis=1)
    for k in range(s.kn):
        payload = s.mixers[k % len(s.mixers)].apply(payload)
    return payload


def _measurement_update(
    s: _CKFSetup, ker: InformationKernel, payload: FloatArray, tri: FloatArray, Nk: FloatArray, rk: FloatArray
) -> None:
    """Fig. 6's update with ``n N^(k_n)``, ``n r^(k_n)`` and Fig. 7's extra terms (gathered and/or node-local)."""
    ex, n_tri, p = s.ex, s.n_tri, s.p
    n, k_loc = ex.n_nodes, ex.nodes.size
    extra = None
    L_mixed = payload[:, n_tri + p : n_tri + p + n] if s.track_L else None
    if s.variance:
        if L_mixed is not None and ex.faults.active:
            L2_rows = L_mixed**2
        else:
            assert s.L2_nominal is not None
            L2_rows = s.L2_nominal
        N_all = ex.gather_nodes(tri)  # analysis input of Fig. 7 (no node has it)
        extra = _symmetric((n * n) * (L2_rows @ N_all), s.up, s.lo, k_loc, p)
    if s.local_precision is None:
        ker.measurement_update(Nk, rk, scale=float(n), extra_error=extra)
        return
    assert L_mixed is not None
    if s.local_precision == "exact":
        E = local_extra_exact(L_mixed, payload[:, n_tri + p + n :].reshape(k_loc, n, n_tri))
    else:
        E = local_extra_bound(L_mixed, payload[:, :n_tri])
    local_extra = _symmetric((n * n) * E, s.up, s.lo, k_loc, p)
    ker.measurement_update(Nk, rk, scale=float(n), extra_errors=[extra, local_extra][-s.n_err :])


def _consensus_deviation(ex: Exchange, N: FloatArray, r: FloatArray, Nk: FloatArray, rk: FloatArray) -> float:
    """``max |N_i^(k_n) − N̄|, |r_i^(k_n) − r̄|`` over the network (global reductions: monitoring only)."""
    n = ex.n_nodes
    Nbar = ex.allreduce(N.sum(axis=0), "sum") / n
    rbar = ex.allreduce(r.sum(axis=0), "sum") / n
    loc = max(float(np.abs(Nk - Nbar).max(initial=0.0)), float(np.abs(rk - rbar).max(initial=0.0)))
    return float(ex.allreduce(loc, "max"))


def _relayed_consensus(
    s: _CKFSetup, measurements: MeasurementSeries, t: int, tests: tuple[NodeEpochTest | None, ...]
) -> FloatArray:
    """The matrix transport's payload from the relayed records (:func:`~distnav.algorithms.kalman.relay.
    relayed_payload`); an observation an innovation test removed is not sent (its record's weight is 0)."""
    assert s.relay is not None
    plan, L_rows = s.relay
    values, weights = measurements.records(t, s.ex.nodes)
    for a, test in enumerate(tests):
        if test is not None and test.removed:
            weights[a, measurements.record_slots(t, s.ex.nodes[a : a + 1])[~test.keep]] = 0.0
    return relayed_payload(
        s.ex,
        plan,
        L_rows,
        measurements,
        t,
        values,
        weights,
        s.up,
        with_rows=s.track_L,
        tagged=s.local_precision == "exact",
    )


def _tested_normals(
    ker: InformationKernel,
    measurements: MeasurementSeries,
    t: int,
    nodes: IntArray,
    N: FloatArray,
    r: FloatArray,
    i_local: int,
    critical: float,
) -> tuple[FloatArray, FloatArray, tuple[NodeEpochTest | None, ...]]:
    """Innovation tests of every local node at epoch ``t`` (after the time update); normals of the kept rows."""
    A, y, row_node = measurements.observations(t, nodes)
    tests: list[NodeEpochTest | None] = [None] * nodes.size
    if t == 0:  # no prediction yet (BLUP start): nothing to test against
        return N, r, tuple(tests)
    inv, est = pseudo_inverse_psd(ker.I)
    x_pred = (inv @ ker.i[..., None])[..., 0]
    P_pred = ker.error_covariance(inv, i_local)
    N, r = N.copy(), r.copy()
    for a, node in enumerate(nodes):
        rows = np.flatnonzero(row_node == node)
        if rows.size == 0:
            continue
        res = innovation_test(A[rows], y[rows], x_pred[a], P_pred[a], est[a], critical)
        tests[a] = res
        if res.removed:
            Ak, yk = A[rows][res.keep], y[rows][res.keep]
            N[a] = Ak.T @ Ak
            r[a] = Ak.T @ yk
    return N, r, tuple(tests)


@runs(iterate_ckf)
def ckf(
    dynamics: DynamicModel,
    measurements: MeasurementSeries,
    *,
    graph: Graph | SwitchingGraph | None = None,
    exchange: Exchange | None = None,
    schedule: ConsensusSchedule | None = None,
    options: CKFOptions | None = None,
    **changes: Any,
) -> FilterResult:
    """Run the CKF (paper 003 Fig. 6) over all epochs; options
    :class:`~distnav.algorithms.kalman.ckf_options.CKFRunOptions` (those of :func:`iterate_ckf` plus
    ``store_matrices``; ``options=`` and/or keyword changes to it — a :class:`CKFOptions` keeps no matrices).

    Returns a :class:`FilterResult` (``mode="ckf"``): ``estimates`` = last-epoch ``x̂_i,t|t`` (n×p),
    ``iterations`` = epochs, ``comm`` = message/byte totals of all consensus rounds, ``series``
    (:class:`FilterSeries` over all nodes: ``std`` from Fig. 7, ``nominal_std`` = sqrt diag ``I_i⁻¹``; with
    ``store_matrices`` also ``covariance`` = ``P_i,t|t`` and ``information`` = ``I_i,t|t`` for every epoch),
    ``information``, ``info_vector``, ``covariance`` (last epoch), ``rounds`` (k_n), ``product`` (``L``) and
    ``alpha`` (with ``variance`` only). Trace: ``consensus_deviation`` per epoch. With ``local_precision`` also
    ``precision`` (:class:`~distnav.algorithms.result.Precision` of the last epoch, with the bytes it cost) and
    ``local_std`` (T, n, p); with ``test_level`` also ``tests`` (:class:`~distnav.algorithms.kalman.InnovationTests`).

    Memory: the per-epoch series are (T, n, p) arrays, and the variance recursion needs the dense n×n ``L`` and
    ``Σ_j l_ij² N_j`` (O(n² p²) work per epoch): for very large networks iterate with :func:`iterate_ckf` and
    ``variance=False``. Per-node results are in the user's node order at every size (without ``exchange`` the run
    keeps the locality order ``"auto"`` inside and gathers back; docs/scale.md).

    Examples
    --------
    Three nodes observe a slowly drifting scalar once per epoch. On a complete graph one round with the weights
    ``1/n`` (P2) is the exact average, so every node's filter equals the central one (paper 003 §4):

    >>> import numpy as np
    >>> from distnav.algorithms.kalman import DynamicModel, ObservationSeries, central_filter
    >>> from distnav.algorithms.kalman.ckf import ckf
    >>> from distnav.network import builders
    >>> rng = np.random.default_rng(1)
    >>> dyn = DynamicModel(1, noise_cov=np.array([[0.01]]))
    >>> epochs = [[(np.ones((1, 1)), np.ones(1), rng.normal(5.0, 1.0, 1)) for _ in range(3)] for _ in range(4)]
    >>> series = ObservationSeries(1, epochs)
    >>> res = ckf(dyn, series, graph=builders.complete(3), protocol="P2", rounds=1)
    >>> bool(np.allclose(res.estimates, central_filter(dyn, series).estimates))
    True
    >>> res.rounds, res.comm.messages  # 4 epochs × 1 round × 6 directed links
    (1, 24)
    """
    o = resolve_options(CKFRunOptions, _run_options(options), changes)
    kn = o.k_n
    run = dataclasses.replace(o, rounds=kn, sampling_interval_s=None, sending_interval_s=None)
    n = measurements.n_nodes
    sched = _schedule(graph, o.protocol, schedule, n)
    ex = exchange if exchange is not None else make_exchange(sched.graph, order="auto")  # results gathered
    test_level = o.test_level
    collector = InnovationCollector(ex, n, test_level, critical_value(test_level)) if test_level is not None else None
    kept = _GatheredSeries(ex, bool(o.store_matrices))
    last: CKFState | None = None
    for st in iterate_ckf(dynamics, measurements, exchange=ex, schedule=sched, options=run):
        kept.add(st)
        if collector is not None:
            collector.add(st.tests)
        last = st
    assert last is not None
    return _filter_result(measurements, ex, sched, o, kept, collector, last)


def _filter_result(
    measurements: MeasurementSeries,
    ex: Exchange,
    sched: ConsensusSchedule,
    o: CKFRunOptions,
    kept: _GatheredSeries,
    collector: InnovationCollector | None,
    last: CKFState,
) -> FilterResult:
    """:func:`ckf`'s result, assembled from its epochs (``kept``: gathered, ``collector``: their innovation tests,
    ``last``: the last epoch's state): the series, the last epoch's information, the consensus product ``L`` and
    ``α`` (with ``o.variance``), the local precision and the tests."""
    kn = o.k_n
    n = measurements.n_nodes
    variance = bool(o.variance)
    L = consensus_product(sched, kn) if variance else None  # dense n×n: only with the variance recursion
    series = kept.series(n)
    comm: CommTotals = ex.comm_totals()
    est_last = series.estimable[-1]
    complete = bool(est_last.all())
    return FilterResult(
        estimates=series.estimates[-1],
        converged=complete,
        iterations=measurements.n_epochs,
        status="converged" if complete else "stopped",
        message=(
            f"CKF over {measurements.n_epochs} epochs with k_n = {kn} consensus rounds each; "
            f"{int(est_last.sum())}/{est_last.size} node-entries estimable at the last epoch"
        ),
        trace=kept.trace.build(),
        comm=comm,
        series=series,
        mode="ckf",
        information=ex.gather_nodes(last.information),
        info_vector=ex.gather_nodes(last.info_vector),
        covariance=ex.gather_nodes(last.covariance) if last.covariance is not None else None,
        rounds=kn,
        product=L,
        alpha=alpha_factor(L) if L is not None else None,
        precision=_local_precision(
            ex, last, o.local_precision, comm, measurements.n_states, variance, o.transport == "relay"
        ),
        local_std=np.stack(kept.lstds) if kept.lstds else None,
        tests=collector.build() if collector is not None else None,
    )


def _run_options(options: CKFOptions | None) -> CKFRunOptions | None:
    """``options`` as a :class:`CKFRunOptions` (a :class:`CKFOptions` keeps no matrices)."""
    if options is None or isinstance(options, CKFRunOptions):
        return options
    if isinstance(options, CKFOptions):
        return CKFRunOptions(**{name: getattr(options, name) for name in option_names(CKFOptions)})
    return options  # not an options object: refused by name in resolve_options


class _GatheredSeries:
    """The per-epoch arrays :func:`ckf` keeps, gathered over every node in the user's order."""

    def __init__(self, ex: Exchange, store_matrices: bool) -> None:
        self.ex, self.store = ex, store_matrices
        self.xs: list[FloatArray] = []
        self.stds: list[FloatArray] = []
        self.nstds: list[FloatArray] = []
        self.ests: list[BoolArray] = []
        self.covs: list[FloatArray] = []
        self.infos: list[FloatArray] = []
        self.lstds: list[FloatArray] = []
        self.trace = TraceBuilder()

    def add(self, st: CKFState) -> None:
        g = self.ex.gather_nodes
        self.xs.append(g(st.estimates))
        if st.local_covariance is not None:
            self.lstds.append(g(masked_std(st.local_covariance, st.estimable)))
        self.ests.append(g(st.estimable))
        self.nstds.append(g(masked_std(st.nominal_covariance, st.estimable)))
        if st.covariance is not None:
            self.stds.append(g(masked_std(st.covariance, st.estimable)))
        if self.store:
            self.infos.append(g(st.information))
            if st.covariance is not None:
                self.covs.append(g(st.covariance))
        self.trace.add(consensus_deviation=st.consensus_deviation)

    def series(self, n: int) -> FilterSeries:
        nominal = np.stack(self.nstds)
        return FilterSeries(
            estimates=np.stack(self.xs),
            std=np.stack(self.stds) if self.stds else np.full_like(nominal, np.nan),
            estimable=np.stack(self.ests),
            nodes=np.arange(n),
            nominal_std=nominal,
            covariance=np.stack(self.covs) if self.covs else None,
            information=np.stack(self.infos) if self.infos else None,
        )


def _local_precision(
    ex: Exchange, last: CKFState, kind: LocalPrecision | None, comm: CommTotals, p: int, variance: bool, relay: bool
) -> Precision | None:
    """The node-local :class:`Precision` of the last epoch; ``comm`` = the bytes it added to the messages (none with
    the relay transport: the records are sent anyway, the rows of ``L`` are static knowledge)."""
    if kind is None or last.local_covariance is None:
        return None
    n = ex.n_nodes
    n_tri = p * (p + 1) // 2
    base = n_tri + p + (n if (variance and ex.faults.active) else 0)
    width = n_tri + p + n + (n * n_tri if kind == "exact" else 0)
    share = 0.0 if relay else (width - base) / width
    extra = CommTotals(
        0,
        np.zeros_like(comm.messages_sent),
        np.rint(comm.bytes_sent * share).astype(np.int64),
        np.zeros_like(comm.messages_received),
        np.rint(comm.bytes_received * share).astype(np.int64),
        np.zeros_like(comm.messages_per_round),
        np.rint(comm.bytes_per_round * share).astype(np.int64),
    )
    return Precision(
        covariance=ex.gather_nodes(last.local_covariance),
        variance_factor=None,
        redundancy=float("nan"),
        kind=kind,
        iterations=0,
        comm=extra,
    )
