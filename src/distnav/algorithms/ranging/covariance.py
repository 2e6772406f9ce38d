"""LM's central per-anchor covariance, computed by the anchors through the exchange (issue 13 item 3).

The 2-hop sub-network σ of :mod:`distnav.algorithms.ranging.precision` cut the chain to the known anchors: on
plant-like halls with the known anchors in a corner they were 0.67–0.88 × LM's central σ and covered 2σ in 85 %
(docs/uwb.md, "Distributed solvers in the workflow"). Here every anchor obtains its own block of LM's

    ``C = σ̂²_noise Q + σ_δ² B Bᵀ``,   ``Q = (JᵀWJ)⁻¹``,   ``B = Q JᵀW G``

(:mod:`distnav.models.uwb.precision`: the a-posteriori variance factor, the per-anchor antenna delays
*considered*, Tapley, Schutz & Born 2004 §6.4; the unknowns are LM's: the free coordinates and the common or
per-anchor range offsets) by solving ``N X = [E, JᵀWG]`` with **conjugate gradients on all the right-hand sides
at once**: ``E`` holds one unit column per free coordinate of the network (anchor ``i`` needs ``X``'s rows of its
own coordinates in its own columns, ``Q_ii``), ``JᵀWG`` one column per anchor's delay (each anchor's rows are its
own links: local). Every CG iteration is one matrix–product round of :class:`~distnav.algorithms.ranging.refine.
NormalSystem` (the final distributed LM phase's product, undamped) — a broadcast of ``P · k`` floats per link,
``k = n_free + n`` columns — plus two network totals of ``2k`` floats per anchor (the CG scalars of every column;
in-process and MPI assemble them in the anchors' order, so the bits agree). Each anchor then holds ``X``'s rows of
its own parameters: ``Q_ii`` and ``B_i`` directly, so ``C_ii`` is local. Network totals besides: ``Σ w r²``
(σ̂²), the delays' share ``tr GᵀWG − tr (JᵀWG)ᵀB`` and, with ``estimate_delays``, the two-component variance
estimate of :func:`~distnav.models.uwb.precision.delay_sigma_estimate` (Koch 1999 §3.6), whose ``tr A²`` needs
the whole ``n × n`` matrix ``A = GᵀWG − (JᵀWG)ᵀB``: one reduction of ``n²`` floats.

**Cost** (the reason for :data:`CENTRAL_MAX_ANCHORS`): a message of ``P (n_free + n)`` floats (the held heights
travel as zeros) for about ``n_free`` CG rounds (CG ends within as many iterations as unknowns in exact arithmetic;
:data:`COVARIANCE_CG_RTOL` per column), i.e. ``O(n²)`` floats per link and ``O(n³)`` over the network. Measured on plant
corner #0 of ``reproduce uwb-field`` (28 anchors, 3-D, heights held, ``3 · 84 · 8 = 2.0 kB`` per message): 40 CG
rounds, 14 k messages, 22 MB with the reductions (the 2-hop σ: 2.3 k, 4.0 MB; the solve itself 62 MB). At 100
anchors about 7 kB × 160 rounds × 750 links ≈ 0.9 GB; at 1,000 anchors 72 kB × 1,600 rounds × 15,000 links ≈ 2 TB.
Above the limit the caller keeps the 2-hop sub-network σ (``O(degree²)`` floats per link in a few rounds).
Why not a probing / Lanczos estimate of ``diag Q``: it gives the variances only approximately (a Hutchinson
estimate's error falls as 1/√probes, each probe a CG solve of its own) and not the delays' ``B``; the exact
columns are affordable for tens of anchors, which is where a central σ matters (the chain to the known ones).
Linearized at the anchors' estimates with the fit's loss weights (fixed IRLS weights), the metres objective only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from distnav._settings import resolve_options
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import LOSSES, loss_terms
from distnav.algorithms.ranging.neighbourhoods import checked_estimates, exchange_for
from distnav.algorithms.ranging.objective import range_sigma
from distnav.algorithms.ranging.refine import Links, NormalSystem, block_preconditioner, jacobian_rows, pcg
from distnav.algorithms.ranging.wire import Reductions, reduction_cost
from distnav.algorithms.result import Precision
from distnav.algorithms.statistics import variance_factor
from distnav.errors import ModelError
from distnav.exchange import Exchange

__all__ = [
    "CentralPrecision",
    "CentralPrecisionOptions",
    "central_precision",
    "CENTRAL_MAX_ANCHORS",
    "COVARIANCE_CG_RTOL",
    "ECONOMY_CG_RTOL",
    "ECONOMY_WIRE_DTYPE",
]

CENTRAL_MAX_ANCHORS = 100  # above: messages of > 7 kB for > 160 rounds (≈ 0.9 GB); the 2-hop σ instead (docstring)
COVARIANCE_CG_RTOL = 1e-10  # per column, relative to its right-hand side
ECONOMY_CG_RTOL = 1e-6  # the field workflow's σ (issue 27): float32 directions reach it, σ within 1e-5 relative
ECONOMY_WIRE_DTYPE = np.float32
MIN_NOISE_SHARE = 0.1  # the noise part keeps at least this share of σ̂² (also LM's: models/uwb/precision.py)
ESTIMATE_MAX_ANCHORS = 200  # the n × n reduction of the delay estimate (LM: m ≤ 2000 rows)


@dataclass(frozen=True, eq=False, kw_only=True)
class CentralPrecision:
    """The result of :func:`central_precision`. ``precision``: kind ``"central"``, the blocks of ``Q`` (σ² = 1),
    gathered for the result (each computed by its anchor), ``variance_factor`` σ̂², ``comm`` the exchange's
    broadcasts. ``delay_covariance``: ``σ_δ² B_i B_iᵀ`` per anchor (None without delays), ``noise_factor``
    σ̂²_noise, ``delay_sigma_m`` the σ_δ used (the prior or the larger estimate). ``cg_iterations``, ``columns``
    and the network reductions (``reduced``) for the cost."""

    precision: Precision
    delay_covariance: np.ndarray | None
    noise_factor: float
    delay_sigma_m: float
    cg_iterations: int
    columns: int
    reduced: Reductions

    def covariance(self, *, a_posteriori: bool = False) -> np.ndarray:
        """Every anchor's covariance ``(n_anchors, dim, dim)``: ``Q_ii`` (a-posteriori: ``σ̂²_noise Q_ii`` plus
        the considered delays' part)."""
        cov = self.precision.covariance
        if not a_posteriori:
            return np.asarray(cov)
        cov = cov * self.noise_factor
        return np.asarray(cov if self.delay_covariance is None else cov + self.delay_covariance)

    def std(self, *, a_posteriori: bool = False) -> np.ndarray:
        """σ per anchor and axis ``(n_anchors, dim)`` from :meth:`covariance`."""
        cov = self.covariance(a_posteriori=a_posteriori)
        return np.asarray(np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0)))

    def reduction_cost(self, n_anchors: int) -> tuple[int, int]:
        """Messages and bytes of the network totals as spanning-tree reductions (up and down: ``2(n − 1)``
        messages each, carrying the reduced floats)."""
        return reduction_cost(n_anchors, self.reduced.count, 8 * self.reduced.floats)


