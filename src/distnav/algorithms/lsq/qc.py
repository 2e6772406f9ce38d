"""Distributed precision and data snooping for least squares by ADMM (issue 12; paper 000 §6's open questions).

**Precision.** The covariance of the BLUE is ``Q_x̂ = N⁻¹``, ``N = Σ_i N_i``: the solution ``X`` of
``Σ_i N_i X = I``. That is again a sum of per-node quadratic problems, ``min Σ_i ½ tr(Xᵀ N_i X) − tr(B_iᵀ X)`` with
any split ``Σ_i B_i = I``, so the same constraint-node ADMM (Fig. 6, :mod:`distnav.algorithms.lsq.kernel`) solves
it for all ``p`` columns at once: node ``i`` holds ``X_i`` (``p × p``), its x-update is the normal-equation form
``X_i = (N_i + c_i W)⁻¹ (B_i + c_i W L_i)`` (eq. (20) with a matrix right-hand side), and every message carries
``p²`` numbers instead of ``p``. The split is ``B_i = I/n`` (``n`` from the same consensus as below), so no node is
special for the covariance and the optimal multipliers ``W⁻¹(B_i − N_i N⁻¹)`` stay of the size of the estimate's.

**Variance factor.** ``σ̂² = Σ_i ê_iᵀR_i⁻¹ê_i / (Σ_i m_i − p)``: each node computes its own weighted residual sum of
squares with its own estimate ``x_i`` and its number of observations ``m_i``; the network averages
``(s_i, m_i, δ_{i,0})`` by the same ADMM (``N_i = I``, whose solution is the mean), and since the mean of the
indicator ``δ_{i,0}`` of node 0 is ``1/n``, every node obtains the sums as ``mean(s)/mean(δ)``. Nothing is gathered;
ADMM (not plain average consensus) because its per-pair form keeps its fixed point when messages are lost.

**Data snooping.** Node ``i`` tests its own observations with ``w_j = (R_i⁻¹ê_i)_j / sqrt((R_i⁻¹ Q_ê,i R_i⁻¹)_jj)``,
``Q_ê,i = R_i − A_i Q_x̂ A_iᵀ`` (the residual covariance needs only its own block, since ``R`` is block diagonal
over nodes, and ``Q_x̂`` from the precision above). The largest ``|w|`` above the critical value is found by
max-flooding (diameter message rounds), its owner drops the observation, and estimate and precision re-converge
from their previous values (warm start) until nothing is flagged. Equal to
:func:`distnav.algorithms.statistics.data_snooping` on the same data (tests); departure: an observation whose
redundancy number ``(R_i⁻¹Q_ê,i)_jj`` is below ``1e-6`` counts as uncheckable (w = NaN) — the distributed ``Q_x̂``
is exact only to the stopping tolerance, so the centralized floor (1e-12 of the largest variance) would test
rounding noise.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse.csgraph as csgraph

from distnav._checks import check_field_types
from distnav._settings import resolve_options
from distnav.algorithms.lsq import driver as driver
from distnav.algorithms.lsq.blue import LinearProblem, weight_matrix
from distnav.algorithms.lsq.driver import AdmmResult, PreparedRun, drive
from distnav.algorithms.lsq.kernel import _Kernel
from distnav.algorithms.result import ObservationTests, Precision
from distnav.algorithms.statistics import critical_value, w_statistics
from distnav.errors import ModelError
from distnav.exchange import Exchange, FaultSchedule, make_exchange
from distnav.network.constraint_nodes import ConstraintNodes
from distnav.network.graph import Graph
from distnav.typing import BoolArray, FloatArray

__all__ = [
    "MIN_REDUNDANCY_NUMBER",
    "PrecisionOptions",
    "PrecisionRun",
    "SnoopingOptions",
    "admm_data_snooping",
    "admm_precision",
    "remove_observation",
]

MIN_REDUNDANCY_NUMBER = 1e-6


class _NormalXUpdate:
    """``X_i = (N_i + c_i W)⁻¹ (B_i + c_i W L_i)`` for ``X_i`` ``(p, k)`` flattened row-major to ``p·k``."""

    def __init__(self, N: FloatArray, B: FloatArray, W: FloatArray, c: FloatArray) -> None:
        cW = c[:, None, None] * W[None]
        M = np.linalg.inv(N + cW)
        self.MB = M @ B
        self.MW = M @ cW
        self.p, self.k = B.shape[1], B.shape[2]

    def __call__(self, l: np.ndarray, x_prev: np.ndarray) -> np.ndarray:
        X: np.ndarray = self.MB + self.MW @ l.reshape(-1, self.p, self.k)
        return X.reshape(-1, self.p * self.k)


def _normal_run(
    ex: Exchange,
    C: ConstraintNodes,
    N: FloatArray,
    B: FloatArray,
    W: FloatArray,
    init: AdmmResult | None,
    stop: PrecisionOptions,
    *,
    reference: FloatArray | None = None,
) -> AdmmResult:
    """Fig. 6 on ``min Σ_i ½ tr(Xᵀ N_i X) − tr(B_iᵀ X)`` for this block's ``N`` ``(nl, p, p)``, ``B`` ``(nl, p, k)``."""
    p, k = B.shape[1], B.shape[2]
    count = C.per_node_count[ex.nodes].astype(float)
    W_big = np.kron(W, np.eye(k))
    kernel = _Kernel(ex, C, W_big, p * k, _NormalXUpdate(N, B, W, count))
    if init is None:
        x0 = np.zeros((ex.n_local, p * k))
        z0 = x0
    else:
        x0 = init.estimates[ex.nodes]
        z0 = init.z_nodes[ex.nodes]
    u0 = None if init is None else init.multipliers
    run = PreparedRun(
        states=kernel.run(x0, z0, u0=u0),
        exchange=ex,
        constraint_nodes=C,
        p=p * k,
        x_update="normal equations (matrix right-hand side)",
        x_weight="lagrangian",
        messages="pairs",
        kernel=kernel,
    )
    return drive(run, stop, reference=None if reference is None else reference.ravel())


