"""ADMM for nonlinear models (paper 000 §4.3): the linearized variant and the nonlinear x-update of eq. (23).

A :class:`NonlinearProblem` holds ``y_i = F_i(x) + e_i`` per node with a model giving ``F_i`` and its Jacobian
(:class:`RangeModel`: ranges from known nodes to unknown targets). :func:`gauss_newton` is the centralized
(fusion-centre) reference; :func:`admm_linearized` runs Fig. 6 on the increments of a common linearization and
updates it; :func:`admm_nonlinear` replaces the linear x-update by a few regularized Gauss–Newton steps (eq. (23))
on the same kernel (:mod:`distnav.algorithms.lsq.kernel`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from distnav._checks import check_field_types
from distnav._settings import resolve_options
from distnav.algorithms.lsq.blue import LinearProblem, weight_matrix
from distnav.algorithms.lsq.driver import (
    AdmmOptions,
    AdmmResult,
    ConstraintOptions,
    PreparedRun,
    Stopping,
    check_stopping,
    constraint_nodes_for,
    drive,
    initial_values,
    prepare,
)
from distnav.algorithms.lsq.kernel import _Kernel, _per_node
from distnav.algorithms.result import SolverResult, TraceBuilder, stopping_fields
from distnav.errors import ModelError
from distnav.exchange import Exchange, make_exchange
from distnav.exchange.core import CommTotals
from distnav.network.constraint_nodes import ConstraintNodes
from distnav.network.graph import Graph
from distnav.typing import FloatArray

__all__ = [
    "LinearizedAdmmResult",
    "LinearizedOptions",
    "NonlinearOptions",
    "NonlinearModel",
    "NonlinearProblem",
    "RangeModel",
    "admm_linearized",
    "admm_nonlinear",
    "gauss_newton",
    "range_positioning_problem",
]


class NonlinearModel(Protocol):
    """What a :class:`NonlinearProblem` needs of its model: ``n_params`` and, for rows ``x`` ``(k, p)`` evaluated
    at nodes ``nodes`` ``(k,)``, ``predict`` ``(k, m)`` and ``jacobian`` ``(k, m, p)``."""

    @property
    def n_params(self) -> int: ...

    def predict(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray: ...

    def jacobian(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, eq=False, kw_only=True)
class LinearizedAdmmResult(SolverResult):
    """Outcome of :func:`admm_linearized`: ``inner_iterations_total`` (ADMM iterations over all outer steps) and
    the ``constraint_nodes`` used; ``iterations`` counts the outer (re-linearization) steps."""

    inner_iterations_total: int
    constraint_nodes: ConstraintNodes


class RangeModel:
    """Ranges from every node (known position ``a_i``) to ``T`` targets with unknown positions: ``x`` stacks the
    targets' coordinates (``p = T·d``), node ``i`` observes ``‖x_t − a_i‖`` for every target ``t`` (``m_i = T``).

    With ``d ≥ 2`` each ``N_i`` has rank ≤ ``T < p``: no node can position the targets alone.
    """

    def __init__(self, node_positions_m: np.ndarray, n_targets: int) -> None:
        pos = np.asarray(node_positions_m, dtype=float)
        if pos.ndim != 2:
            raise ModelError(f"node positions must be (n_nodes, dim), got shape {pos.shape}")
        if n_targets < 1:
            raise ModelError(f"n_targets must be ≥ 1, got {n_targets}")
        self.positions_m = pos
        self.n_targets = int(n_targets)
        self.dim = int(pos.shape[1])
        self._n_params = self.n_targets * self.dim

    @property
    def n_params(self) -> int:
        return self._n_params

    def predict(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """Ranges ``(len(nodes), T)`` from each listed node to the targets in its own ``x`` row ``(len(nodes), p)``."""
        d = x.reshape(x.shape[0], self.n_targets, self.dim) - self.positions_m[nodes][:, None, :]
        ranges: np.ndarray = np.sqrt(np.einsum("ntd,ntd->nt", d, d))
        return ranges

    def jacobian(self, x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """``∂ range / ∂ x`` ``(len(nodes), T, p)``: unit vectors from node to target, in the target's columns."""
        n = x.shape[0]
        d = x.reshape(n, self.n_targets, self.dim) - self.positions_m[nodes][:, None, :]
        rng = np.sqrt(np.einsum("ntd,ntd->nt", d, d))
        if np.any(rng == 0):
            raise ModelError("a target estimate coincides with a node position: the range Jacobian is undefined")
        J = np.zeros((n, self.n_targets, self.n_params))
        for t in range(self.n_targets):
            J[:, t, t * self.dim : (t + 1) * self.dim] = d[:, t, :] / rng[:, t, None]
        return J


