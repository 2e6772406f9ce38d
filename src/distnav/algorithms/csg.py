"""Distributed anchor self-localization (paper 002 §3.2–3.4): CSG, N-CSG (+ BLS / TBLS line search), N-CLM.

Every anchor is a node of the measurement graph and talks only to the anchors it ranges with, through the
exchange (:mod:`distnav.exchange`); all arrays below are local to the exchange's block of anchors.

* **CSG** (Koppanyi et al. 2018; paper 002 eqs. (10)–(12)): anchor ``i`` holds an estimate ``x⁽ⁱ⁾`` of *every*
  anchor. Update phase ``u⁽ⁱ⁾ = x⁽ⁱ⁾ − α G⁽ⁱ⁾ᵀ g⁽ⁱ⁾`` where ``g⁽ⁱ⁾`` keeps only the residuals
  ``g_l = ‖r_a − r_b‖² − d_l²`` of the ranges anchor ``i`` measured (eq. (10)); consensus phase
  ``u⁽ⁱ⁾ ← Σ_{j∈N(i)∪{i}} W_ij u⁽ʲ⁾`` repeated ``consensus_rounds`` times (eq. (11)), then ``x⁽ⁱ⁾ ← u⁽ⁱ⁾``.
  ``W`` is Metropolis–Hastings (eq. (12), ``"MH"``) or Koppanyi's own variant (``"Koppanyi"``). A message is the
  whole vector: its size grows with the *network*.
* **N-CSG** (eqs. (14)–(18)), **N-CSG + BLS / TBLS** (eqs. (19)–(21)) and **N-CLM** (eq. (22)): every anchor holds
  only itself and its neighbours (messages grow with the *neighbourhood*); the equations and the machinery
  (index maps, mixing, line searches, local LM) are in :mod:`distnav.algorithms.neighbourhood`. This module has
  CSG and the front doors (:func:`solve_csg`, :func:`solve_ncsg`, :func:`solve_nclm`, :func:`solve`), which
  return a :class:`~distnav.algorithms.ranging.RangingResult` (status ``"max_iterations"``, or ``"diverged"``
  when the estimates blow up).

Fixed anchors take part (they measure and relay) but their coordinates, and any held coordinate, are never changed.
Paper defaults: 500 iterations, ``α = 1e-3``, ``α₀ = 1e-2``, ``β = γ = 1/2``, one consensus round.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import scipy.sparse as sp

from distnav.algorithms.neighbourhood import (
    IterationState,
    check_start,
    exchange_for,
    half_measurements,
    iterate_neighbourhood,
    mixing_weights,
)
from distnav.algorithms.nlsq import range_loss_scale, robust_weights, solve_lm
from distnav.algorithms.ranging import RangingData, RangingResult
from distnav.algorithms.result import Trace
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.weights import ConsensusWeights

__all__ = [
    "SOLVERS",
    "DISTRIBUTED_SOLVERS",
    "IterationState",
    "iterate_csg",
    "iterate_neighbourhood",
    "solve_csg",
    "solve_ncsg",
    "solve_nclm",
    "solve",
]

SOLVERS = ("LM", "CSG", "N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM")
DISTRIBUTED_SOLVERS = SOLVERS[1:]


def _summarize(problem: RangingData, ex: Exchange, own_local: np.ndarray, truth: np.ndarray | None,
               est: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Monitoring only (gathers): all own estimates, global cost f (eq. (2)) and RMSE (eq. (24))."""
    own = ex.gather_nodes(own_local)
    cost = problem.cost(own)
    if truth is None:
        return own, cost, float("nan")
    d = own[est] - truth[est]
    return own, cost, float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d)))) if est.any() else 0.0


