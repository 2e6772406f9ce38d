"""Node-local precision of a distributed UWB solution that admits the neighbours' errors ("neighbourhood").

The conditional covariance of :func:`distnav.algorithms.ranging_qc.local_quality` is ``N_i⁻¹``, anchor ``i``'s
own information ``N_i = Σ_{l∈E(i)} w_l j_l j_lᵀ`` inverted with its neighbours held at their estimates: a lower
bound (on an 18-anchor hall 0.73× the central σ). The central covariance is ``Q = N⁻¹`` of the whole normal
matrix ``N = D + O`` (``D`` = the block diagonal ``N_i``, ``O`` = the cross blocks ``O_ij = −Σ_{l∈(i,j)} w_l
j_l j_lᵀ`` of the links). From ``N⁻¹ = D⁻¹ − D⁻¹ O N⁻¹`` and ``N⁻¹ = D⁻¹ − N⁻¹ O D⁻¹``,

    ``N⁻¹ = D⁻¹ − D⁻¹ O D⁻¹ + D⁻¹ O N⁻¹ O D⁻¹``,

and since ``O_ii = 0`` its ``i``-th diagonal block is exactly

    ``Q_ii = N_i⁻¹ + N_i⁻¹ (Σ_{j,k∈N(i)} O_ij Q_jk O_ki) N_i⁻¹``

(the block-Jacobi splitting; the same form as a first-order *consider* covariance, Bierman 1977 ch. VI: the
state's own noise plus the effect of the "considered" parameters — the neighbours — through the cross terms).
Anchor ``i`` knows ``N_i`` and ``O_ij`` from its own links; it does not know the cross-covariances ``Q_jk``
(``j ≠ k``) of its neighbours, so they are **dropped** (``⊕_j Q_jj``) and the neighbours' own ``Q_jj`` are
replaced by their current estimates, iterated over rounds of messages:

    ``Σ_i⁽⁰⁾ = N_i⁻¹``,  ``Σ_i⁽ᵗ⁺¹⁾ = N_i⁻¹ + N_i⁻¹ (Σ_{j∈N(i)} O_ij Σ_j⁽ᵗ⁾ O_ji) N_i⁻¹``

— every round each anchor broadcasts its ``dim × dim`` block (``dim²`` floats per link). Every term added is
positive semidefinite, so ``Σ_i⁽ᵗ⁾`` grows monotonically from the conditional value; it is still an
approximation (neither bound): the dropped ``Q_jk`` are mostly positive (neighbours share the errors of the
network's far part) and make it optimistic for anchors far from the known ones; ``Q_jj`` of a neighbour with
neighbours of its own in common with ``i`` counts ``i``'s own noise again. Monte Carlo numbers: docs/uwb.md,
"Per-anchor precision". Linearized at the anchors' own estimates with the final weights of the solver's loss
(fixed IRLS weights, as :func:`~distnav.algorithms.ranging_qc.local_quality`).

**Local variance factor.** Each anchor scales its σ by ``σ̂_i² = Σ_l s_l w_l r_l² / (Σ_l s_l − p_i)`` over its own
links, with ``s_l = ½`` for a link to an estimated anchor (the other half is the neighbour's) and 1 to a known one,
``p_i`` its free coordinates (the shares sum to the global ``m − n``). It is robust only through the loss's
weights ``w_l`` (a Cauchy loss gives an NLOS link ``w ≈ 0``) and floored at ``(1/4)²`` (the floor of the local
robust test scale); with no local redundancy it is 1 (the a-priori σ).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from distnav.algorithms.neighbourhood import exchange_for, half_measurements
from distnav.algorithms.nlsq import LOSSES, loss_terms, range_loss_scale
from distnav.algorithms.ranging import RangingData
from distnav.algorithms.ranging_objective import range_sigma
from distnav.algorithms.ranging_qc import free_block_inverses
from distnav.algorithms.result import Precision
from distnav.algorithms.statistics import variance_factor
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = ["NeighbourhoodPrecision", "neighbourhood_precision"]

log = logging.getLogger(__name__)
VARIANCE_FLOOR = 1.0 / 16.0


@dataclass(frozen=True, eq=False, kw_only=True)
class NeighbourhoodPrecision:
    """The result of :func:`neighbourhood_precision`.

    ``precision``: kind ``"neighbourhood"``, covariances at σ² = 1 (gathered for the result; computed locally),
    ``variance_factor`` the global σ̂² (an allreduce, for monitoring). ``variance_factor_nodes``: every anchor's
    local σ̂_i² (module docstring; NaN at known anchors). ``conditional``: the round-0 ``N_i⁻¹`` (kind
    ``"conditional"``) for comparison. ``change``: the largest relative change of a σ in the last round.
    """

    precision: Precision
    variance_factor_nodes: np.ndarray
    conditional: np.ndarray
    change: float

    def std(self, *, a_posteriori: bool = False) -> np.ndarray:
        """σ per anchor and axis ``(n_anchors, dim)``; a-posteriori: × every anchor's own ``σ̂_i``."""
        s = self.precision.std()
        if a_posteriori:
            s = s * np.sqrt(np.nan_to_num(self.variance_factor_nodes, nan=1.0))[:, None]
        return np.asarray(s)