@dataclass(frozen=True, eq=False)
class NonlinearProblem:
    """``y_i = F_i(x) + e_i``, ``C(e_i) = R_i`` per node (paper 000 §4.3 with nonlinear maps ``A_i(x)``).

    ``model`` provides ``predict(x_rows, nodes)`` ``(k, m)`` and ``jacobian(x_rows, nodes)`` ``(k, m, p)``, where row
    ``j`` is evaluated for node ``nodes[j]`` at its own ``x_rows[j]`` (nodes use only their own data).
    ``y`` ``(n, m)`` and ``R`` ``(n, m, m)``.
    """

    model: NonlinearModel
    y: np.ndarray
    R: np.ndarray

    def __post_init__(self) -> None:
        y = np.asarray(self.y, dtype=float)
        R = np.asarray(self.R, dtype=float)
        if y.ndim != 2 or R.shape != (y.shape[0], y.shape[1], y.shape[1]):
            raise ModelError(f"y must be (n, m) and R (n, m, m); got {y.shape} and {R.shape}")
        bad = ~np.isfinite(y).all(axis=1)
        if bad.any():
            raise ModelError(f"node {int(np.argmax(bad))}: observations are not finite")
        try:
            np.linalg.cholesky(R)
        except np.linalg.LinAlgError:
            i = int(np.argmin([np.linalg.eigvalsh(r).min() for r in R]))
            raise ModelError(f"node {i}: R_i is not positive definite") from None
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "R", R)

    @property
    def n_nodes(self) -> int:
        return int(self.y.shape[0])

    @property
    def n_params(self) -> int:
        return int(self.model.n_params)

    def linearize(self, x_approx: np.ndarray) -> LinearProblem:
        """Increments at each node's approximate value ``x_i^o`` (§4.3): ``Δy_i = y_i − F_i(x_i^o)``,
        ``A_i = ∂F_i(x_i^o)``; ``x_approx`` is ``(p,)`` (common) or ``(n, p)``."""
        n = self.n_nodes
        xo = _per_node(x_approx, n, self.n_params, "x_approx")
        nodes = np.arange(n)
        return LinearProblem.from_stacked(
            self.model.jacobian(xo, nodes), self.y - self.model.predict(xo, nodes), self.R
        )

    def cost(self, x: np.ndarray) -> float:
        """``Σ_i ½‖y_i − F_i(x)‖²_{R_i⁻¹}`` at a common ``x``."""
        n = self.n_nodes
        e = self.y - self.model.predict(np.broadcast_to(np.asarray(x, float), (n, self.n_params)), np.arange(n))
        return float(0.5 * np.einsum("nm,nmk,nk->", e, np.linalg.inv(self.R), e))


def range_positioning_problem(
    node_positions_m: np.ndarray, targets_m: np.ndarray, *, sigma_m: float, rng: np.random.Generator
) -> NonlinearProblem:
    """Every node measures its range to every target with noise ``N(0, σ²)``: a :class:`NonlinearProblem` on a
    :class:`RangeModel` (``targets_m`` is ``(T, d)``; the true ``x`` is ``targets_m.ravel()``)."""
    tg = np.atleast_2d(np.asarray(targets_m, dtype=float))
    if sigma_m <= 0:
        raise ModelError(f"sigma_m must be > 0, got {sigma_m}")
    model = RangeModel(node_positions_m, tg.shape[0])
    n = model.positions_m.shape[0]
    if tg.shape[1] != model.dim:
        raise ModelError(f"targets have {tg.shape[1]} coordinates, nodes have {model.dim}")
    truth = np.broadcast_to(tg.ravel(), (n, model.n_params))
    y = model.predict(truth, np.arange(n)) + sigma_m * rng.standard_normal((n, tg.shape[0]))
    R = np.broadcast_to(sigma_m**2 * np.eye(tg.shape[0]), (n, tg.shape[0], tg.shape[0])).copy()
    return NonlinearProblem(model, y, R)