@dataclass(frozen=True, kw_only=True)
class CentralPrecisionOptions:
    """What :func:`central_precision` computes with, checked once (defaults in brackets).

    ``sigma_m`` [1] / ``loss`` [linear] / ``loss_scale_m`` [0.3]: the fit's. ``range_offsets`` [none]: ``common``
    or ``per_anchor`` (prior σ ``offset_prior_sigma_m`` [0.1 m]). ``delay_sigma_m`` [0] > 0 (not with per-anchor
    offsets): delays considered; ``estimate_delays`` [False]: that σ is a floor, the residuals' estimate is used
    where larger (as LM, :func:`distnav.models.uwb.precision.consider_precision`; ``delay_upper_z`` [0]: the
    estimate plus that many of its standard deviations, LM's ``DELAY_UPPER_Z`` in the field workflow).
    ``variance_scale_m`` [None: ``loss_scale_m``]: the loss scale of σ̂²'s weights where the fit's own differs (LM's
    σ̂² is its fit's; the field workflow's polish fits at 0.3 m, its σ at the tight scale). ``max_iterations``
    [``2 n_unknowns + 20``]: CG rounds; a column not converged raises ModelError. ``rtol``
    [:data:`COVARIANCE_CG_RTOL`] and ``wire_dtype`` [float64]: the CG vectors on the wire
    (:mod:`~distnav.algorithms.ranging.wire`); the field workflow uses :data:`ECONOMY_WIRE_DTYPE` with
    :data:`ECONOMY_CG_RTOL` (issue 27: 0.64 × the bytes of float64 at ``1e-10``, σ within 1e-5 relative of it on
    plant-like halls, docs/economy_uwb.md); where its CG does not converge the columns are solved once more in
    float64 to :data:`COVARIANCE_CG_RTOL` (both runs counted)."""

    sigma_m: float | np.ndarray = 1.0
    loss: str = "linear"
    loss_scale_m: float = 0.3
    range_offsets: str = "none"
    offset_prior_sigma_m: float = 0.1
    delay_sigma_m: float = 0.0
    estimate_delays: bool = False
    rtol: float = COVARIANCE_CG_RTOL
    max_iterations: int | None = None
    variance_scale_m: float | None = None
    delay_upper_z: float = 0.0
    wire_dtype: type[np.floating] = np.float64

    def __post_init__(self) -> None:
        _checked_options(self.loss, self.range_offsets, self.delay_sigma_m, self.loss_scale_m)