# ---------------------------------------------------------------------- CSG (full estimation vector)
def iterate_csg(
    problem: RangingData,
    *,
    exchange: Exchange | None = None,
    iterations: int = 500,
    alpha: float = 1e-3,
    consensus_rounds: int = 1,
    weights: str | ConsensusWeights = "MH",
    initial_m: np.ndarray | None = None,
) -> Iterator[IterationState]:
    """Yield the CSG state after iterations 0 (start), 1, …, ``iterations`` (paper 002 eqs. (10)–(12))."""
    init = check_start(problem, iterations, consensus_rounds, initial_m)
    if not alpha > 0:
        raise ModelError(f"alpha must be positive, got {alpha}")
    ex = exchange_for(problem, exchange)
    mixer = ex.mixer(mixing_weights(problem, weights))
    n, dim, nl = problem.n_anchors, problem.dim, ex.n_local
    own_idx, other, d2, _ = half_measurements(problem, ex)
    me = ex.nodes[own_idx]
    # full vectors: F[li, k] = anchor ex.nodes[li]'s estimate of anchor k
    F = np.broadcast_to(init, (nl, n, dim)).copy()
    free = np.broadcast_to(problem.free, (nl, n, dim))
    known = np.broadcast_to(problem.positions_m, (nl, n, dim))
    fl_self = own_idx * n + me
    fl_other = own_idx * n + other
    nh = own_idx.size
    Q = sp.csr_matrix((np.concatenate([np.ones(nh), -np.ones(nh)]),
                       (np.concatenate([fl_self, fl_other]), np.concatenate([np.arange(nh)] * 2))),
                      shape=(nl * n, nh))
    alpha_local = np.full(nl, float(alpha))

    def partial_cost(Fc: np.ndarray) -> np.ndarray:
        flat = Fc.reshape(nl * n, dim)
        diff = flat[fl_self] - flat[fl_other]
        g = np.einsum("ij,ij->i", diff, diff) - d2
        return np.bincount(own_idx, g * g, minlength=nl)

    flat = F.reshape(nl * n, dim)
    yield IterationState(0, flat[ex.nodes[np.arange(nl)] + np.arange(nl) * n].copy(), alpha_local,
                         partial_cost(F))
    for k in range(1, iterations + 1):
        flat = F.reshape(nl * n, dim)
        diff = flat[fl_self] - flat[fl_other]
        g = np.einsum("ij,ij->i", diff, diff) - d2
        pc = np.bincount(own_idx, g * g, minlength=nl)
        grad = np.asarray(Q @ (2.0 * g[:, None] * diff)).reshape(nl, n, dim)  # G⁽ⁱ⁾ᵀ g⁽ⁱ⁾, eq. (10)
        U = np.where(free, F - alpha * grad, known)
        for _ in range(consensus_rounds):  # eq. (11)
            U = mixer.apply(U)
        F = np.where(free, U, known)
        flat = F.reshape(nl * n, dim)
        yield IterationState(k, flat[ex.nodes + np.arange(nl) * n].copy(), alpha_local, pc)


# ---------------------------------------------------------------------- run-to-end front doors
def _check_monitor(monitor_every: int) -> None:
    if monitor_every < 0:
        raise ModelError(f"monitor_every must be ≥ 0, got {monitor_every}")


def _run(problem: RangingData, states: Iterator[IterationState], ex: Exchange, name: str, iterations: int,
         settings: dict[str, Any], *, monitor_every: int = 1, loss: str = "linear",
         loss_scale_m: float = 0.3) -> RangingResult:
    """Drive a state generator to its end, monitoring every ``monitor_every``-th iteration (and the first and last).

    Monitoring gathers every anchor's own estimate (``ex.gather_nodes``) and sums the partial costs and steps
    (``ex.allreduce``): network-wide collectives a deployment would not run each iteration. Unmonitored rows of the
    trace are NaN; a blow-up (non-finite cost) is detected at the next monitored iteration and ends the run as
    ``"diverged"``. ``monitor_every=0`` monitors the start and the end only.
    """
    truth = problem.truth_m
    est = problem.estimated
    rm: list[float] = []
    cost: list[float] = []
    pcost: list[float] = []
    step: list[float] = []
    count = max(int(ex.allreduce(ex.n_local, "sum")), 1)
    own: np.ndarray | None = None
    last: IterationState | None = None
    diverged = False
    nan = float("nan")
    with np.errstate(over="ignore", invalid="ignore"):
        for st in states:
            last = st
            k = st.iteration
            if not (k == 0 or k == iterations or (monitor_every and k % monitor_every == 0)):
                rm.append(nan)
                cost.append(nan)
                pcost.append(nan)
                step.append(nan)
                continue
            own, c, r = _summarize(problem, ex, st.own_m, truth, est)
            rm.append(r)
            cost.append(c)
            pcost.append(float(ex.allreduce(float(st.partial_cost.sum()), "sum")))
            step.append(float(ex.allreduce(float(st.step_size.sum()), "sum")) / count)
            if not np.isfinite(c):  # the estimates blew up (e.g. a fixed α too large for the geometry)
                diverged = True
                break
    assert own is not None and last is not None
    key = "lambda" if name == "N-CLM" else "step_size"
    trace = Trace({"rmse_m": np.asarray(rm), "cost": np.asarray(cost), "partial_cost": np.asarray(pcost),
                   key: np.asarray(step)})
    final_cost = cost[-1]
    with np.errstate(over="ignore", invalid="ignore"):
        objective = final_cost if loss == "linear" else robust_weights(
            problem.residuals(own), range_loss_scale(problem, loss_scale_m), loss)[1]
    return RangingResult(
        estimates=own,
        converged=False,
        iterations=last.iteration,
        status="diverged" if diverged else "max_iterations",
        message=f"{name}: {'diverged after ' if diverged else ''}{last.iteration} iterations, cost {final_cost:.6g}"
                + (f", RMSE {rm[-1]:.3f} m" if truth is not None else ""),
        trace=trace,
        comm=ex.comm_totals(),
        solver=name,
        cost=final_cost,
        objective=objective,
        loss=loss,
        settings=settings,
    )


