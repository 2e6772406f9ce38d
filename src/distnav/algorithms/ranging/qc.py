"""Precision and per-link tests of a UWB ranging solution; the link-exclusion loop.

Centralized (LM, :func:`centralized_quality`): at the solution ``x̂`` with whitened Jacobian ``J`` (rows
``j_l``) and the final IRLS weights ``W = diag(w_l)`` (1 for the linear loss),

* covariance ``Q_x̂ = (JᵀWJ)⁻¹`` (σ² = 1; the a-posteriori covariance is ``σ̂² Q_x̂`` with ``σ̂² = Σ w r² / (m − n)``),
  cut into every anchor's ``dim × dim`` block (:class:`~distnav.algorithms.result.Precision`, kind
  ``"centralized"``);
* residual variances of the whitened ranges under H0 for the fixed weights,
  ``q_l = (I − JQJᵀW)(I − JQJᵀW)ᵀ_ll = 1 − 2 w_l h_l + j_l Q (JᵀW²J) Q j_lᵀ`` with ``h_l = j_l Q j_lᵀ``
  (for ``W = I``: ``1 − h_l``, Baarda's redundancy number). A link the robust loss ignored (``w_l ≈ 0``) gets
  ``q_l ≈ 1 + h_l``: its residual is a prediction and tests it at full strength;
* w-statistics ``w_l = r̂_l / (ŝ √q_l)`` (:func:`distnav.algorithms.statistics.w_statistics`), where ``ŝ`` is a
  **robust scale** by default: ``1.4826 · median |r̂_l / √q_l|``. Why: the range σ of a real log is not known
  in advance, and the a-posteriori ``σ̂`` from the sum of squares is inflated by the very NLOS links one is
  looking for (masking them); the median is insensitive to up to half the links being bad. ``scale="a-priori"``
  uses the given σ (``ŝ = 1``) for data whose σ is trusted.

Distributed (:func:`local_quality`): anchor ``i`` knows its own links and the estimates it holds of itself and
its neighbours. Its information about its own position with the neighbours held at their estimates is
``N_i = Σ_{l∈E(i)} w_l j_l j_lᵀ``; ``N_i⁻¹`` is the **conditional** covariance (kind ``"conditional"``): never
larger than the centralized block (it ignores the neighbours' own errors), so it is a lower bound — optimistic —
and says so. Each anchor tests its own links with ``q_l = 1 − w_l j_lᵀ N_i⁻¹ j_l`` and, by default
(``test_scale="robust"``), the **network robust scale** of :func:`network_robust_scale`: ``1.4826 · median
|r_l / √q_l|`` over every link of the network (each once, from the anchor that tests it), floored at the a-priori
σ / 4 — the central test's statistic, a network total (one gather of one float per link, as the result's).
``test_scale="local"`` is the earlier choice, each anchor's robust scale from its own 5–8 links (floored the same
way): an anchor with 2 NLOS links among 5 has its scale inflated by them and passes them (plant-like hall of
``reproduce uwb-field``, corner #1: w −1.8 and −1.3 where the central test has −37 and −24), and at an exact
least-squares solution an anchor whose residuals the fit absorbs gets a small scale and false alarms.
A two-end ``q`` (the other end's leverage from its ``N_j⁻¹``, one broadcast) was tried and not kept: closer to the
central ``q`` on NLOS links but up to 5.5 × off on a link whose ends' cross-covariance matters (docs/uwb.md).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from distnav._blas import single_threaded_blas
from distnav.algorithms.ranging.data import RangingData, RangingResult
from distnav.algorithms.ranging.losses import loss_terms
from distnav.algorithms.result import ObservationTests, Precision
from distnav.algorithms.statistics import critical_value, variance_factor, w_statistics
from distnav.errors import ModelError
from distnav.exchange import Exchange

if TYPE_CHECKING:
    from distnav.algorithms.ranging.neighbourhoods import IterationState

__all__ = [
    "TEST_SCALES",
    "DISTRIBUTED_TEST_SCALES",
    "centralized_quality",
    "exclude_links",
    "free_block_inverses",
    "HalfLinks",
    "local_quality",
    "network_robust_scale",
    "robust_scale",
]

log = logging.getLogger(__name__)
TEST_SCALES = ("robust", "a-priori")
DISTRIBUTED_TEST_SCALES = (*TEST_SCALES, "local")  # "robust": the network's robust scale; "local": each anchor's
SCALE_FLOOR = 0.25  # the distributed tests' robust scale is floored at a quarter of the a-priori σ
_MAX_DENSE = 6000  # unknowns up to which the covariance is formed (a dense inverse)
#: a near-critical link always blocked by a pick of its anchors leaves no loose re-fit's choice open (:func:`_decided`)
BLOCKED_NEAR = True
#: issue 27 (docs/economy_uwb.md items 44–46, 60): an open round (:func:`_decided`) of an early-stopped fit with at
#: least :data:`DEFER_MIN_NEAR` eligible links within the margin of the critical value takes its sure picks
#: (:func:`_sure_picks`), defers the rest to the next re-fit and climbs only where no pick is sure — in networks of
#: :data:`DEFER_MIN_ANCHORS` or more: above 3,000 (where it doubled one anchor's error), below 10⁴ (what it is for)
DEFER_OPEN = True
DEFER_MIN_ANCHORS = 5000
#: links within the margin grow with the network (1 cm: about 1 in 300); `[78, 0]` middle holds 1–2 (item 46)
DEFER_MIN_NEAR = 10
#: a deferring round's next re-fit is on its own rung (3 mm after a 3 mm round's picks), not the first
DEFER_STAYS = True


def robust_scale(standardized: np.ndarray) -> float:
    """``1.4826 · median |s|`` over the finite entries (the normal-consistent MAD about zero); NaN if none."""
    s = np.abs(standardized[np.isfinite(standardized)])
    return float(1.4826 * np.median(s)) if s.size else float("nan")


def _inverse_spd(n_mat: np.ndarray) -> np.ndarray | None:
    """``N⁻¹`` of a symmetric positive definite matrix by LAPACK's Cholesky and ``potri`` (half the flops of
    solving for the identity); None if ``N`` is not positive definite (singular)."""
    u, info = sla.lapack.dpotrf(n_mat, lower=0, clean=1, overwrite_a=0)  # clean: zeros below the diagonal
    if info != 0 or not np.all(np.isfinite(u)):
        return None
    inv, info = sla.lapack.dpotri(u, lower=0, overwrite_c=1)  # the upper triangle of N⁻¹; zeros below
    if info != 0:
        return None
    out = inv + inv.T
    out.flat[:: out.shape[0] + 1] *= 0.5
    return np.asarray(out)


def _hat_terms(J: sp.csr_matrix, Q: np.ndarray, weight: np.ndarray, n_ranges: int) -> tuple[np.ndarray, np.ndarray]:
    """``h_l = j_l Q j_lᵀ`` and ``j_l Q (JᵀW²J) Q j_lᵀ = Σ_k w_k² (j_l Q j_kᵀ)²`` of the first ``n_ranges`` rows,
    from blocks of ``J Q Jᵀ`` (``z = J_l Q`` for a chunk of rows, then ``J zᵀ``; never the n × n product
    ``Q JᵀW²J Q``)."""
    Jr = J[:n_ranges]
    JT = sp.csr_matrix(J)
    w2 = weight * weight
    h = np.empty(n_ranges)
    qmq = np.empty(n_ranges)
    for lo in range(0, n_ranges, 512):
        z = np.asarray(Jr[lo : lo + 512] @ Q)  # (chunk, n)
        y = np.asarray(JT @ z.T)  # (m, chunk): j_k Q j_lᵀ
        h[lo : lo + 512] = y[np.arange(lo, lo + z.shape[0]), np.arange(z.shape[0])]
        qmq[lo : lo + 512] = w2 @ (y * y)
    return h, qmq


def centralized_quality(
    problem: RangingData,
    jacobian: sp.csr_matrix,
    residual: np.ndarray,
    weight: np.ndarray,
    n_ranges: int,
    *,
    level: float = 0.001,
    scale: str = "robust",
) -> tuple[Precision | None, ObservationTests | None, np.ndarray | None]:
    """Precision of every anchor and w-tests of every range sample at an LM solution (module docstring).

    ``jacobian`` / ``residual`` / ``weight`` are the whitened rows at the solution (the first ``n_ranges`` rows are
    the range samples; further rows are priors, not tested). Returns ``(precision, tests, Q_x̂)``, or Nones when
    the normal matrix is singular (a mirror image or a non-rigid part: the positions are not determined) or the
    problem is too large for a dense covariance.
    """
    if scale not in TEST_SCALES:
        raise ModelError(f"test scale must be one of {', '.join(TEST_SCALES)}, got {scale!r}")
    n_x = jacobian.shape[1]
    if n_x == 0 or n_x > _MAX_DENSE:
        log.info("no covariance: %d unknowns", n_x)
        return None, None, None
    J = sp.csr_matrix(jacobian)
    with single_threaded_blas():  # one LAPACK thread: OpenBLAS's threads on a loaded machine cost 5× (measured)
        Q = _inverse_spd(np.asarray((J.T @ sp.diags(weight) @ J).toarray()))
        if Q is None:
            log.info("singular normal matrix: no covariance")
            return None, None, None
        m_rows = J.shape[0]
        redundancy = float(m_rows - n_x)
        s2 = variance_factor(float(np.sum(weight * residual * residual)), redundancy)
        # per-anchor blocks of Q (zeros at known coordinates)
        col = np.full(problem.free.shape, -1, np.int64)
        col[problem.free] = np.arange(problem.n_free)
        safe = np.maximum(col, 0)
        blocks = Q[safe[:, :, None], safe[:, None, :]] * ((col[:, :, None] >= 0) & (col[:, None, :] >= 0))
        precision = Precision(covariance=blocks, variance_factor=s2, redundancy=redundancy, kind="centralized")
        h, qmq = _hat_terms(J, Q, weight, n_ranges)
    q = np.maximum(1.0 - 2.0 * weight[:n_ranges] * h + qmq, 0.0)
    r = residual[:n_ranges]
    std = w_statistics(r, q)
    s = robust_scale(std) if scale == "robust" else 1.0
    w = std / s if s > 0 else std
    k = critical_value(level)
    tests = ObservationTests(
        node=np.asarray(problem.meas_a), w=w, critical_value=k, level=level, flagged=np.abs(np.nan_to_num(w)) > k
    )
    return precision, tests, Q


def network_robust_scale(tested: np.ndarray, *, floor: float = SCALE_FLOOR) -> float:
    """The distributed tests' network robust scale: :func:`robust_scale` of the standardized residuals of every
    link of the network, each sample once (``tested``: the values its testing anchor computed, gathered), floored
    at ``floor`` (a quarter of the a-priori σ: at an exact fit of a small network the median can be tiny); 1 if
    no link was tested. The same statistic as :func:`centralized_quality`'s scale where the standardized
    residuals are the same; a network total (a deployment: one gather of one float per link, or a median by
    bisection over sum reductions of counts)."""
    val = robust_scale(np.asarray(tested, float))
    return max(val, floor) if np.isfinite(val) else 1.0


def free_block_inverses(info: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``N_i⁻¹`` of every anchor's ``dim × dim`` information block on its free coordinates (zeros elsewhere; inf
    where the block is singular): the conditional covariance each anchor computes from its own links."""
    cov = np.zeros_like(info)
    for li in np.flatnonzero(free.any(axis=1)):  # small blocks, the free coordinates only
        f = free[li]
        try:
            cov[li][np.ix_(f, f)] = np.linalg.inv(info[li][np.ix_(f, f)])
        except np.linalg.LinAlgError:
            cov[li][np.ix_(f, f)] = np.inf
    return cov