def central_precision(
    problem: RangingData,
    estimates_m: np.ndarray,
    *,
    offset_m: float | np.ndarray | None = None,
    exchange: Exchange | None = None,
    options: CentralPrecisionOptions | None = None,
    **changes: Any,
) -> CentralPrecision:
    """Every anchor's block of LM's central a-posteriori covariance through the exchange (module docstring).

    ``estimates_m`` ``(n_anchors, dim)``: the anchors' own estimates (each block reads its rows); ``offset_m``:
    the common offset (``range_offsets="common"``) or every anchor's own (``"per_anchor"``), as the solver
    estimated them; ``options``: :class:`CentralPrecisionOptions`, with keyword ``changes`` to it."""
    o = resolve_options(CentralPrecisionOptions, options, changes)
    per, common = o.range_offsets == "per_anchor", o.range_offsets == "common"
    est = checked_estimates(problem, estimates_m)
    ex = exchange_for(problem, exchange)
    before = ex.comm_totals().snapshot()
    links = Links(problem, ex, per_anchor_offsets=per)
    owner, other, samp = links.owner, links.other, links.samp
    dim, n, nl = problem.dim, problem.n_anchors, ex.n_local
    x, c = _anchor_state(est, ex.nodes, dim, per, common, offset_m)
    P = x.shape[1]
    free, free_nb = _free_masks(problem.free, ex.nodes, other, P)
    prior = 1.0 / o.offset_prior_sigma_m**2 if per else 0.0
    sig = range_sigma(problem, o.sigma_m)[samp]
    nb = links.neighbours(x)  # one broadcast: the neighbours' estimates (and offsets)
    bias = (x[owner, dim] + nb[:, dim]) if per else c
    r = (np.linalg.norm(x[owner, :dim] - nb[:, :dim], axis=1) + bias - problem.range_m[samp]) / sig
    w = loss_terms(r, o.loss_scale_m / sig, o.loss)[0]
    a, cn, e = jacobian_rows(x, nb, owner, sig, dim, per, common, free, free_nb)
    pre_inv = _preconditioner(owner, w, a, free, dim, prior if per else None)
    delays = o.delay_sigma_m > 0
    col, b, bc = _right_hand_sides(problem, ex, links, w, sig, a, e, free, common, delays)
    dc = float(links.total(0.5 * np.bincount(owner, w * e * e, minlength=nl))) if common else 1.0
    n_unknowns = int(links.total(free.sum(axis=1).astype(float))) + (1 if common else 0)
    its_max = 2 * n_unknowns + 20 if o.max_iterations is None else o.max_iterations

    def system(dtype: type[np.floating]) -> NormalSystem:
        return NormalSystem(links, owner, a, cn, e, w, np.zeros((nl, P)), 0.0, prior, free, common, dtype)

    tries = [(o.wire_dtype, o.rtol)] + ([(np.float64, COVARIANCE_CG_RTOL)] if o.wire_dtype != np.float64 else [])
    X, Xc, its = _solve_columns(system, tries, links, b, bc, pre_inv, dc, its_max, free, common)
    blocks = _own_blocks(X, free, col[ex.nodes], dim)
    # a-posteriori variance factor over LM's rows (the ranges and, per anchor, the offsets' priors)
    w_vf = w if o.variance_scale_m is None else loss_terms(r, o.variance_scale_m / sig, o.loss)[0]
    wssr_node = 0.5 * np.bincount(owner, w_vf * r * r, minlength=nl) + (prior * x[:, dim] ** 2 if per else 0.0)
    m_rows = problem.n_meas + (n if per else 0)
    redundancy = float(m_rows - n_unknowns)
    totals = links.total(
        np.c_[
            wssr_node, np.bincount(owner, w / sig**2, minlength=nl), 0.5 * np.bincount(owner, w * r * r, minlength=nl)
        ]
    )  # σ̂²'s, tr GᵀWG, ẽᵀẽ
    vf = variance_factor(float(totals[0]), redundancy)
    s2 = 1.0 if vf is None else vf
    delay_sigma_used_m, s2, delay_cov = o.delay_sigma_m, s2, None
    if delays:
        delay_sigma_used_m, s2, delay_cov = _delay_part(
            o, problem, ex, links, (w, r, sig), (X, Xc, b, bc), totals, redundancy, free, s2
        )
    precision = Precision.gathered(
        ex, blocks, before, variance_factor=vf, redundancy=redundancy, kind="central", iterations=its + 2
    )
    return CentralPrecision(
        precision=precision,
        delay_covariance=None if delay_cov is None else ex.gather_nodes(delay_cov),
        noise_factor=s2,
        delay_sigma_m=delay_sigma_used_m,
        cg_iterations=its,
        columns=bc.size,
        reduced=links.counted(),
    )