def gauss_newton(
    problem: NonlinearProblem, x0: FloatArray, *, max_iterations: int = 50, tol: float = 1e-12
) -> SolverResult:
    """Centralized Gauss–Newton on ``Σ_i ½‖y_i − F_i(x)‖²_{R_i⁻¹}`` (the fusion-centre reference, Teunissen 1990):
    ``x ← x + (Σ J_iᵀR_i⁻¹J_i)⁻¹ Σ J_iᵀR_i⁻¹(y_i − F_i(x))`` until ``‖Δx‖ ≤ tol·(1 + ‖x‖)``."""
    p = problem.n_params
    x = np.asarray(x0, dtype=float).copy()
    if x.shape != (p,):
        raise ModelError(f"x0 must be a length-{p} vector, got shape {x.shape}")
    n = problem.n_nodes
    nodes = np.arange(n)
    Rinv = np.linalg.inv(problem.R)
    tb = TraceBuilder()
    converged = False
    k = 0
    while k < max_iterations:
        k += 1
        xs = np.broadcast_to(x, (n, p))
        J = problem.model.jacobian(xs, nodes)
        e = problem.y - problem.model.predict(xs, nodes)
        JtRi = np.einsum("nmp,nmk->npk", J, Rinv)
        N = np.einsum("npk,nkq->pq", JtRi, J)
        g = np.einsum("npk,nk->p", JtRi, e)
        dx = np.linalg.solve(N, g)
        x = x + dx
        tb.add(step_norm=float(np.linalg.norm(dx)), cost=problem.cost(x))
        if np.linalg.norm(dx) <= tol * (1 + np.linalg.norm(x)):
            converged = True
            break
    message = f"Gauss-Newton: {k} iterations, cost {problem.cost(x):.6g}"
    return SolverResult(estimates=x[None, :], **stopping_fields(converged, k, message, tb, CommTotals.empty(n)))


@dataclass(frozen=True, eq=False, kw_only=True)
class LinearizedOptions(ConstraintOptions):
    """Options of :func:`admm_linearized` (house style: :mod:`distnav._settings`; default in brackets):
    ``constraint_nodes`` and ``W`` as for :func:`~distnav.algorithms.lsq.admm.admm`, and

    Fields
    ------
    outer_iterations : [10] at most that many relinearizations,
    tol : [1e-10] ending when ``max_i ‖Δx_i‖ ≤ tol·(1 + ‖x^o‖)``.
    inner_max_iterations : [2000] the stopping rule of each ADMM run,
    inner_tol : [1e-12] its relative tolerance,
    inner_atol : [1e-12] and its absolute tolerance (units of ``x``).
    messages : [``"pairs"``] ``"pairs"`` or ``"aggregated"``, as for :func:`~distnav.algorithms.lsq.admm.admm`.
    """

    outer_iterations: int = 10
    inner_max_iterations: int = 2000
    inner_tol: float = 1e-12
    inner_atol: float = 1e-12
    tol: float = 1e-10
    messages: Literal["pairs", "aggregated"] = "pairs"

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        check_stopping(self.inner_max_iterations, self.inner_tol, self.inner_atol)


@dataclass(frozen=True, eq=False, kw_only=True)
class NonlinearOptions(ConstraintOptions):
    """Options of :func:`admm_nonlinear` (house style: :mod:`distnav._settings`; default in brackets):
    ``constraint_nodes`` and ``W`` as for :func:`~distnav.algorithms.lsq.admm.admm`, and

    Fields
    ------
    gn_steps : [2] Gauss–Newton steps per x-update (eq. (23)).
    max_iterations : [2000], tol : [1e-10], atol : [0.0] the stopping rule, as for
        :func:`~distnav.algorithms.lsq.admm.admm`.
    record_nodes : [True] trace every node's distance to the reference.
    """

    gn_steps: int = 2
    max_iterations: int = 2000
    tol: float = 1e-10
    atol: float = 0.0
    record_nodes: bool = True

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        check_stopping(self.max_iterations, self.tol, self.atol)
        if self.gn_steps < 1:
            raise ModelError(f"gn_steps must be ≥ 1, got {self.gn_steps}")