@dataclass(frozen=True, eq=False)
class HalfLinks:
    """One row per half-measurement an exchange block holds: its measured ``range_m``, ``owner`` (local anchor
    index) and the owner's free coordinates ``owner_free`` ``(h, dim)``, ``own_m`` / ``other_m`` (the owner's
    estimate of itself and of the other end, ``(h, dim)``) and the range ``sigma``."""

    range_m: np.ndarray
    owner: np.ndarray
    owner_free: np.ndarray
    own_m: np.ndarray
    other_m: np.ndarray
    sigma: np.ndarray


def local_quality(
    half: HalfLinks,
    n_local: int,
    kind: str,
    *,
    loss: str = "linear",
    loss_scale: np.ndarray | float = 1.0,
    scale: str = "robust",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What every anchor of one exchange block computes from its own links (module docstring); no messages.

    ``half``: the block's half-measurements (:class:`HalfLinks`); the loss with its per-row scale (for the IRLS
    weights). ``kind`` is the objective (``"squared"`` or ``"metres"``).
    ``scale``: ``"local"`` divides by each anchor's robust scale of its own links; ``"robust"`` and
    ``"a-priori"`` return the standardized residuals unscaled (the network's robust scale is applied by
    :func:`distributed_quality`, after a gather).
    Returns ``(conditional covariance (n_local, dim, dim), w of every half-measurement, weighted SSR per anchor)``.
    """
    if scale not in DISTRIBUTED_TEST_SCALES:
        raise ModelError(f"test scale must be one of {', '.join(DISTRIBUTED_TEST_SCALES)}, got {scale!r}")
    range_m, owner, owner_free, sigma = half.range_m, half.owner, half.owner_free, half.sigma
    dim = half.own_m.shape[1]
    diff = half.own_m - half.other_m
    dist = np.linalg.norm(diff, axis=1)
    if kind == "metres":
        j = diff / (np.where(dist > 0, dist, np.inf) * sigma)[:, None]
        r = (dist - range_m) / sigma
    else:
        j = 2.0 * diff
        r = dist * dist - range_m * range_m
    j = j * owner_free
    weight = loss_terms(r, loss_scale, loss)[0]
    info = np.zeros((n_local, dim, dim))
    np.add.at(info, owner, weight[:, None, None] * j[:, :, None] * j[:, None, :])
    free = np.zeros((n_local, dim), bool)
    free[owner] = owner_free
    cov = free_block_inverses(info, free)
    with np.errstate(invalid="ignore"):
        h = np.einsum("li,lij,lj->l", j, cov[owner], j)
    q = np.where(np.isfinite(h), np.maximum(1.0 - weight * h, 0.0), 0.0)
    std = w_statistics(r, q)
    s = np.ones(n_local)
    if scale == "local":  # each anchor's robust scale from its own links, floored at a quarter of the a-priori σ
        for node in range(n_local):
            val = robust_scale(std[owner == node])
            s[node] = max(val, SCALE_FLOOR) if np.isfinite(val) else 1.0
    wssr = np.bincount(owner, weight * r * r, minlength=n_local)
    return cov, np.asarray(std / s[owner]), np.asarray(wssr)


def _links_left(problem: RangingData, keep: np.ndarray) -> np.ndarray:
    """Distinct links per anchor among the kept samples."""
    a, b = problem.meas_a[keep], problem.meas_b[keep]
    n = problem.n_anchors
    key = np.unique(np.minimum(a, b) * n + np.maximum(a, b))
    return np.bincount(np.concatenate([key // n, key % n]), minlength=n)


def exclude_links(
    problem: RangingData,
    fit: Callable[[RangingData], RangingResult],
    *,
    max_exclusions: int | None = None,
    one_sided: bool = False,
    per_round: int | None = 1,
    loose: Sequence[tuple[Callable[[RangingData], RangingResult], float]] = (),
    opening: RangingResult | None = None,
    confirm: bool = True,
) -> tuple[RangingResult, RangingData, ObservationTests]:
    """Iterative exclusion: while a link is flagged, remove the link (all its samples) with the largest |w| whose
    two anchors keep more links than free coordinates (the network stays determined with a check), and re-fit.

    ``one_sided``: only links measured *longer* than the fit (``w < 0``; residual = fitted − measured) are
    excluded. NLOS and multipath only ever lengthen a UWB range, so a link measured much shorter than the fit
    is a good link the fit was dragged away from (by NLOS links elsewhere): excluding it would lock in the wrong
    solution. Such a link stays flagged (and the per-anchor check of :mod:`distnav.models.uwb.local` looks at it).

    ``per_round`` (default 1: Baarda's one at a time): up to that many links per re-fit (``None``: no cap), the
    flagged ones in order of |w| that share no anchor with a link already taken in that round. An NLOS link
    inflates the residuals of the other links of its anchors most (swamping), so links of one anchor are
    removed one per re-fit; links of different anchors together.

    ``loose`` (issue 27): fits stopped early, loosest first, each with its margin ``(fit, margin_w)``. The re-fit
    after an exclusion is the first; its choice is taken only where it is **decided with its margin**: no eligible
    link's |w| within ``margin_w`` of the critical value (but one always blocked by a pick of its anchors) and no
    two links whose |w| are within ``2 · margin_w`` of each other chosen differently in the other order
    (:func:`_decided`). Otherwise the next fit continues from its solution (the caller's fits start from the last
    one) and decides, the last being ``fit`` (no margin); where a decided choice would end the loop, ``fit``
    continues at once and confirms it (issue 27, sixth session: not every rung): the loop ends with ``fit``'s answer
    and tests, and excludes what ``fit`` alone would have excluded wherever each margin bounds the change of |w|
    up to ``fit``'s solution.

    ``opening`` (issue 27, seventh session): a fit of the whole ``problem`` already made, stopped as early as the
    first of ``loose`` (the workflow's last tightening fit, with its tests): the loop starts from it at that rung
    instead of with ``fit(problem)`` — its choice taken only where decided with that margin, as a re-fit's.
    ``confirm`` False (issue 27, seventh session): where a decided choice ends the loop on a loose fit, that fit is
    returned (no ``fit`` to confirm it): the caller completes it where its answer needs the full tolerance.

    ``fit(subproblem)`` solves a problem and returns a result with ``tests`` (LM with QC, or a distributed solver).
    Returns ``(final result, the problem without the excluded links, tests)`` where the tests hold the final
    ``w`` of every original sample (NaN for excluded ones), ``flagged`` in the final solution and ``removed`` =
    the original sample indices excluded, in order.
    """
    keep = np.ones(problem.n_meas, bool)
    removed: list[int] = []
    ladder = [*loose, (fit, 0.0)]
    res, level = (opening, 0) if opening is not None and loose else (fit(problem), len(ladder) - 1)
    sub = problem
    limit = problem.n_meas if max_exclusions is None else int(max_exclusions)
    n_links = 0
    need = problem.free.sum(axis=1) + 1
    while True:
        cap = min(limit - n_links, problem.n_meas if per_round is None else max(int(per_round), 1))
        usable = res.tests is not None and res.usable and cap > 0
        aw, a, b, idx = _eligible(problem, res.tests, keep, need, one_sided) if usable else (np.zeros(0),) * 4
        crit = float(res.tests.critical_value) if usable and res.tests is not None else 0.0
        picks = _round_picks(problem.n_anchors, aw, a, b, cap, crit)
        stay = 0
        if level < len(ladder) - 1:
            margin = ladder[level][1]
            step = _ladder_step(problem.n_anchors, res, (aw, a, b), (cap, crit, margin), picks, confirm)
            defers = _defers(step, aw, crit, margin) and problem.n_anchors >= DEFER_MIN_ANCHORS
            sure = _sure_picks(aw, (a, b), cap, crit, margin, picks) if defers else []
            if sure:  # the sure picks now, the open rest at the next re-fit (issue 27, eighth session)
                step, picks = _TAKE, sure
                stay = level if DEFER_STAYS else 0
            if step == _END:
                break
            if step != _TAKE:  # the next fit decides (its level), or the last fit confirms the loop's end
                level = level + 1 if step == _NEXT else len(ladder) - 1
                res = ladder[level][0](sub)
                continue
        if not picks:
            break
        sub, n_links, level = _drop_links(problem, keep, removed, picks, (a, b, idx)), n_links + len(picks), stay
        res = ladder[level][0](sub)
    if res.tests is None:
        raise ModelError("exclude_links needs a fit that returns per-link tests (result.tests)")
    return res, sub, _all_sample_tests(problem, res.tests, keep, removed)


def _drop_links(
    problem: RangingData,
    keep: np.ndarray,
    removed: list[int],
    picks: list[int],
    rows: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> RangingData:
    """Every sample of each picked link (``rows``: the ends and original index of every kept sample) cleared from
    ``keep`` and appended to ``removed`` (both updated in place); the problem without them."""
    a, b, idx = rows
    for worst in picks:
        lo, hi = int(min(a[worst], b[worst])), int(max(a[worst], b[worst]))
        same = idx[(np.minimum(a, b) == lo) & (np.maximum(a, b) == hi)]
        keep[same] = False
        removed.extend(int(s) for s in same)
    return dataclasses.replace(
        problem, meas_a=problem.meas_a[keep], meas_b=problem.meas_b[keep], range_m=problem.range_m[keep]
    )


_TAKE, _NEXT, _CONFIRM, _END = "take", "next", "confirm", "end"  # :func:`_ladder_step`'s answers


def _ladder_step(
    n_anchors: int,
    res: RangingResult,
    round_: tuple[np.ndarray, np.ndarray, np.ndarray],
    limits: tuple[int, float, float],
    picks: list[int],
    confirm: bool,
) -> str:
    """What :func:`exclude_links` does with an early-stopped fit's round (``round_``: |w| ``aw`` and the ends of
    every kept sample; ``limits``: the round's cap, the critical value and the fit's margin): ``_TAKE`` its
    ``picks`` where decided; where undecided, ``_NEXT`` (the next fit decides); where a decided choice ends the
    loop, ``_CONFIRM`` (the last fit confirms it) or, with ``confirm`` False, ``_END`` (the loop ends on this
    fit) — only where the fit is usable and tested: an unusable fit (diverged, singular; no eligible link, so
    "decided") has nothing to end on, and the last fit continues as with ``confirm``."""
    aw, a, b = round_
    cap, crit, margin = limits
    if not _decided(n_anchors, aw, (a, b), cap, crit, margin, picks):
        return _NEXT
    if picks:
        return _TAKE
    return _END if res.usable and res.tests is not None and not confirm else _CONFIRM


def _eligible(
    problem: RangingData, t: ObservationTests | None, keep: np.ndarray, need: np.ndarray, one_sided: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """|w| of every kept sample (−inf where it may not be excluded: NaN, read short with ``one_sided``, or an end
    left with no check), its anchors and its original index."""
    assert t is not None
    idx = np.flatnonzero(keep)
    aw = np.where(np.isfinite(t.w) & ((t.w < 0) if one_sided else True), np.abs(t.w), -np.inf)
    left = _links_left(problem, keep)
    a, b = problem.meas_a[idx], problem.meas_b[idx]
    ok = ((left[a] - 1 >= need[a]) | problem.fixed[a]) & ((left[b] - 1 >= need[b]) | problem.fixed[b])
    return np.where(ok, aw, -np.inf), a, b, idx


def _round_picks(n_anchors: int, aw: np.ndarray, a: np.ndarray, b: np.ndarray, cap: int, critical: float) -> list[int]:
    """One round of :func:`exclude_links`: up to ``cap`` flagged samples (|w| ``aw`` above ``critical``, −inf
    where not allowed) in order of ``aw``, no two sharing an anchor (so no two samples of one link)."""
    blocked = np.zeros(n_anchors, bool)  # anchors of this round's links
    picks: list[int] = []
    for worst in np.argsort(-aw, kind="stable"):
        if len(picks) >= cap or aw[worst] <= critical:
            break
        if blocked[a[worst]] or blocked[b[worst]]:
            continue
        picks.append(int(worst))
        blocked[[a[worst], b[worst]]] = True
    return picks


def _links_of(picks: list[int], a: np.ndarray, b: np.ndarray) -> set[tuple[int, int]]:
    return {(int(min(a[k], b[k])), int(max(a[k], b[k]))) for k in picks}


def _decided(
    n_anchors: int,
    aw: np.ndarray,
    ends: tuple[np.ndarray, np.ndarray],
    cap: int,
    critical: float,
    margin: float,
    picks: list[int] | None = None,
) -> bool:
    """Whether a round's choice (:func:`_round_picks`) stands when every |w| may be off by ``margin``: no eligible
    |w| within ``margin`` of ``critical`` (but one that a pick of its anchors always blocks, :data:`BLOCKED_NEAR`),
    and swapping the |w| of any two links within ``2 · margin`` of each other
    (both above ``critical − margin``) chooses the same links. ``picks``: the round's choice
    (:func:`_round_picks` of the same arguments; None: made here)."""
    a, b = ends
    if picks is None:
        picks = _round_picks(n_anchors, aw, a, b, cap, critical)
    near_crit = np.abs(aw - critical) <= margin
    if BLOCKED_NEAR:  # a link always behind a pick of one of its anchors is never picked, whatever its |w|
        near_crit &= ~_always_blocked(aw, a, b, picks, critical, margin)
    if np.any(near_crit):
        return False
    base = _links_of(picks, a, b)
    near = np.flatnonzero(aw > critical - margin)
    for i_pos, i in enumerate(near):
        for j in near[i_pos + 1 :]:
            if abs(aw[i] - aw[j]) > 2 * margin:
                continue
            swapped = aw.copy()
            swapped[[i, j]] = aw[[j, i]]
            if _links_of(_round_picks(n_anchors, swapped, a, b, cap, critical), a, b) != base:
                return False
    return True


def _defers(step: str, aw: np.ndarray, critical: float, margin: float) -> bool:
    """Whether a round that :func:`_ladder_step` leaves open defers its undecided links (:data:`DEFER_OPEN`,
    :data:`DEFER_MIN_NEAR`; the caller applies :data:`DEFER_MIN_ANCHORS`)."""
    return step == _NEXT and DEFER_OPEN and int(np.count_nonzero(np.abs(aw - critical) <= margin)) >= DEFER_MIN_NEAR


def _sure_picks(
    aw: np.ndarray, ends: tuple[np.ndarray, np.ndarray], cap: int, critical: float, margin: float, picks: list[int]
) -> list[int]:
    """The picks of a round (:func:`_round_picks`) that it takes too with each |w| off by up to ``margin`` (issue 27,
    eighth session): |w| above ``critical + margin``; every other link's sample of its anchors that could be flagged
    (above ``critical − margin``) more than ``2 · margin`` below it (none can come first); fewer than ``cap`` other
    links' samples at most ``2 · margin`` below it or above (the cap cannot stop the round before it)."""
    a, b = ends
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    live = np.flatnonzero(aw > critical - margin)  # the samples any such round could take
    ranked = np.sort(aw[live])
    out: list[int] = []
    for k in picks:
        if aw[k] <= critical + margin:
            continue
        of_link = (lo[live] == lo[k]) & (hi[live] == hi[k])
        ahead = (
            live.size
            - np.searchsorted(ranked, aw[k] - 2 * margin, side="right")
            - np.count_nonzero(of_link & (aw[live] > aw[k] - 2 * margin))
        )
        if ahead >= cap:
            continue
        ends_k = (a[live] == a[k]) | (a[live] == b[k]) | (b[live] == a[k]) | (b[live] == b[k])
        if np.any(ends_k & ~of_link & (aw[live] >= aw[k] - 2 * margin)):
            continue
        out.append(k)
    return out


def _always_blocked(
    aw: np.ndarray, a: np.ndarray, b: np.ndarray, picks: list[int], critical: float, margin: float
) -> np.ndarray:
    """Per sample: whether it shares an anchor with a pick that stays flagged and ahead of it when every |w| may be
    off by ``margin`` (the pick's |w| above ``critical + margin`` and more than ``2 · margin`` above the sample's)."""
    out = np.zeros(aw.size, bool)
    for k in picks:
        if aw[k] <= critical + margin:
            continue
        shares = (a == a[k]) | (a == b[k]) | (b == a[k]) | (b == b[k])
        out |= shares & (aw < aw[k] - 2 * margin)
    return out


def _all_sample_tests(
    problem: RangingData, final: ObservationTests, keep: np.ndarray, removed: list[int]
) -> ObservationTests:
    """The final tests over every original sample (w NaN for the excluded ones) with the exclusions in order."""
    w_all = np.full(problem.n_meas, np.nan)
    flagged = np.zeros(problem.n_meas, bool)
    w_all[keep] = final.w
    flagged[keep] = final.flagged
    return ObservationTests(
        node=np.minimum(problem.meas_a, problem.meas_b),
        w=w_all,
        critical_value=final.critical_value,
        level=final.level,
        flagged=flagged,
        removed=tuple(removed),
        iterations=0,
        comm=None,
    )


def distributed_quality(
    problem: RangingData,
    ex: Exchange,
    st: IterationState,
    sigma: np.ndarray,
    scale: np.ndarray,
    *,
    objective: str,
    loss: str,
    test_scale: str,
    test_level: float,
) -> tuple[Precision, ObservationTests]:
    """Every anchor's conditional covariance and the w-tests of its own links (computed locally, then gathered);
    each sample is tested and reported by the lower-indexed of its two anchors. ``test_scale="robust"``: the
    standardized residuals are divided by the network robust scale (:func:`network_robust_scale`, a network total
    of the gathered values); ``"local"``: by each anchor's own; ``"a-priori"``: not at all."""
    assert st.half_owner is not None and st.half_sample is not None and st.half_other_m is not None
    owner, samp = st.half_owner, st.half_sample
    rng = problem.range_m[samp] - (0.0 if st.half_offset_m is None else st.half_offset_m)  # the holder's bias
    cov, w_half, wssr = local_quality(
        HalfLinks(rng, owner, problem.free[ex.nodes[owner]], st.own_m[owner], st.half_other_m, sigma[samp]),
        ex.n_local,
        objective,
        loss=loss,
        loss_scale=scale[samp],
        scale=test_scale,
    )
    # pack per anchor (padded) so the result can be gathered over blocks
    per = np.bincount(owner, minlength=ex.n_local)
    K = max(int(ex.allreduce(int(per.max(initial=0)), "max")), 1)
    order = np.argsort(owner, kind="stable")
    slot = np.empty(owner.size, np.int64)
    slot[order] = np.arange(owner.size) - np.repeat(np.cumsum(per) - per, per)
    w_pack = np.full((ex.n_local, K), np.nan)
    s_pack = np.full((ex.n_local, K), -1.0)
    w_pack[owner, slot] = w_half
    s_pack[owner, slot] = samp
    cov_all = ex.gather_nodes(cov)
    w_all_half = ex.gather_nodes(w_pack)
    s_all = ex.gather_nodes(s_pack).astype(np.int64)
    holder = np.repeat(np.arange(problem.n_anchors), K)
    smp = s_all.ravel()
    ok = smp >= 0
    tester = np.minimum(problem.meas_a, problem.meas_b)
    mine = ok & (holder == tester[np.maximum(smp, 0)])
    w = np.full(problem.n_meas, np.nan)
    w[smp[mine]] = w_all_half.ravel()[mine]
    if test_scale == "robust":  # one network-wide robust scale, from every link's test (each sample once)
        w = w / network_robust_scale(w)
    wssr_total = float(ex.allreduce(float(wssr.sum()), "sum")) / 2.0  # every sample is held twice
    links = np.bincount(np.concatenate([problem.meas_a, problem.meas_b]), minlength=problem.n_anchors)
    red = float(np.sum(np.maximum(links - problem.free.sum(axis=1), 0)[problem.estimated]))
    k = critical_value(test_level)
    precision = Precision(
        covariance=cov_all,
        variance_factor=variance_factor(wssr_total, max(problem.n_meas - problem.n_free, 0)),
        redundancy=red,
        kind="conditional",
    )
    tests = ObservationTests(node=tester, w=w, critical_value=k, level=test_level, flagged=np.abs(np.nan_to_num(w)) > k)
    return precision, tests