def _checked_options(loss: str, range_offsets: str, delay_sigma_m: float, loss_scale_m: float) -> tuple[bool, bool]:
    """Refuse by name what :func:`central_precision` cannot use; returns ``(per-anchor offsets, common offset)``."""
    if loss not in LOSSES:
        raise ModelError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    if range_offsets not in ("none", "common", "per_anchor"):
        raise ModelError(f"range_offsets must be 'none', 'common' or 'per_anchor', got {range_offsets!r}")
    per, common = range_offsets == "per_anchor", range_offsets == "common"
    if not (np.isfinite(delay_sigma_m) and delay_sigma_m >= 0) or (delay_sigma_m > 0 and per):
        raise ModelError(f"delay_sigma_m must be ≥ 0 m (and not with per-anchor offsets), got {delay_sigma_m}")
    if not loss_scale_m > 0:
        raise ModelError(f"loss_scale_m must be positive, got {loss_scale_m}")
    return per, common


def _anchor_state(
    est: np.ndarray, nodes: np.ndarray, dim: int, per: bool, common: bool, offset_m: float | np.ndarray | None
) -> tuple[np.ndarray, float]:
    """The block's anchors' unknowns ``x`` ``(n_local, dim [+ 1 per-anchor offset])`` and the common offset ``c``."""
    n = est.shape[0]
    x = np.zeros((nodes.size, dim + (1 if per else 0)))
    x[:, :dim] = est[nodes]
    c = 0.0
    if per:
        off = np.asarray(offset_m, float) if offset_m is not None else np.zeros(0)
        if off.shape != (n,):
            raise ModelError(f"per-anchor offsets must have shape ({n},), got {off.shape}")
        x[:, dim] = off[nodes]
    elif common:
        c = float(np.mean(np.asarray(offset_m if offset_m is not None else 0.0, float)))
    if not (np.all(np.isfinite(x)) and np.isfinite(c)):
        raise ModelError("estimates are not finite (a diverged run has no precision)")
    return x, c