def solve_csg(problem: RangingData, *, exchange: Exchange | None = None, iterations: int = 500,
              alpha: float = 1e-3, consensus_rounds: int = 1, weights: str | ConsensusWeights = "MH",
              initial_m: np.ndarray | None = None, monitor_every: int = 1) -> RangingResult:
    """CSG (paper 002 eqs. (10)–(12)); trace: ``rmse_m``, ``cost`` (global f at the anchors' own estimates),
    ``partial_cost`` (Σ_i f⁽ⁱ⁾(x⁽ⁱ⁾)), ``step_size``; row 0 is the start.

    ``monitor_every = k`` gathers the estimates for the trace (and the divergence check) only every ``k``-th
    iteration (NaN rows otherwise; 0: start and end only); see :func:`_run`. The estimates do not depend on it."""
    _check_monitor(monitor_every)
    ex = exchange_for(problem, exchange)
    states = iterate_csg(problem, exchange=ex, iterations=iterations, alpha=alpha,
                         consensus_rounds=consensus_rounds, weights=weights, initial_m=initial_m)
    return _run(problem, states, ex, "CSG", iterations, {"alpha": alpha, "consensus_rounds": consensus_rounds},
                monitor_every=monitor_every)


def solve_ncsg(problem: RangingData, *, line_search: str | None = None, exchange: Exchange | None = None,
               iterations: int = 500, alpha: float = 1e-3, alpha0: float = 1e-2, beta: float = 0.5,
               gamma: float = 0.5, consensus_rounds: int = 1, weights: str | ConsensusWeights = "MH",
               initial_m: np.ndarray | None = None, max_backtracks: int = 40,
               armijo_slope: str = "subgradient", loss: str = "linear", loss_scale_m: float = 0.3,
               monitor_every: int = 1) -> RangingResult:
    """N-CSG (eqs. (14)–(18)); ``line_search="BLS"`` (eqs. (19)–(20)) or ``"TBLS"`` (eq. (21)).

    Trace (and ``monitor_every``) as :func:`solve_csg`; ``step_size`` is the mean ``α`` over anchors (paper 002
    Fig. 6).
    ``armijo_slope="subgradient"`` (default, the papers README's eq. (19): ``d = −∇f``, "the subgradient") puts
    the subgradient ``G⁽ⁱ⁾ᵀg⁽ⁱ⁾`` of eq. (10) in place of ``∇f⁽ⁱ⁾`` in the Armijo test, i.e. requires
    ``f⁽ⁱ⁾(x + αd) ≤ f⁽ⁱ⁾(x) − γα‖d‖²``; this reproduces the paper's Fig. 6 step sizes (≈1.2e-3 on RC/RM).
    ``"gradient"`` uses the true slope ``∇f⁽ⁱ⁾ᵀd = −2‖d‖²`` of ``f⁽ⁱ⁾ = Σ g²`` (a stricter test: steps ≈ 0.7×).
    """
    if line_search is None:
        method = "N-CSG"
    elif str(line_search).upper() in ("BLS", "TBLS"):
        method = f"N-CSG-{str(line_search).upper()}"
    else:
        raise ModelError(f"line_search must be None, 'BLS' or 'TBLS', got {line_search!r}")
    _check_monitor(monitor_every)
    ex = exchange_for(problem, exchange)
    states = iterate_neighbourhood(problem, method=method, exchange=ex, iterations=iterations, alpha=alpha,
                                   alpha0=alpha0, beta=beta, gamma=gamma, consensus_rounds=consensus_rounds,
                                   weights=weights, initial_m=initial_m, max_backtracks=max_backtracks,
                                   armijo_slope=armijo_slope, loss=loss, loss_scale_m=loss_scale_m)
    return _run(problem, states, ex, method, iterations,
                {"alpha": alpha, "alpha0": alpha0, "beta": beta, "gamma": gamma, "consensus_rounds": consensus_rounds,
                 "armijo_slope": armijo_slope, "loss": loss},
                monitor_every=monitor_every, loss=loss, loss_scale_m=loss_scale_m)