@dataclass(frozen=True, eq=False)
class PrecisionRun:
    """The precision of every node and the ADMM runs behind it (``covariance_run`` warm-starts the next one)."""

    precision: Precision
    covariance_run: AdmmResult
    sums_run: AdmmResult
    variance_factor_nodes: FloatArray


@dataclass(frozen=True, eq=False, kw_only=True)
class PrecisionOptions(driver.ConstraintOptions):
    """Options of :func:`admm_precision` (house style: :mod:`distnav._settings`; default in brackets):
    ``constraint_nodes`` and ``W`` as for :func:`~distnav.algorithms.lsq.admm.admm` (the same ρ suits both: the same
    ``N_i``), and

    Fields
    ------
    max_iterations : [5000] the stopping rule of each of the two runs (sums and covariance),
    tol : [1e-12] its relative tolerance,
    atol : [0.0] and its absolute tolerance.
    """

    max_iterations: int = 5000
    tol: float = 1e-12
    atol: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        driver.check_stopping(self.max_iterations, self.tol, self.atol)


@dataclass(frozen=True, eq=False, kw_only=True)
class SnoopingOptions(driver.AdmmOptions):
    """Options of :func:`admm_data_snooping`: the kernel's :class:`~distnav.algorithms.lsq.driver.AdmmOptions`
    plus (default in brackets)

    Fields
    ------
    level : [0.001] significance level of each w-test (two-sided, :func:`~distnav.algorithms.statistics.
        critical_value`).
    max_removals : [None: until nothing is flagged] at most that many observations removed.
    max_iterations : [5000] the stopping rule of every estimate and precision run,
    tol : [1e-12] its relative tolerance,
    atol : [0.0] and its absolute tolerance.
    """

    level: float = 0.001
    max_removals: int | None = None
    max_iterations: int = 5000
    tol: float = 1e-12
    atol: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        driver.check_stopping(self.max_iterations, self.tol, self.atol)