def admm_linearized(
    problem: NonlinearProblem,
    graph: Graph,
    x_approx: FloatArray,
    *,
    reference: np.ndarray | None = None,
    exchange: Exchange | None = None,
    options: LinearizedOptions | None = None,
    **changes: Any,
) -> LinearizedAdmmResult:
    """The linearized case of paper 000 §4.3: all nodes start from the same approximate value ``x^o``, linearize
    their models there, run Fig. 6 on the increments from ``Δx_i^[0] = z_s^[0] = 0`` until it converges, then set
    ``x_i^o ← x_i^o + Δx_i``; repeated until ``max_i ‖Δx_i‖ ≤ tol·(1 + ‖x^o‖)`` or ``outer_iterations``; options
    :class:`LinearizedOptions` (``options=`` and/or keyword changes to it).

    Each node keeps its own ``x_i^o``; they stay identical up to the inner tolerance (the paper's requirement of
    identical approximate values), so ``inner_tol`` should be tight; ``inner_atol`` (absolute, in the units of ``x``)
    ends the inner runs of the last steps, whose increments are tiny. Trace per outer iteration: ``max_step``,
    ``inner_iterations``, ``spread`` (``max_i ‖x_i^o − mean‖``) and with ``reference`` ``max_distance_to_reference``.
    """
    o = resolve_options(LinearizedOptions, options, changes)
    p = problem.n_params
    ex = exchange if exchange is not None else make_exchange(graph)
    C = constraint_nodes_for(graph, o.constraint_nodes)
    xo = _per_node(x_approx, problem.n_nodes, p, "x_approx")
    admm_options = AdmmOptions(constraint_nodes=C, W=o.W, init="zero", messages=o.messages)
    inner_stop = Stopping(max_iterations=o.inner_max_iterations, tol=o.inner_tol, atol=o.inner_atol)
    tb = TraceBuilder()
    converged = False
    total_inner = 0
    t = 0
    while t < o.outer_iterations:
        t += 1
        inner = drive(prepare(problem.linearize(xo), graph, ex, admm_options), inner_stop)
        dx = inner.estimates
        xo = xo + dx
        total_inner += inner.iterations
        step = float(np.linalg.norm(dx, axis=1).max())
        tb.add(
            max_step=step,
            inner_iterations=inner.iterations,
            spread=float(np.linalg.norm(xo - xo.mean(axis=0), axis=1).max()),
        )
        if reference is not None:
            tb.add(max_distance_to_reference=float(np.linalg.norm(xo - np.asarray(reference)[None, :], axis=1).max()))
        if step <= o.tol * (1 + float(np.linalg.norm(xo.mean(axis=0)))):
            converged = True
            break
    message = f"linearized ADMM: {t} outer iterations, {total_inner} ADMM iterations in all"
    return LinearizedAdmmResult(
        estimates=xo,
        **stopping_fields(converged, t, message, tb, ex.comm_totals()),
        inner_iterations_total=total_inner,
        constraint_nodes=C,
    )


class _NonlinearXUpdate:
    """Eq. (23): ``x_i = argmin ‖y_i − F_i(x)‖²_{R_i⁻¹} + c_i‖l_i − x‖²_W`` by ``steps`` regularized Gauss–Newton steps
    from the previous ``x_i`` (batched over the block's nodes)."""

    def __init__(self, problem: NonlinearProblem, nodes: np.ndarray, W: np.ndarray, c: np.ndarray, steps: int) -> None:
        self.model = problem.model
        self.nodes = nodes
        self.y = problem.y[nodes]
        self.Rinv = np.linalg.inv(problem.R[nodes])
        self.Wc = c[:, None, None] * W[None]
        self.steps = steps

    def __call__(self, l: np.ndarray, x_prev: np.ndarray) -> np.ndarray:
        x = x_prev
        for _ in range(self.steps):
            J = self.model.jacobian(x, self.nodes)
            e = self.y - self.model.predict(x, self.nodes)
            JtRi = np.einsum("nmp,nmk->npk", J, self.Rinv)
            H = JtRi @ J + self.Wc
            g = np.einsum("npk,nk->np", JtRi, e) + (self.Wc @ (l - x)[..., None])[..., 0]
            x = x + np.linalg.solve(H, g[..., None])[..., 0]
        return x


def admm_nonlinear(
    problem: NonlinearProblem,
    graph: Graph,
    x0: FloatArray,
    *,
    reference: np.ndarray | None = None,
    exchange: Exchange | None = None,
    options: NonlinearOptions | None = None,
    **changes: Any,
) -> AdmmResult:
    """ADMM with constraint nodes and the nonlinear x-update of paper 000 eq. (23): each node solves its regularized
    nonlinear least-squares problem (``gn_steps`` Gauss–Newton steps warm-started at its previous ``x_i`` per
    iteration; exact at convergence). ``x0``: common ``(p,)`` or per-node ``(n, p)`` start (also ``z_s^[0]``).
    Same stopping and trace as :func:`admm`; options :class:`NonlinearOptions` (``options=`` and/or keyword changes
    to it)."""
    o = resolve_options(NonlinearOptions, options, changes)
    gn_steps = o.gn_steps
    p = problem.n_params
    Wm = weight_matrix(o.W, p)
    ex = exchange if exchange is not None else make_exchange(graph)
    C = constraint_nodes_for(graph, o.constraint_nodes)
    x_init, z_init = initial_values(x0, None, problem.n_nodes, p)
    count = C.per_node_count[ex.nodes].astype(float)
    xu = _NonlinearXUpdate(problem, ex.nodes, Wm, count, gn_steps)
    kernel = _Kernel(ex, C, Wm, p, xu)
    run = PreparedRun(
        states=kernel.run(x_init[ex.nodes], z_init[ex.nodes]),
        exchange=ex,
        constraint_nodes=C,
        p=p,
        x_update=f"nonlinear (eq. 23, {gn_steps} Gauss-Newton steps)",
        x_weight="lagrangian",
        messages="pairs",
    )
    return drive(run, o, reference=reference, record_nodes=o.record_nodes)