def _right_hand_sides(
    problem: RangingData,
    ex: Exchange,
    links: Links,
    w: np.ndarray,
    sig: np.ndarray,
    a: np.ndarray,
    e: np.ndarray,
    free: np.ndarray,
    common: bool,
    delays: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The CG columns: every free coordinate of the network (anchor by anchor, as LM's ``x``), then every anchor's
    delay (``JᵀWG``: a link's row at both ends' delays, 1/σ at each; the common offset's row a network total).
    Returns ``(col`` (n, dim) column of each free coordinate, ``b`` (n_local, P, k), ``bc`` (k,) the offset's row)."""
    owner, other = links.owner, links.other
    n, dim, nl, P = problem.n_anchors, problem.dim, ex.n_local, free.shape[1]
    col = np.full((n, dim), -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    k = problem.n_free + (n if delays else 0)
    b = np.zeros((nl, P, k))
    li, ai = np.nonzero(problem.free[ex.nodes])
    b[li, ai, col[ex.nodes[li], ai]] = 1.0
    bc = np.zeros(k)
    if delays:
        wa = (w / sig)[:, None] * a
        for p_ in range(P):
            np.add.at(b[:, p_, :], (owner, problem.n_free + ex.nodes[owner]), wa[:, p_])
            np.add.at(b[:, p_, :], (owner, problem.n_free + other), wa[:, p_])
        if common:
            hc = np.zeros((nl, n))
            np.add.at(hc, (owner, ex.nodes[owner]), 0.5 * w * e / sig)
            np.add.at(hc, (owner, other), 0.5 * w * e / sig)
            bc[problem.n_free :] = links.total(hc)
        b = np.where(free[:, :, None], b, 0.0)
    return col, b, bc


def _solve_columns(
    system: Any,
    tries: list[tuple[Any, float]],
    links: Links,
    b: np.ndarray,
    bc: np.ndarray,
    pre_inv: np.ndarray,
    dc: float,
    its_max: int,
    free: np.ndarray,
    common: bool,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Preconditioned CG on every column, for each ``(wire dtype, tolerance)`` of ``tries`` until the columns'
    final residuals (one product more, a network total) reach it; ModelError when none does."""
    k = bc.size
    worst, its = float("inf"), 0
    for dtype, tol in tries:
        sys_ = system(dtype)
        X, Xc, its = pcg(sys_, b, bc, pre_inv, dc, links, its_max, rtol=tol)
        q, q_share = sys_.matvec(X, Xc)
        resid = np.where(free[:, :, None], b - q, 0.0)
        t = links.total(
            np.concatenate([np.einsum("nak,nak->nk", resid, resid), np.einsum("nak,nak->nk", b, b), q_share], axis=1)
        )
        rc = bc - t[2 * k :] if common else np.zeros(k)
        worst = float(np.max(np.sqrt((t[:k] + rc * rc) / np.maximum(t[k : 2 * k] + bc * bc, 1e-300)), initial=0.0))
        if worst <= max(100.0 * tol, 1e-8):
            return X, Xc, its
    raise ModelError(f"central precision: CG did not converge (relative residual {worst:.2g} after {its})")


def _own_blocks(X: np.ndarray, free: np.ndarray, own_col: np.ndarray, dim: int) -> np.ndarray:
    """Each local anchor's ``dim × dim`` covariance block from the solved columns (its free coordinates' own
    columns ``own_col``), symmetrized."""
    blocks = np.zeros((X.shape[0], dim, dim))
    for a_ in range(dim):
        for b_ in range(dim):
            ok = free[:, a_] & free[:, b_]
            blocks[ok, a_, b_] = X[np.flatnonzero(ok), a_, own_col[ok, b_]]
    return 0.5 * (blocks + blocks.transpose(0, 2, 1))


def _delay_part(
    o: CentralPrecisionOptions,
    problem: RangingData,
    ex: Exchange,
    links: Links,
    fit: tuple[np.ndarray, np.ndarray, np.ndarray],
    solved: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    totals: np.ndarray,
    redundancy: float,
    free: np.ndarray,
    s2: float,
) -> tuple[float, float, np.ndarray]:
    """The delays' share of σ̂² and their covariance blocks (considered, or estimated from the residuals with
    ``o.delay_sigma_m`` as floor): ``(delay σ used, noise factor, delay covariance blocks)``. ``fit``: the links'
    ``(w, r, σ)``; ``solved``: the CG's ``(X, Xc)`` and its right-hand sides ``(b, bc)``; ``totals``: σ̂²'s,
    tr GᵀWG, ẽᵀẽ."""
    w, r, sig = fit
    X, Xc, b, bc = solved
    nf, dim = problem.n_free, problem.dim
    B = X[:, :, nf:]  # (n_local, P, n): rows of B = Q JᵀWG, the anchor's own
    H = b[:, :, nf:]
    hb = np.einsum("npk,npk->n", H, B)
    tr_a = float(totals[1]) - float(links.total(hb)) - float(bc[nf:] @ Xc[nf:])
    delay_sigma_used_m = o.delay_sigma_m
    if o.estimate_delays and problem.n_anchors <= ESTIMATE_MAX_ANCHORS:
        rows = (links.owner, links.other, w, r, sig, H, B, bc[nf:], Xc[nf:])
        estimate_m = _delay_estimate(problem, ex, links, *rows, tr_a, float(totals[2]), redundancy, o.delay_upper_z)
        delay_sigma_used_m = max(o.delay_sigma_m, estimate_m)
    share = delay_sigma_used_m**2 * tr_a / redundancy if redundancy > 0 else 0.0
    s2 = max(s2 - share, MIN_NOISE_SHARE * s2)
    Bp = B[:, :dim, :] * free[:, :dim, None]
    return delay_sigma_used_m, s2, delay_sigma_used_m**2 * np.einsum("nak,nbk->nab", Bp, Bp)


def _free_masks(anchor_free: np.ndarray, nodes: np.ndarray, other: np.ndarray, P: int) -> tuple[np.ndarray, np.ndarray]:
    """Which unknowns are free: of the block's anchors ``(n_local, P)`` and of each link's other end
    ``(n_links, P)`` (an offset column, when there is one, is always free)."""
    dim = anchor_free.shape[1]
    free = np.ones((nodes.size, P), bool)
    free[:, :dim] = anchor_free[nodes]
    free_nb = np.ones((other.size, P), bool)
    free_nb[:, :dim] = anchor_free[other]
    return free, free_nb


def _preconditioner(
    owner: np.ndarray, w: np.ndarray, a: np.ndarray, free: np.ndarray, dim: int, prior: float | None
) -> np.ndarray:
    """CG's block-Jacobi preconditioner: the inverse of each anchor's own normal block (its links' rows, and its
    offset's prior when per-anchor offsets are estimated)."""
    nl, P = free.shape
    own_block = np.zeros((nl, P, P))
    np.add.at(own_block, owner, np.einsum("h,ha,hb->hab", w, a, a))
    if prior is not None:
        own_block[:, dim, dim] += prior
    try:
        pre_inv: np.ndarray = block_preconditioner(own_block, np.zeros((nl, P)), free)
    except np.linalg.LinAlgError as err:
        raise ModelError("an anchor's own normal block is singular (too few links): no central precision") from err
    return pre_inv


def _delay_estimate(
    problem: RangingData,
    ex: Exchange,
    links: Links,
    owner: np.ndarray,
    other: np.ndarray,
    w: np.ndarray,
    r: np.ndarray,
    sig: np.ndarray,
    H: np.ndarray,
    B: np.ndarray,
    hc: np.ndarray,
    bc_row: np.ndarray,
    tr_a: float,
    ete: float,
    tr_m: float,
    upper_z: float,
) -> float:
    """σ_δ from the residuals as :func:`distnav.models.uwb.precision.delay_sigma_estimate`, from network totals:
    ``A = GᵀWG − (JᵀWG)ᵀB`` (``n²`` floats per anchor: its own rows of both), ``‖GᵀWr‖²`` (anchor ``k``'s entry is
    a sum over its own links), ``ẽᵀẽ = Σ w r²`` and ``tr M = m − n_x``; ``√(σ̂_δ² + upper_z · sd)`` with the
    estimate's standard deviation as :func:`~distnav.models.uwb.precision.delay_variance_estimate`'s."""
    n, nl = problem.n_anchors, ex.n_local
    me = ex.nodes[owner]
    part = -np.einsum("npk,npl->nkl", H, B)
    gwg = w / sig**2
    np.add.at(part, (owner, me, me), gwg)  # row k of GᵀWG from k's own links: the diagonal and its neighbours
    np.add.at(part, (owner, me, other), gwg)
    gwr = np.zeros((nl, n))
    np.add.at(gwr, (owner, me), w * r / sig)
    tot = links.total(np.concatenate([part.reshape(nl, n * n), gwr], axis=1))
    A = tot[: n * n].reshape(n, n) - np.outer(hc, bc_row)  # the common offset's row of JᵀWG and B, once
    gwr_all = tot[n * n :]
    A2 = A @ A
    tr_a2, tr_a3, tr_a4 = float(np.sum(A * A)), float(np.sum(A2 * A)), float(np.sum(A2 * A2))
    lhs = np.array([[tr_m, tr_a], [tr_a, tr_a2]])
    rhs = np.array([ete, float(gwr_all @ gwr_all)])
    try:
        inv = np.linalg.inv(lhs)
    except np.linalg.LinAlgError:
        return 0.0
    s2, d2 = inv @ rhs
    if d2 > 0 and s2 <= 0:
        d2, s2 = rhs[1] / lhs[1, 1], 0.0
    # its standard deviation for normal errors, 2 tr(Bᵢ Σ Bⱼ Σ) with Σ = s² M + σ_δ² M G̃G̃ᵀ M, from A alone
    # (M² = M): tr Σ² = s⁴ tr M + 2s²σ_δ² tr A + σ_δ⁴ tr A², and likewise one and two powers of A higher
    sp, dp = max(float(s2), 0.0), max(float(d2), 0.0)
    c = [
        sp * sp * t0 + 2.0 * sp * dp * t1 + dp * dp * t2
        for t0, t1, t2 in ((tr_m, tr_a, tr_a2), (tr_a, tr_a2, tr_a3), (tr_a2, tr_a3, tr_a4))
    ]
    C = 2.0 * np.array([[c[0], c[1]], [c[1], c[2]]])
    sd = float(np.sqrt(max(float((inv @ C @ inv.T)[1, 1]), 0.0)))
    v = float(d2) + upper_z * sd
    return float(np.sqrt(v)) if v > 0 else 0.0