def admm_precision(
    problem: LinearProblem,
    graph: Graph,
    estimates: FloatArray,
    *,
    active: BoolArray | None = None,
    init: PrecisionRun | None = None,
    reference_covariance: FloatArray | None = None,
    exchange: Exchange | None = None,
    faults: FaultSchedule | None = None,
    options: PrecisionOptions | None = None,
    **changes: Any,
) -> PrecisionRun:
    """Each node's covariance block ``Q_x̂ = N⁻¹`` and the a-posteriori variance factor, by message rounds only;
    options :class:`PrecisionOptions` (``options=`` and/or keyword changes to it).

    ``estimates`` ``(n, p)``: every node's converged ``x_i`` (e.g. ``admm(...).estimates``; a node reads its own
    row). ``active`` ``(n, m)``: observations still in the model (default: the problem's rows).
    ``init``: a previous :class:`PrecisionRun` to warm-start from (data snooping). ``reference_covariance``
    ``(p, p)``: the centralized ``N⁻¹``, for the trace and ``iterations_to`` of ``covariance_run`` only.
    The result's :class:`~distnav.algorithms.result.Precision` has ``kind="exact"`` (equal to the centralized value
    up to the stopping tolerance), the iterations and messages of both runs; the variance factor is node 0's
    (``variance_factor_nodes`` holds every node's, equal to the tolerance).

    Examples
    --------
    The three nodes of :func:`~distnav.algorithms.lsq.admm.admm`'s example: each node learns ``N⁻¹`` with
    ``N = [[2, 1], [1, 2]]``, i.e. ``[[2, −1], [−1, 2]]/3``, and ``σ̂² = 0.03/(3 − 2)`` (three residuals of size 0.1):

    >>> import numpy as np
    >>> from distnav.algorithms.lsq.admm import admm
    >>> from distnav.algorithms.lsq.blue import LinearProblem
    >>> from distnav.algorithms.lsq.qc import admm_precision
    >>> from distnav.network import builders
    >>> A = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 1.0]])]
    >>> problem = LinearProblem.from_blocks(A, [np.array([1.0]), np.array([2.0]), np.array([3.3])])
    >>> est = admm(problem, builders.path(3), max_iterations=2000, tol=1e-12).estimates
    >>> run = admm_precision(problem, builders.path(3), est)
    >>> bool(np.allclose(run.precision.covariance, np.array([[2.0, -1.0], [-1.0, 2.0]]) / 3))
    True
    >>> round(run.precision.variance_factor, 9), run.precision.redundancy
    (0.03, 1.0)
    """
    o = resolve_options(PrecisionOptions, options, changes)
    if exchange is not None and faults is not None:
        raise ModelError("pass faults either to the exchange or to admm_precision(), not both")
    x_all = _check_precision_inputs(problem, graph, estimates, reference_covariance)
    p = problem.n_params
    Wm = weight_matrix(o.W, p)
    C = driver.constraint_nodes_for(graph, o.constraint_nodes)
    ex = exchange if exchange is not None else make_exchange(graph, faults=faults)
    before = ex.comm_totals().snapshot()
    local = problem.subset(ex.nodes)
    act = _active_rows(problem, active)[ex.nodes]
    sums = _normal_run(ex, C, *_sums_inputs(local, x_all[ex.nodes], act, ex.nodes), np.eye(3), _prev(init, "sums"), o)
    n_est, redundancy, vf = _variance_factor(sums.estimates, p)
    B = np.broadcast_to(np.eye(p), (ex.nodes.size, p, p)) * (1.0 / n_est[ex.nodes])[:, None, None]
    cov = _normal_run(ex, C, local.normal_equations[0], B, Wm, _prev(init, "cov"), o, reference=reference_covariance)
    Q = cov.estimates.reshape(problem.n_nodes, p, p)
    precision = Precision(
        covariance=0.5 * (Q + np.swapaxes(Q, 1, 2)),
        variance_factor=None if not np.isfinite(vf[0]) else float(vf[0]),
        redundancy=float(redundancy[0]),
        kind="exact",
        iterations=sums.iterations + cov.iterations,
        comm=ex.comm_totals().since(before),
    )
    return PrecisionRun(precision=precision, covariance_run=cov, sums_run=sums, variance_factor_nodes=vf)


