"""Quality control of a solved anchor network: per-link tests in metres, NLOS exclusion, per-anchor precision
(issue 13, items 2 and 3).

Everything is linearized at the solution, in **metres**: the residual of link ``l`` is
``e_l = ‖r̂_a − r̂_b‖ − d_l`` and its design row ``a_l`` holds the unit vector ``u = (r̂_a − r̂_b)/‖·‖`` at a's free
coordinates and ``−u`` at b's. One observation per link (``uwb solve`` combines the samples of a pair by their
median first).

**Link test (w-test with the residual covariance and a robust scale).** For an estimator that weights link
``l`` by ``u_l`` (1 for the objective in metres; ``d_l²`` for the paper's squared form ``g = ‖·‖² − d²``, whose
residual is ≈ 2d·e), the residuals have covariance ``σ² Q_ê`` with ``Q_ê = (I − H)(I − H)ᵀ``,
``H = A (AᵀUA)⁻¹ AᵀU`` (for ``U = I`` this is Baarda's ``I − A N⁻¹ Aᵀ``). Then ``w_l = e_l / (σ̂ √(Q_ê)_ll)``
(:func:`distnav.algorithms.statistics.w_statistics`). σ is **not** taken from the data sheet: on real links the
error is dominated by per-link systematic effects (antenna delays, multipath) that no a-priori σ knows, and an
NLOS link inflates the classical σ̂. We use the robust scale ``σ̂ = 1.4826 · median_l |e_l| / √(Q_ê)_ll`` of the
links still in the solution, so a minority of NLOS links cannot mask themselves. A link already excluded is
tested by its prediction residual, variance ``σ̂² (1 + a_l N⁻¹ a_lᵀ)`` (it is not in the fit).

**Exclusion** (:func:`exclude_links`): in each round every anchor looks at its own links, and a link whose
``|w|`` exceeds the critical value and is the largest among all links of both its anchors is excluded (so one
gross error is removed at a time per neighbourhood — the worst one — and far-apart NLOS links go in the same
round); an exclusion that would leave an anchor with no more links than free coordinates, or make the network
non-rigid, is refused (the link is reported as flagged, not excluded). Then the network is re-solved from the
current estimate, until no link is left above the critical value.

**Precision** (:func:`anchor_covariance`): the covariance of the estimate, sandwich form
``σ̂² (AᵀUA)⁻¹ AᵀU²A (AᵀUA)⁻¹`` (= ``σ̂² (AᵀA)⁻¹`` for ``U = I``), per-anchor ``dim × dim`` blocks; σ̂² here is the
classical a-posteriori variance ``Σ e² / tr(Q_ê)`` of the links in the fit (= ``eᵀe / r`` for ``U = I``; after
exclusion the remaining links are consistent, and the classical σ̂ is the unbiased one).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from distnav.algorithms.statistics import critical_value, w_statistics
from distnav.errors import ModelError
from distnav.models.uwb.geometry import MAX_DENSE_RIGIDITY, flexible_anchors
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["LinkQC", "ExclusionOutcome", "metres_design", "link_tests", "anchor_covariance", "exclude_links",
           "with_measurements", "estimator_weights"]

ROBUST_SCALE = 1.4826


@dataclass(frozen=True, eq=False)
class LinkQC:
    """Per-measurement statistics at one solution (see the module docstring); ``active`` marks the
    measurements in the fit, ``scale_m`` is the robust σ̂ (m), ``variance_factor`` the classical one (m²)."""

    residual_m: FloatArray
    w: FloatArray
    q_ll: FloatArray
    scale_m: float
    variance_factor_m2: float | None
    redundancy: int
    critical_value: float
    level: float
    active: BoolArray

    @property
    def flagged(self) -> BoolArray:
        out: BoolArray = np.abs(np.nan_to_num(self.w)) > self.critical_value
        return out


def estimator_weights(problem: RangingProblem, objective: str) -> FloatArray:
    """Per-link weight ``u_l`` the estimator gives a range error in metres: 1 (metres), ``d_l²`` (squared)."""
    if objective == "metres":
        return np.ones(problem.n_meas)
    if objective == "squared":
        out: FloatArray = np.maximum(problem.range_m, 1e-3) ** 2
        return out
    raise ModelError(f"unknown objective {objective!r}; choose metres or squared")


def metres_design(problem: RangingProblem, positions_m: FloatArray) -> tuple[sp.csr_matrix, FloatArray]:
    """Design matrix ``A`` (``m × n_free``, unit vectors) and residuals ``e`` in metres at ``positions_m``."""
    p = np.asarray(positions_m, float)
    diff = p[problem.meas_a] - p[problem.meas_b]
    dist = np.linalg.norm(diff, axis=1)
    u = diff / np.maximum(dist, 1e-12)[:, None]
    col = np.full(problem.free.shape, -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    m, d = problem.n_meas, problem.dim
    rows = np.concatenate([np.repeat(np.arange(m), d)] * 2)
    cols = np.concatenate([col[problem.meas_a].ravel(), col[problem.meas_b].ravel()])
    vals = np.concatenate([u.ravel(), -u.ravel()])
    keep = cols >= 0
    a = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(m, problem.n_free))
    return a, dist - problem.range_m


def _normal_inverse(a: sp.csr_matrix, weights: FloatArray) -> FloatArray:
    n = (a.T @ sp.diags(weights) @ a).toarray()
    try:
        out: FloatArray = np.linalg.inv(n)
    except np.linalg.LinAlgError:
        raise ModelError("the normal matrix of the solution is singular: the network is not determined") from None
    return out


def link_tests(problem: RangingProblem, positions_m: FloatArray, *, objective: str = "metres",
               level: float = 0.001, active: BoolArray | None = None) -> LinkQC:
    """w-tests of every measurement at ``positions_m`` (see the module docstring)."""
    act = np.ones(problem.n_meas, bool) if active is None else np.asarray(active, bool)
    a, e = metres_design(problem, positions_m)
    u = estimator_weights(problem, objective) * act
    ninv = _normal_inverse(a, u)
    an = (a @ ninv)
    h_diag = np.asarray(a.multiply(an).sum(axis=1)).ravel()  # a_l N⁻¹ a_lᵀ
    # (Q_ê)_ll = 1 − 2 u_l h_ll + Σ_k u_k² (a_l N⁻¹ a_k)² ; for U = I this is 1 − h_ll
    if np.allclose(u[act], 1.0):
        q = np.where(act, 1.0 - h_diag, 1.0 + h_diag)
    else:
        hk = (an @ (a.T @ sp.diags(u)).toarray())  # H = A N⁻¹ AᵀU (dense m × m; networks of ≤ a few 1000 links)
        q_act = 1.0 - 2.0 * np.diag(hk) + np.einsum("lk,lk->l", hk, hk)
        q = np.where(act, q_act, 1.0 + h_diag)
    q = np.maximum(q, 0.0)
    std = np.where(q > 1e-10, np.abs(e) / np.sqrt(np.maximum(q, 1e-300)), np.nan)
    finite = act & np.isfinite(std)
    scale = float(ROBUST_SCALE * np.median(std[finite])) if finite.any() else float("nan")
    scale = max(scale, 1e-4)
    redundancy = int(act.sum()) - problem.n_free
    trace_q = float(np.sum(q[act]))  # E{Σ e²} = σ² tr(Q_ê) over the links in the fit (= σ² r for U = I)
    vf = float(np.sum(e[act] ** 2) / trace_q) if redundancy > 0 and trace_q > 0 else None
    w = w_statistics(e / scale, q)
    return LinkQC(residual_m=e, w=w, q_ll=q, scale_m=scale, variance_factor_m2=vf, redundancy=redundancy,
                  critical_value=critical_value(level), level=level, active=act)


def anchor_covariance(problem: RangingProblem, positions_m: FloatArray, *, objective: str = "metres",
                      active: BoolArray | None = None, variance_m2: float | None = None) -> FloatArray:
    """``(n, dim, dim)`` covariance of every anchor's estimate (zeros for known / held coordinates).

    ``variance_m2`` is the range variance σ² (default: the classical a-posteriori one of :func:`link_tests`)."""
    act = np.ones(problem.n_meas, bool) if active is None else np.asarray(active, bool)
    if variance_m2 is None:
        variance_m2 = link_tests(problem, positions_m, objective=objective, active=act).variance_factor_m2
        if variance_m2 is None:
            raise ModelError("no redundancy: the precision of the anchors cannot be estimated")
    a, _ = metres_design(problem, positions_m)
    u = estimator_weights(problem, objective) * act
    u = u / float(np.mean(u[act]))
    ninv = _normal_inverse(a, u)
    inner = (a.T @ sp.diags(u * u) @ a).toarray()
    cov_x = variance_m2 * (ninv @ inner @ ninv)
    n, d = problem.n_anchors, problem.dim
    out = np.zeros((n, d, d))
    col = np.full(problem.free.shape, -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    for i in np.flatnonzero(problem.estimated):
        axes = np.flatnonzero(col[i] >= 0)
        c = col[i, axes]
        out[i][np.ix_(axes, axes)] = cov_x[np.ix_(c, c)]
    return out


def with_measurements(problem: RangingProblem, keep: BoolArray) -> RangingProblem:
    """The same problem with only the measurements where ``keep`` is True."""
    k = np.asarray(keep, bool)
    return dataclasses.replace(problem, meas_a=problem.meas_a[k], meas_b=problem.meas_b[k], range_m=problem.range_m[k])


@dataclass(frozen=True, eq=False)
class ExclusionOutcome:
    """Result of :func:`exclude_links`: the final positions and tests, the excluded measurements in order
    (``excluded``), those flagged but kept because excluding them would leave the network undetermined
    (``kept_flagged``), and the number of re-solves."""

    positions_m: FloatArray
    tests: LinkQC
    excluded: IntArray
    kept_flagged: IntArray
    rounds: int
    solver_iterations: int
    last: Any


def _determined_without(problem: RangingProblem, active: BoolArray, drop: list[int]) -> bool:
    trial = active.copy()
    trial[drop] = False
    deg = np.bincount(np.concatenate([problem.meas_a[trial], problem.meas_b[trial]]), minlength=problem.n_anchors)
    k_free = problem.free.sum(axis=1)
    if np.any((k_free > 0) & (deg <= k_free)):
        return False
    if problem.n_free > MAX_DENSE_RIGIDITY:
        return True
    return not flexible_anchors(with_measurements(problem, trial)).any()


def exclude_links(problem: RangingProblem, positions_m: FloatArray,
                  solve: Callable[[RangingProblem, FloatArray], tuple[FloatArray, Any, int]], *,
                  objective: str = "metres", level: float = 0.001, max_exclusions: int | None = None,
                  max_rounds: int = 50) -> ExclusionOutcome:
    """Iterative exclusion of the worst link per neighbourhood, re-solving after each round (module docstring).

    ``solve(problem_with_fewer_links, start_positions) -> (positions, result, iterations)`` re-solves."""
    n_meas = problem.n_meas
    cap = max(1, int(0.25 * n_meas)) if max_exclusions is None else int(max_exclusions)
    active = np.ones(n_meas, bool)
    pos = np.asarray(positions_m, float)
    excluded: list[int] = []
    kept: set[int] = set()
    rounds = iters = 0
    last: Any = None
    tests = link_tests(problem, pos, objective=objective, level=level, active=active)
    while rounds < max_rounds and len(excluded) < cap:
        absw = np.where(active, np.abs(np.nan_to_num(tests.w)), 0.0)
        if kept:
            absw[list(kept)] = 0.0  # refused before: never again a candidate, nor the worst of an anchor
        cand = np.flatnonzero(absw > tests.critical_value)
        if cand.size == 0:
            break
        # the worst link at each anchor, among its active links
        worst = np.zeros(problem.n_anchors)
        np.maximum.at(worst, problem.meas_a, absw)
        np.maximum.at(worst, problem.meas_b, absw)
        local = cand[(absw[cand] >= worst[problem.meas_a[cand]]) & (absw[cand] >= worst[problem.meas_b[cand]])]
        drop: list[int] = []
        for c in local[np.argsort(-absw[local])]:
            if len(excluded) + len(drop) >= cap:
                break
            if _determined_without(problem, active, drop + [int(c)]):
                drop.append(int(c))
            else:
                kept.add(int(c))
        if not drop:
            if local.size == 0:
                break
            continue
        active[drop] = False
        excluded += drop
        rounds += 1
        sub_pos, last, k = solve(with_measurements(problem, active), pos)
        pos, iters = np.asarray(sub_pos, float), iters + k
        tests = link_tests(problem, pos, objective=objective, level=level, active=active)
    flagged_kept = np.array(sorted(i for i in kept if active[i]), np.int64)
    return ExclusionOutcome(positions_m=pos, tests=tests, excluded=np.array(excluded, np.int64),
                            kept_flagged=flagged_kept, rounds=rounds, solver_iterations=iters, last=last)
