"""Node-local precision of a distributed UWB solution that admits the neighbours' errors ("neighbourhood").

The conditional covariance of :func:`distnav.algorithms.ranging.qc.local_quality` is ``N_i⁻¹``, anchor ``i``'s
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

— every round each anchor sends its ``dim × dim`` block (packed: the free upper triangle). Every term added is
positive semidefinite, so ``Σ_i⁽ᵗ⁾`` grows monotonically from the conditional value; it is still an
approximation (neither bound): the dropped ``Q_jk`` are mostly positive (neighbours share the errors of the
network's far part) and make it optimistic for anchors far from the known ones; ``Q_jj`` of a neighbour with
neighbours of its own in common with ``i`` counts ``i``'s own noise again. Monte Carlo numbers: docs/uwb.md,
"Per-anchor precision". Linearized at the anchors' own estimates with the final weights of the solver's loss
(fixed IRLS weights, as :func:`~distnav.algorithms.ranging.qc.local_quality`).

**k-hop sub-network** (``hops`` = 1 or 2; ``uwb solve`` uses 2). The same identity holds for any split of the
anchors into ``S`` and the rest ``R``: with ``N_SS`` the principal block of ``S`` (its anchors' own blocks and the
cross terms among them) and ``N_SR`` the cross terms of the links leaving ``S``,

    ``Q_SS = N_SS⁻¹ + N_SS⁻¹ N_SR Q_RR N_RS N_SS⁻¹``   (exact; ``N_SR`` couples ``S`` only to its *ring*).

Anchor ``i`` takes ``S`` = the free anchors within ``hops`` hops and replaces ``Q_RR`` of the ring by its
anchors' neighbourhood blocks ``⊕_v Σ_v`` (a consider covariance of the ring, Bierman 1977 ch. VI): the
cross-covariances *inside* ``S`` are now carried exactly, only those among the ring are dropped. It learns
``N_SS`` and ``N_SR`` from link records ``[v, u, c, Σ w r², samples, Σ_v]`` (``c u uᵀ`` is the link's
information) relayed over ``hops`` rounds of messages (:mod:`~distnav.algorithms.ranging.subnetwork`: each
record once per neighbourhood, in float32). Where ``S`` spans the
network (every anchor within ``hops`` of every other) it is LM's ``(JᵀWJ)⁻¹`` block (tested). Its variance
factor is the local one's over ``S``'s links (a link into the ring counts ½), which is the global ``σ̂²`` where
``S`` spans the network.

**Antenna delays considered** (``delay_sigma_m``): as :mod:`distnav.models.uwb.precision` does for LM (Tapley,
Schutz & Born 2004 §6.4), over ``S``: a delay ``δ_k`` shifts ``JᵀWr`` by ``c u`` at both ends of each of
``k``'s links (``G_S``), so the estimate by ``−N_SS⁻¹ G_S δ`` and ``C_i = s_i² Q_ii + σ_δ² B_i B_iᵀ`` with
``B = N_SS⁻¹ G_S`` and ``s_i²`` the sub-network's factor less the delays' share ``σ_δ² (tr GᵀWG − tr G_Sᵀ
N_SS⁻¹ G_S) / redundancy``. It omits the delays' effect through the ring; where ``S`` spans the network it is
LM's consider covariance (tested).

**Local variance factor.** Each anchor scales its σ by ``σ̂_i² = Σ_l s_l w_l r_l² / (Σ_l s_l − p_i)`` over its own
links, with ``s_l = ½`` for a link to an estimated anchor (the other half is the neighbour's) and 1 to a known one,
``p_i`` its free coordinates (the shares sum to the global ``m − n``). It is robust only through the loss's
weights ``w_l`` (a Cauchy loss gives an NLOS link ``w ≈ 0``) and floored at ``(1/4)²`` (the floor of the local
robust test scale); with no local redundancy it is 1 (the a-priori σ).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import LOSSES, loss_terms, range_loss_scale
from distnav.algorithms.ranging.neighbourhoods import checked_estimates, exchange_for, half_measurements
from distnav.algorithms.ranging.objective import range_sigma
from distnav.algorithms.ranging.qc import free_block_inverses
from distnav.algorithms.ranging.subnetwork import VARIANCE_FLOOR, _send_blocks, _subnetwork
from distnav.algorithms.result import Precision
from distnav.algorithms.statistics import variance_factor
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = ["NeighbourhoodPrecision", "PrecisionOptions", "neighbourhood_precision"]

log = logging.getLogger(__name__)


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
    delay_covariance: np.ndarray | None = None
    noise_factor_nodes: np.ndarray | None = None

    def covariance(self, *, a_posteriori: bool = False) -> np.ndarray:
        """Every anchor's covariance ``(n_anchors, dim, dim)``: the noise part (a-posteriori: × its own ``σ̂_i²``,
        less the delays' share where they are considered) plus the considered delays' part, if any."""
        cov = self.precision.covariance
        if a_posteriori:
            vf = self.variance_factor_nodes if self.noise_factor_nodes is None else self.noise_factor_nodes
            cov = cov * np.nan_to_num(vf, nan=1.0)[:, None, None]
        if self.delay_covariance is not None:
            cov = cov + self.delay_covariance
        return np.asarray(cov)

    def std(self, *, a_posteriori: bool = False) -> np.ndarray:
        """σ per anchor and axis ``(n_anchors, dim)`` from :meth:`covariance`."""
        cov = self.covariance(a_posteriori=a_posteriori)
        return np.asarray(np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0)))


@dataclass(frozen=True, kw_only=True)
class PrecisionOptions:
    """The settings of :func:`neighbourhood_precision` (checked here, :class:`~distnav.errors.ModelError` naming
    the field).

    - ``objective`` (``"metres"``; or ``"squared"``), ``sigma_m`` (1.0, metres, a value or one per range),
      ``loss`` (``"linear"``) and ``loss_scale_m`` (0.3, metres): as the solver that produced the estimates.
    - ``rounds`` (20): at most this many rounds of block messages; ``rtol`` (1e-3): they stop when no σ changed
      by more than that, relative (0 runs all ``rounds``).
    - ``hops`` (0; 1 or 2): the k-hop sub-network covariance.
    - ``delay_sigma_m`` (0.0, metres; > 0 needs ``hops`` ≥ 1): per-anchor antenna delays considered.
    """

    objective: str = "metres"
    sigma_m: float | np.ndarray = 1.0
    loss: str = "linear"
    loss_scale_m: float = 0.3
    rounds: int = 20
    rtol: float = 1e-3
    hops: int = 0
    delay_sigma_m: float = 0.0

    def __post_init__(self) -> None:
        hops, delay_sigma_m = self.hops, self.delay_sigma_m
        if hops not in (0, 1, 2):
            raise ModelError(f"hops must be 0, 1 or 2, got {hops}")
        if not (np.isfinite(delay_sigma_m) and delay_sigma_m >= 0) or (delay_sigma_m > 0 and not hops):
            raise ModelError(f"delay_sigma_m must be ≥ 0 m (and needs hops ≥ 1), got {delay_sigma_m}")
        if self.objective not in ("metres", "squared"):
            raise ModelError(f"objective must be 'metres' or 'squared', got {self.objective!r}")
        if self.loss not in LOSSES:
            raise ModelError(f"unknown loss {self.loss!r}; choose one of {', '.join(LOSSES)}")
        if self.rounds < 0:
            raise ModelError(f"rounds must be ≥ 0, got {self.rounds}")


def neighbourhood_precision(
    problem: RangingData,
    estimates_m: np.ndarray,
    *,
    exchange: Exchange | None = None,
    options: PrecisionOptions | None = None,
    **changes: Any,
) -> NeighbourhoodPrecision:
    """Every anchor's covariance from its own links and its neighbours' blocks (module docstring).

    ``estimates_m``: the anchors' estimates of themselves ``(n_anchors, dim)`` (a distributed solver's
    ``result.estimates``); each block reads only its own rows and learns its neighbours' positions by one
    broadcast. ``options``: :class:`PrecisionOptions` (with keyword ``changes`` to it:
    :func:`distnav._settings.resolve_options`); ``objective`` / ``sigma_m`` / ``loss`` / ``loss_scale_m`` as the
    solver that produced them. ``rounds``: at most this many rounds of block messages; they stop early when no σ
    changed by more than ``rtol`` relative (a one-float max allreduce per round, like the solvers'
    :class:`~distnav.algorithms.ranging.csg.StopRule`; ``rtol=0`` runs all ``rounds``). ``precision.iterations``
    counts the message rounds including the broadcast of the positions. ``hops`` ≥ 1: then the **k-hop
    sub-network** covariance (module docstring) from one more broadcast of the blocks and ``hops`` relay rounds of
    link records (kind ``"neighbourhood"`` still; ``variance_factor_nodes`` then from the sub-network's links).
    ``delay_sigma_m`` > 0 (with ``hops`` ≥ 1): per-anchor antenna delays of that σ are *considered* over the
    sub-network (module docstring).
    """
    o = resolve_options(PrecisionOptions, options, changes)
    est = checked_estimates(problem, estimates_m)
    ex = exchange_for(problem, exchange)
    before = ex.comm_totals().snapshot()
    own = est[ex.nodes]
    if not np.all(np.isfinite(own)):
        raise ModelError("estimates are not finite (a diverged run has no precision)")
    lk = _Linearized.at(problem, ex, own, o)
    free = problem.free[ex.nodes]
    cond = free_block_inverses(lk.info, free)
    vf_i = _local_variance_factor(problem, ex, lk, free)
    cov, change, done = _block_rounds(ex, cond, lk.cross, free, o.rounds, o.rtol)
    if change > o.rtol:
        log.info("neighbourhood precision: σ still changing by %.3g after %d rounds", change, done)
    delay_cov = noise_f = None
    if o.hops:
        cov, vf_i, delay_cov, noise_f = _subnetwork(
            problem, ex, o.hops, cov, cond, lk.pos, lk.cross.shape[0], lk.j_own, lk.w, lk.r, free, o.delay_sigma_m
        )
        done += 1 + o.hops
    w, r = lk.w, lk.r
    wssr = float(ex.allreduce(float(np.sum(w * r * r)), "sum")) / 2.0  # every sample is held twice
    m_red = float(max(problem.n_meas - problem.n_free, 0))
    vf = variance_factor(wssr, m_red)
    precision = Precision.gathered(
        ex, cov, before, variance_factor=vf, redundancy=m_red, kind="neighbourhood", iterations=done + 1
    )
    return NeighbourhoodPrecision(
        precision=precision,
        variance_factor_nodes=ex.gather_nodes(vf_i),
        conditional=ex.gather_nodes(cond),
        change=change,
        delay_covariance=None if delay_cov is None else ex.gather_nodes(delay_cov),
        noise_factor_nodes=None if noise_f is None else ex.gather_nodes(noise_f),
    )


@dataclass(frozen=True, eq=False)
class _Linearized:
    """The block's half-measurements linearized at the anchors' own estimates: the in-edge of each (``pos``,
    ``owner``, ``other``), whitened Jacobian rows (own end, free coordinates only), residuals, IRLS weights, every
    anchor's own information ``N_i`` and the cross blocks ``O_ij`` per in-edge."""

    pos: np.ndarray
    owner: np.ndarray
    other: np.ndarray
    j_own: np.ndarray
    r: np.ndarray
    w: np.ndarray
    info: np.ndarray
    cross: np.ndarray

    @staticmethod
    def at(problem: RangingData, ex: Exchange, own: np.ndarray, o: PrecisionOptions) -> _Linearized:
        """One broadcast of the own estimates; the rest is local."""
        dim, n, nl = problem.dim, problem.n_anchors, ex.n_local
        pos_in = ex.broadcast(own)  # every anchor learns its neighbours' own estimates
        # in-edge of every half-measurement: receiver = owner (local), sender = the other end (global)
        in_key = pos_in.dst * n + pos_in.src
        order = np.argsort(in_key, kind="stable")
        owner, other, _, samp = half_measurements(problem, ex)
        want = owner * n + other
        pos = order[np.minimum(np.searchsorted(in_key[order], want), order.size - 1)]
        if order.size == 0 or not np.all(in_key[pos] == want) or not np.all(pos_in.delivered[pos]):
            raise ModelError("a ranged pair is not an edge of the exchange's graph (or its message was lost)")
        sigma = range_sigma(problem, o.sigma_m)[samp]
        diff = own[owner] - pos_in.values[pos]
        dist = np.linalg.norm(diff, axis=1)
        if o.objective == "metres":
            j = diff / (np.where(dist > 0, dist, np.inf) * sigma)[:, None]
            r = (dist - problem.range_m[samp]) / sigma
            scale = o.loss_scale_m / sigma
        else:
            j = 2.0 * diff
            r = dist * dist - problem.range_m[samp] ** 2
            scale = range_loss_scale(problem, o.loss_scale_m)[samp] if o.loss != "linear" else np.ones(samp.size)
        w = loss_terms(r, scale, o.loss)[0]
        free_own = problem.free[ex.nodes[owner]]
        j_own = j * free_own
        j_oth = j * problem.free[other]
        info = np.zeros((nl, dim, dim))
        np.add.at(info, owner, w[:, None, None] * j_own[:, :, None] * j_own[:, None, :])
        cross = np.zeros((pos_in.values.shape[0], dim, dim))  # O_ij per in-edge (i = receiver, j = sender)
        np.add.at(cross, pos, -w[:, None, None] * j_own[:, :, None] * j_oth[:, None, :])
        return _Linearized(pos, owner, other, j_own, r, w, info, cross)


def _local_variance_factor(problem: RangingData, ex: Exchange, lk: _Linearized, free: np.ndarray) -> np.ndarray:
    """Every local anchor's σ̂_i² from its share of its links (module docstring; NaN at known anchors)."""
    w, r, owner, nl = lk.w, lk.r, lk.owner, ex.n_local
    share = np.where(problem.fixed[lk.other], 1.0, 0.5)
    wssr_i = np.bincount(owner, share * w * r * r, minlength=nl)
    red_i = np.bincount(owner, share, minlength=nl) - free.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        vf_i = np.where(red_i > 0, np.maximum(wssr_i / red_i, VARIANCE_FLOOR), 1.0)
    return np.asarray(np.where(free.any(axis=1), vf_i, np.nan))


def _block_rounds(
    ex: Exchange, cond: np.ndarray, cross: np.ndarray, free: np.ndarray, rounds: int, rtol: float
) -> tuple[np.ndarray, float, int]:
    """``Σ_i⁽ᵗ⁺¹⁾ = N_i⁻¹ + N_i⁻¹ (Σ_j O_ij Σ_j⁽ᵗ⁾ O_ji) N_i⁻¹`` from ``Σ⁽⁰⁾ = N_i⁻¹`` (one message of the packed
    blocks on every link a round, :func:`_send_blocks`) until no σ changes by more than ``rtol``: ``(Σ, the last
    change, rounds run)``."""
    nl, dim = cond.shape[0], cond.shape[1]
    cov = cond.copy()
    change = float("inf") if rounds else 0.0
    done = 0
    with np.errstate(invalid="ignore", over="ignore"):
        while done < rounds and change > rtol:
            nb = _send_blocks(ex, cov, free)[1]
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
    return cov, change, done