def _check_precision_inputs(
    problem: LinearProblem, graph: Graph, estimates: FloatArray, reference_covariance: FloatArray | None
) -> FloatArray:
    """The estimates as an ``(n, p)`` float array, or a :class:`ModelError` naming the mismatch."""
    n, p = problem.n_nodes, problem.n_params
    if problem.n_nodes != graph.n_nodes:
        raise ModelError(f"the problem has {problem.n_nodes} nodes, the graph {graph.n_nodes}")
    x_all = np.asarray(estimates, dtype=float)
    if x_all.shape != (n, p):
        raise ModelError(f"estimates must be ({n}, {p}) (one x_i per node), got shape {x_all.shape}")
    if reference_covariance is not None and np.shape(reference_covariance) != (p, p):
        raise ModelError(f"reference_covariance must be ({p}, {p}), got shape {np.shape(reference_covariance)}")
    return x_all


def _sums_inputs(
    local: LinearProblem, x_local: FloatArray, act: BoolArray, nodes: np.ndarray
) -> tuple[FloatArray, FloatArray]:
    """``(N, B)`` of the network mean of each node's weighted SSR with its own estimate, its observation count and
    the indicator of node 0 (so every node learns n as 1/mean)."""
    e = local.y - np.einsum("nmp,np->nm", local.A, x_local)
    ssr = np.einsum("nm,nmk,nk->n", e, local.R_inv, e)
    values = np.stack([ssr, act.sum(axis=1).astype(float), (nodes == 0).astype(float)], axis=1)
    return np.broadcast_to(np.eye(3), (nodes.size, 3, 3)), values[:, :, None]