def solve_nclm(problem: RangingData, *, exchange: Exchange | None = None, iterations: int = 500,
               lambda0: float = 1e-3, consensus_rounds: int = 1, weights: str | ConsensusWeights = "MH",
               initial_m: np.ndarray | None = None, damping: str = "levenberg", loss: str = "linear",
               loss_scale_m: float = 0.3, lambda_min: float = 0.1, monitor_every: int = 1) -> RangingResult:
    """N-CLM (eq. (22)); trace (and ``monitor_every``) as :func:`solve_csg` with the mean ``lambda`` instead of
    ``step_size``.

    ``damping="fletcher"`` is eq. (22) read literally with eq. (8)'s ``λ diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)``. On the partial cost
    this stalls: anchor ``i`` has ``d_i`` ranges but ``(d_i + 1)·dim`` unknowns, and a neighbour's coordinates
    carry the curvature of one range only, so Fletcher's scaling lets every anchor drag each neighbour to fit
    that one range; after mixing the network wanders (10×10 grid, 2-D, noise 0.15 m: RMSE 3.1 m after 300
    iterations, vs 0.26 m for N-CSG-BLS). The default ``"levenberg"`` damps isotropically with
    ``λ_i · mean(diag(G⁽ⁱ⁾ᵀG⁽ⁱ⁾)) · I`` (scale-free like Fletcher's, but equal for own and neighbour
    coordinates), which reaches 0.26 m on the same problem.

    ``lambda_min`` (default 0.1) floors each anchor's ``λ_i``: with ``λ_i → 0`` an anchor's step fits its own,
    underdetermined, ranges exactly and the network drifts when the ranges disagree (one anchor pair 3 m NLOS:
    RMSE 3.15 m with the floor 1e-9, 0.30 m with 0.1 and a Cauchy loss; RM with heights held: 0.78 → 0.51 m).
    """
    _check_monitor(monitor_every)
    ex = exchange_for(problem, exchange)
    states = iterate_neighbourhood(problem, method="N-CLM", exchange=ex, iterations=iterations, lambda0=lambda0,
                                   consensus_rounds=consensus_rounds, weights=weights, initial_m=initial_m,
                                   damping=damping, loss=loss, loss_scale_m=loss_scale_m, lambda_min=lambda_min)
    return _run(problem, states, ex, "N-CLM", iterations,
                {"lambda0": lambda0, "consensus_rounds": consensus_rounds, "damping": damping, "loss": loss},
                monitor_every=monitor_every, loss=loss, loss_scale_m=loss_scale_m)


def solve(problem: RangingData, solver: str, *, iterations: int = 500, exchange: Exchange | None = None,
          **options: Any) -> RangingResult:
    """Run one of :data:`SOLVERS` by name with paper defaults (``options`` go to the solver's front door)."""
    key = str(solver).upper()
    if key == "LM":
        return solve_lm(problem, max_iterations=iterations, **options)
    if key == "CSG":
        return solve_csg(problem, iterations=iterations, exchange=exchange, **options)
    if key == "N-CSG":
        return solve_ncsg(problem, iterations=iterations, exchange=exchange, **options)
    if key in ("N-CSG-BLS", "N-CSG-TBLS"):
        return solve_ncsg(problem, line_search=key.rsplit("-", 1)[1], iterations=iterations, exchange=exchange,
                          **options)
    if key == "N-CLM":
        return solve_nclm(problem, iterations=iterations, exchange=exchange, **options)
    raise ModelError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