def neighbourhood_precision(problem: RangingData, estimates_m: np.ndarray, *, exchange: Exchange | None = None,
                            objective: str = "metres", sigma_m: float | np.ndarray = 1.0, loss: str = "linear",
                            loss_scale_m: float = 0.3, rounds: int = 20, rtol: float = 1e-3
                            ) -> NeighbourhoodPrecision:
    """Every anchor's covariance from its own links and its neighbours' blocks (module docstring).

    ``estimates_m``: the anchors' estimates of themselves ``(n_anchors, dim)`` (a distributed solver's
    ``result.estimates``); each block reads only its own rows and learns its neighbours' positions by one
    broadcast. ``objective`` / ``sigma_m`` / ``loss`` / ``loss_scale_m`` as the solver that produced them.
    ``rounds``: at most this many rounds of block messages; they stop early when no σ changed by more than
    ``rtol`` relative (a one-float max allreduce per round, like the solvers' :class:`~distnav.algorithms.csg.
    StopRule`; ``rtol=0`` runs all ``rounds``). ``precision.iterations`` counts the message rounds including the
    broadcast of the positions.
    """
    if objective not in ("metres", "squared"):
        raise ModelError(f"objective must be 'metres' or 'squared', got {objective!r}")
    if loss not in LOSSES:
        raise ModelError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    if rounds < 0:
        raise ModelError(f"rounds must be ≥ 0, got {rounds}")
    est = np.asarray(estimates_m, float)
    if est.shape != (problem.n_anchors, problem.dim):
        raise ModelError(f"estimates must have shape ({problem.n_anchors}, {problem.dim}), got {est.shape}")
    ex = exchange_for(problem, exchange)
    before = ex.comm_totals().snapshot()
    dim, n, nl = problem.dim, problem.n_anchors, ex.n_local
    own = est[ex.nodes]
    if not np.all(np.isfinite(own)):
        raise ModelError("estimates are not finite (a diverged run has no precision)")
    pos_in = ex.broadcast(own)  # every anchor learns its neighbours' own estimates
    # in-edge of every half-measurement: receiver = owner (local), sender = the other end (global)
    in_key = pos_in.dst * n + pos_in.src
    order = np.argsort(in_key, kind="stable")
    owner, other, _, samp = half_measurements(problem, ex)
    want = owner * n + other
    pos = order[np.minimum(np.searchsorted(in_key[order], want), order.size - 1)]
    if order.size == 0 or not np.all(in_key[pos] == want) or not np.all(pos_in.delivered[pos]):
        raise ModelError("a ranged pair is not an edge of the exchange's graph (or its message was lost)")
    sigma = range_sigma(problem, sigma_m)[samp]
    diff = own[owner] - pos_in.values[pos]
    dist = np.linalg.norm(diff, axis=1)
    if objective == "metres":
        j = diff / (np.where(dist > 0, dist, np.inf) * sigma)[:, None]
        r = (dist - problem.range_m[samp]) / sigma
        scale = loss_scale_m / sigma
    else:
        j = 2.0 * diff
        r = dist * dist - problem.range_m[samp] ** 2
        scale = range_loss_scale(problem, loss_scale_m)[samp] if loss != "linear" else np.ones(samp.size)
    w = loss_terms(r, scale, loss)[0]
    free_own = problem.free[ex.nodes[owner]]
    j_own = j * free_own
    j_oth = j * problem.free[other]
    info = np.zeros((nl, dim, dim))
    np.add.at(info, owner, w[:, None, None] * j_own[:, :, None] * j_own[:, None, :])
    cross = np.zeros((pos_in.values.shape[0], dim, dim))  # O_ij per in-edge (i = receiver, j = sender)
    np.add.at(cross, pos, -w[:, None, None] * j_own[:, :, None] * j_oth[:, None, :])
    free = problem.free[ex.nodes]
    cond = free_block_inverses(info, free)
    # local variance factor from the anchor's share of its links
    share = np.where(problem.fixed[other], 1.0, 0.5)
    wssr_i = np.bincount(owner, share * w * r * r, minlength=nl)
    red_i = np.bincount(owner, share, minlength=nl) - free.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        vf_i = np.where(red_i > 0, np.maximum(wssr_i / red_i, VARIANCE_FLOOR), 1.0)
    vf_i = np.where(free.any(axis=1), vf_i, np.nan)
    cov = cond.copy()
    change = float("inf") if rounds else 0.0
    done = 0
    with np.errstate(invalid="ignore", over="ignore"):
        while done < rounds and change > rtol:
            nb = ex.broadcast(cov.reshape(nl, dim * dim))
            s_nb = nb.values.reshape(-1, dim, dim)
            term = np.einsum("eab,ebc,edc->ead", cross, s_nb, cross)  # O_ij Σ_j O_ijᵀ (O_ji = O_ijᵀ)
            total = np.zeros((nl, dim, dim))
            np.add.at(total, nb.dst[nb.delivered], term[nb.delivered])
            new = cond + np.einsum("lab,lbc,ldc->lad", cond, total, cond)
            s_old = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
            s_new = np.sqrt(np.maximum(np.diagonal(new, axis1=1, axis2=2), 0.0))
            rel = np.where(s_new > 0, np.abs(s_new - s_old) / np.where(s_new > 0, s_new, 1.0), 0.0)
            change = float(ex.allreduce(float(np.nan_to_num(rel, nan=np.inf).max(initial=0.0)), "max"))
            cov = new
            done += 1
    if change > rtol:
        log.info("neighbourhood precision: σ still changing by %.3g after %d rounds", change, done)
    wssr = float(ex.allreduce(float(np.sum(w * r * r)), "sum")) / 2.0  # every sample is held twice
    m_red = float(max(problem.n_meas - problem.n_free, 0))
    precision = Precision(covariance=ex.gather_nodes(cov), variance_factor=variance_factor(wssr, m_red),
                          redundancy=m_red, kind="neighbourhood", iterations=done + 1,
                          comm=ex.comm_totals().since(before))
    return NeighbourhoodPrecision(precision=precision, variance_factor_nodes=ex.gather_nodes(vf_i),
                                  conditional=ex.gather_nodes(cond), change=change)