def _variance_factor(mean: FloatArray, p: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per node from the network means: the node count, the redundancy ``Σ m_i − p`` and the variance factor."""
    n_est = 1.0 / mean[:, 2]
    weighted_ssr = mean[:, 0] * n_est
    redundancy = np.rint(mean[:, 1] * n_est) - p  # an integer: Σ m_i − rank A (= p, admm() refuses less)
    vf = np.where(redundancy > 0, weighted_ssr / np.maximum(redundancy, 1.0), np.nan)
    return n_est, redundancy, vf


def _prev(init: PrecisionRun | None, which: str) -> AdmmResult | None:
    if init is None:
        return None
    return init.sums_run if which == "sums" else init.covariance_run


def _active_rows(problem: LinearProblem, active: BoolArray | None) -> BoolArray:
    rows = np.arange(problem.max_rows)[None, :] < problem.rows[:, None]
    if active is None:
        return rows
    act = np.asarray(active, dtype=bool)
    if act.shape != rows.shape:
        raise ModelError(f"active must be {rows.shape} (nodes × rows), got {act.shape}")
    return act & rows


def remove_observation(problem: LinearProblem, node: int, row: int) -> LinearProblem:
    """The problem without observation ``row`` of ``node``: its design row and observation become 0 and its row
    and column of ``R_i`` a unit vector, so it contributes nothing (the other observations keep their covariance)."""
    A, y, R = problem.A.copy(), problem.y.copy(), problem.R.copy()
    A[node, row] = 0.0
    y[node, row] = 0.0
    R[node, row, :] = 0.0
    R[node, :, row] = 0.0
    R[node, row, row] = 1.0
    return LinearProblem(
        A=A, y=y, R=R, rows=problem.rows, parameter_names=problem.parameter_names, node_names=problem.node_names
    )


def _local_w(local: LinearProblem, x: FloatArray, Q: FloatArray, act: BoolArray) -> FloatArray:
    """w-statistics of this block's observations (NaN for removed, padded and uncheckable ones)."""
    e = local.y - np.einsum("nmp,np->nm", local.A, x)
    Ri = local.R_inv
    Qe = local.R - np.einsum("nmp,npq,nkq->nmk", local.A, Q, local.A)
    v = np.einsum("nmk,nk->nm", Ri, e)
    q = np.einsum("nij,njk,nki->ni", Ri, Qe, Ri)
    r_num = np.einsum("nij,nji->ni", Ri, Qe)  # redundancy numbers (R⁻¹ Q_ê)_jj
    q = np.where(act & (r_num > MIN_REDUNDANCY_NUMBER), q, 0.0)
    return w_statistics(v, q, relative_floor=0.0)


def _flood_max(ex: Exchange, key: FloatArray, rounds: int) -> FloatArray:
    """Every node ends with the largest ``(value, id)`` row of the network after ``rounds`` broadcast rounds (a
    lost message leaves the receiver's value unchanged for that round)."""
    best = key.copy()
    for _ in range(rounds):
        inbox = ex.broadcast(best)
        ok = inbox.delivered
        vals, dst = inbox.values[ok], inbox.dst[ok]
        top = best[:, 0].copy()
        np.maximum.at(top, dst, vals[:, 0])  # the largest value per receiver, its own included
        ident = np.where(best[:, 0] == top, best[:, 1], -np.inf)
        np.maximum.at(ident, dst, np.where(vals[:, 0] == top[dst], vals[:, 1], -np.inf))  # ties: the largest id
        best = np.stack([top, ident], axis=1)
    return best


def admm_data_snooping(
    problem: LinearProblem,
    graph: Graph,
    *,
    exchange: Exchange | None = None,
    faults: FaultSchedule | None = None,
    options: SnoopingOptions | None = None,
    **changes: Any,
) -> AdmmResult:
    """Distributed iterative data snooping (module docstring): the final ADMM estimate with ``precision`` and
    ``tests`` filled in; options :class:`SnoopingOptions` (``options=`` and/or keyword changes to it).
    ``tests.removed`` are flat observation indices (node-major over each node's rows, as in
    :func:`distnav.algorithms.statistics.data_snooping` on the stacked data); ``tests.iterations`` and ``tests.comm``
    are what the re-convergences after the first solution cost (estimate, precision and the floods).

    Examples
    --------
    Six nodes on a ring, three unit-variance observations each of ``x = (1, −2)``; node 2's first observation
    carries a gross error of 8σ. The distributed tests remove it (flat index 2·3 + 0 = 6), as the centralized
    data snooping on the stacked data does:

    >>> import numpy as np
    >>> from distnav.algorithms.lsq.blue import LinearProblem
    >>> from distnav.algorithms.lsq.qc import admm_data_snooping
    >>> from distnav.algorithms.statistics import data_snooping
    >>> from distnav.network import builders
    >>> rng = np.random.default_rng(1)
    >>> A = rng.standard_normal((6, 3, 2))
    >>> y = A @ np.array([1.0, -2.0]) + rng.standard_normal((6, 3))
    >>> y[2, 0] += 8.0
    >>> res = admm_data_snooping(LinearProblem.from_stacked(A, y), builders.ring(6), W=3.0, tol=1e-11)
    >>> res.tests.removed, data_snooping(A.reshape(18, 2), y.ravel(), np.eye(18)).removed
    ((6,), (6,))
    """
    o = resolve_options(SnoopingOptions, options, changes)
    if exchange is not None and faults is not None:
        raise ModelError("pass faults either to the exchange or to admm_data_snooping(), not both")
    k_crit = critical_value(o.level)
    ex = exchange if exchange is not None else make_exchange(graph, faults=faults)
    C = driver.constraint_nodes_for(graph, o.constraint_nodes)
    opts = dataclasses.replace(o, constraint_nodes=C)
    prec_opts = PrecisionOptions(W=o.W, constraint_nodes=C, max_iterations=o.max_iterations, tol=o.tol, atol=o.atol)
    diameter = int(np.max(csgraph.shortest_path(graph.adjacency(), unweighted=True, directed=False)))
    flood_rounds = max(diameter, 1) * (3 if ex.faults.active else 1)
    act = _active_rows(problem, None)
    offsets = np.concatenate([[0], np.cumsum(problem.rows)])
    prob = problem
    est, prec = _solve_with_precision(prob, graph, ex, opts, act, None, prec_opts)
    first_iterations = est.iterations + prec.precision.iterations
    after_first = ex.comm_totals().snapshot()
    removed: list[int] = []
    extra_iterations = 0
    nodes = ex.nodes
    while True:
        w_local = _local_w(prob.subset(nodes), est.estimates[nodes], prec.precision.covariance[nodes], act[nodes])
        gid = _worst_flagged(ex, prob, w_local, k_crit, flood_rounds)
        if gid is None or (o.max_removals is not None and len(removed) >= o.max_removals):
            break
        node, r = divmod(gid, prob.max_rows)
        removed.append(int(offsets[node] + r))
        act = act.copy()
        act[node, r] = False
        prob = remove_observation(prob, node, r)
        warm = dataclasses.replace(opts, init=est, multipliers=est.multipliers)  # x, z and u carried over
        est, prec = _solve_with_precision(prob, graph, ex, warm, act, prec, prec_opts)
        extra_iterations += est.iterations + prec.precision.iterations
    w_all = ex.gather_nodes(w_local)
    flat = np.concatenate([w_all[i, : problem.rows[i]] for i in range(problem.n_nodes)])
    tests = ObservationTests(
        node=np.repeat(np.arange(problem.n_nodes), problem.rows),
        w=flat,
        critical_value=k_crit,
        level=o.level,
        flagged=np.nan_to_num(np.abs(flat)) > k_crit,
        removed=tuple(removed),
        iterations=extra_iterations,
        comm=ex.comm_totals().since(after_first),
    )
    msg = (
        f"data snooping: {len(removed)} observation(s) removed, {extra_iterations} extra iterations after the "
        f"first solution ({first_iterations} for estimate and precision); {est.message}"
    )
    return dataclasses.replace(est, precision=prec.precision, tests=tests, message=msg, comm=ex.comm_totals())


def _solve_with_precision(
    prob: LinearProblem,
    graph: Graph,
    ex: Exchange,
    opts: SnoopingOptions,
    act: BoolArray,
    init: PrecisionRun | None,
    prec_opts: PrecisionOptions,
) -> tuple[AdmmResult, PrecisionRun]:
    """One data-snooping step: the ADMM estimate of ``prob`` (warm when ``opts`` carry one) and its precision."""
    est = drive(driver.prepare(prob, graph, ex, opts), opts)
    prec = admm_precision(prob, graph, est.estimates, active=act, init=init, exchange=ex, options=prec_opts)
    return est, prec


def _worst_flagged(
    ex: Exchange, prob: LinearProblem, w_local: FloatArray, k_crit: float, flood_rounds: int
) -> int | None:
    """The flat id (``node · max_rows + row``) of the network's largest |w| above ``k_crit`` after a max-flood, or
    ``None`` when nothing is flagged; a :class:`ModelError` if the flood did not reach every node."""
    nodes = ex.nodes
    aw = np.where(np.isfinite(w_local), np.abs(w_local), -np.inf)
    row = np.argmax(aw, axis=1)
    val = aw[np.arange(nodes.size), row]
    key = np.stack([np.where(val > k_crit, val, -np.inf), -(nodes * prob.max_rows + row).astype(float)], axis=1)
    worst = _flood_max(ex, key, flood_rounds)
    # monitoring only: every node must hold the same worst observation after the flood
    spread = [
        worst[:, 0].max(initial=-np.inf),
        -worst[:, 0].min(initial=np.inf),
        worst[:, 1].max(initial=-np.inf),
        -worst[:, 1].min(initial=np.inf),
    ]
    agree = np.asarray(ex.allreduce(np.array(spread), "max"))
    if agree[0] != -agree[1] or (np.isfinite(agree[0]) and agree[2] != -agree[3]):
        raise ModelError(f"the max-flood of {flood_rounds} rounds did not reach every node (message losses)")
    return int(-agree[2]) if np.isfinite(agree[0]) else None
