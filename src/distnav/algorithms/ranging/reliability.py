"""External reliability of a ranging solution: redundancy numbers, minimal detectable biases and the largest shift
one undetected bad link can cause (Baarda; issue 28 item 5) — centrally, and by the anchors from their k-hop
neighbourhood's link records plus ``hops`` message rounds.

**The numbers** (:func:`external_reliability`; Baarda 1968, Teunissen 2006 §4.2; the statistics in
:mod:`distnav.algorithms.statistics`). With ``J`` the whitened Jacobian of the metres objective at the solution,
``W`` the final IRLS weights of the robust loss, ``Q = (JᵀWJ)⁻¹``: the redundancy number of link ``l``
``r_l = 1 − w_l j_l Q j_lᵀ``; the residual variance its w-test divides by (fixed weights)
``q_l = 1 − 2 w_l j_l Q j_lᵀ + j_l Q JᵀW²J Q j_lᵀ``; its **minimal detectable bias**
``∇_l = σ_l ŝ √λ0 √q_l / r_l`` (``ŝ`` the w-tests' robust scale, ``λ0`` the non-centrality of the test's level and
power 0.8); and what that bias, undetected, does to the unknowns: ``∇x̂_l = Q j_lᵀ w_l ∇_l / σ_l``. An anchor's
**worst shift** is the largest ``‖∇x̂_l‖`` over its free coordinates and all kept links. ``r_l ≈ 0``: nothing checks
the link, its MDB is infinite and every anchor it moves has an infinite shift.

**From what each anchor holds** (:func:`local_reliability`). ``Q`` is the inverse of the whole network's normal
matrix: no anchor holds it. Anchor ``i`` instead learns the link records ``[sample, a, b, d, r̂_a, r̂_b (, b̂_a,
b̂_b)]`` (the sample's ends, its range and both ends' estimates, with per-anchor offsets their estimates) of its
``hops``-hop neighbourhood by flooding: each anchor starts with the records of its own links; in every round it
broadcasts the records it learned in the last one (padded to the most any anchor learned, ids −1), so after
``hops`` rounds it holds every link of every anchor within ``hops`` hops (``S``, the set whose links it knows
completely) and their far ends (the ring ``R``). It then computes the numbers above on the **sub-network**: the free
coordinates of ``S`` (and the offsets: a common one, or ``S``'s and the ring's per-anchor ones with their priors)
are the unknowns, the ring's positions are held at their estimates, ``ŝ`` is the robust scale of the
sub-network's w-statistics. It keeps its own worst shift (over the sub-network's links) and, for the links it owns
(the sample's first estimated end), their ``r``, ``q``, MDB. Where ``S`` spans the network (``hops`` ≥ every
anchor's eccentricity) these are exactly the central numbers (tested). Elsewhere they differ in three ways, each
measured in docs/uwb.md ("Reliability from the anchors' neighbourhoods"): the held ring makes ``S`` better
determined than it is (``r`` larger, the MDB smaller: optimistic), a link outside the neighbourhood moves ``i`` by
nothing in its sum (the far links' shifts are dropped), and ``ŝ`` is the neighbourhood's.

**Bytes**: one flooding round sends, per directed edge, ``K × (4 + 2 dim [+ 2])`` floats (``K`` the most records
an anchor learned in the last round); the exchange counts them (``LocalReliability.comm``). The dense ``Q`` of a
sub-network of ``p`` unknowns costs ``O(p³)`` per anchor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from distnav._blas import single_threaded_blas
from distnav.algorithms.ranging.data import RangingData
from distnav.algorithms.ranging.losses import LOSSES, loss_terms
from distnav.algorithms.ranging.neighbourhoods import checked_estimates, exchange_for
from distnav.algorithms.ranging.objective import OFFSETS, RangeObjective
from distnav.algorithms.ranging.qc import robust_scale
from distnav.algorithms.statistics import minimal_detectable_bias, noncentrality, redundancy_numbers, w_statistics
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.typing import FloatArray, IntArray

__all__ = [
    "MAX_FREE",
    "POWER",
    "ExternalReliability",
    "LocalReliability",
    "ReliabilityOptions",
    "external_reliability",
    "local_reliability",
]

MAX_FREE = 1500  # free coordinates above which the dense Q is not formed (the test is skipped, with a note)
POWER = 0.8  # Baarda's β: the probability that a bias of the MDB is found
_SENSITIVE = 1e-9  # |∂x/∂range| below this (whitened) counts as "this link does not move the anchor"


@dataclass(frozen=True)
class ReliabilityOptions:
    """The fit the numbers linearize (the metres objective): range σ ``sigma_m``, ``offsets`` (none / common /
    per_anchor, prior σ ``offset_prior_sigma_m``), the robust ``loss`` at ``loss_scale_m`` (its IRLS weights), the
    test's ``level`` and Baarda's ``power``. Checked when made."""

    sigma_m: float = 0.1
    offsets: str = "none"
    loss: str = "linear"
    loss_scale_m: float = 0.3
    level: float = 0.001
    offset_prior_sigma_m: float = 0.1
    power: float = POWER

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_m) and self.sigma_m > 0):
            raise ModelError(f"sigma_m must be a positive number of metres, got {self.sigma_m!r}")
        if self.offsets not in OFFSETS:
            raise ModelError(f"offsets must be one of {', '.join(OFFSETS)}, got {self.offsets!r}")
        if self.loss not in LOSSES:
            raise ModelError(f"unknown loss {self.loss!r}; choose one of {', '.join(LOSSES)}")
        if not (np.isfinite(self.loss_scale_m) and self.loss_scale_m > 0):
            raise ModelError(f"loss_scale_m must be positive, got {self.loss_scale_m!r}")
        if not (0.0 < self.level < 1.0 and 0.0 < self.power < 1.0):
            raise ModelError(f"level and power must lie in (0, 1), got {self.level!r}, {self.power!r}")


@dataclass(frozen=True, eq=False)
class ExternalReliability:
    """Per kept link (``problem``'s measurements): redundancy number ``r``, ``mdb_m`` (inf: unchecked); per anchor:
    ``shift_m`` the largest shift of its free coordinates by one link's undetected MDB (0 for known anchors, inf
    when an unchecked link moves it) and ``worst_link`` that link's index (-1 if none); ``lam0`` and ``scale`` ŝ;
    ``q`` the w-test's residual variance per link; ``gain`` ``(n_free, m)`` the free coordinates' move per metre
    of bias on each link, ``Q j_lᵀ w_l / σ_l`` (central numbers only; None from the neighbourhoods)."""

    r: FloatArray
    mdb_m: FloatArray
    shift_m: FloatArray
    worst_link: IntArray
    lam0: float
    scale: float
    q: FloatArray | None = None
    gain: FloatArray | None = None

    @property
    def redundancy(self) -> float:
        """``Σ r_l`` over the range rows (= rows − unknowns with least-squares weights, less prior rows' share)."""
        return float(np.sum(self.r))


def external_reliability(
    problem: RangingData, x: FloatArray, options: ReliabilityOptions
) -> ExternalReliability | None:
    """The reliability numbers (module docstring) of the metres-objective solution with free vector ``x``
    (:class:`RangeObjective`'s layout) on ``problem`` (the kept links), computed centrally. None when the normal
    matrix is singular or the problem has more than :data:`MAX_FREE` free coordinates."""
    return _numbers(problem, np.asarray(x, float), options)


def _numbers(problem: RangingData, x: FloatArray, opts: ReliabilityOptions) -> ExternalReliability | None:
    obj = RangeObjective(problem, "metres", opts.sigma_m, opts.offsets, opts.offset_prior_sigma_m)
    if x.size != obj.n_x or problem.n_free > MAX_FREE or problem.n_free == 0:
        return None
    m = problem.n_meas
    J = sp.csr_matrix(obj.jacobian(x))
    res = obj.residual(x)
    w = loss_terms(res, obj.loss_scale(opts.loss_scale_m), opts.loss)[0] if opts.loss != "linear" else np.ones_like(res)
    with single_threaded_blas():
        N = np.asarray((J.T @ sp.diags(w) @ J).toarray())
        try:
            Q = sla.cho_solve(sla.cho_factor(N, check_finite=False), np.eye(obj.n_x), check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None
        Jr = J[:m]
        r = redundancy_numbers(Jr, w[:m], Q)
        JQ = np.asarray(Jr @ Q)  # (m, n_x): row l is j_l Q
        # the w-test's residual variance, fixed weights (ranging_qc.centralized_quality): 1 − 2wh + j Q JᵀW²J Q jᵀ
        h = np.einsum("ij,ij->i", JQ, np.asarray(Jr.toarray()))
        JW2J = np.asarray((J.T @ sp.diags(w * w) @ J).toarray())
        q = np.maximum(1.0 - 2.0 * w[:m] * h + np.einsum("ij,jk,ik->i", JQ, JW2J, JQ), 0.0)
    std = w_statistics(res[:m], q)
    s = robust_scale(std)
    s = s if np.isfinite(s) and s > 0 else 1.0
    lam0 = noncentrality(opts.level, opts.power)
    sigma = obj.sigma
    mdb = minimal_detectable_bias(sigma * s, r, lam0, residual_variance=q)
    # ∂x / ∂(range bias of l) in metres per metre: Q j_lᵀ w_l / σ_l (the whitened residual moves by ∇/σ)
    gain = (JQ * (w[:m] / sigma)[:, None]).T[: problem.n_free]  # (n_free, m)
    shift, worst = _worst_shifts(problem, gain, mdb)
    return ExternalReliability(r=r, mdb_m=mdb, shift_m=shift, worst_link=worst, lam0=lam0, scale=s, q=q, gain=gain)


def _worst_shifts(problem: RangingData, gain: FloatArray, mdb: FloatArray) -> tuple[FloatArray, IntArray]:
    """Per anchor, the largest ``‖gain_i,l‖ · MDB_l`` over the links ``l`` (inf where an unchecked link moves it)
    and that link."""
    col = np.full(problem.free.shape, -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    n = problem.n_anchors
    shift = np.zeros(n)
    worst = np.full(n, -1, np.int64)
    finite = np.isfinite(mdb)
    for i in np.flatnonzero(problem.free.any(axis=1)):
        g = gain[col[i][col[i] >= 0]]  # (free coords of i, m)
        gn = np.sqrt(np.sum(g * g, axis=0))
        eff = np.where(finite, gn * np.where(finite, mdb, 0.0), np.where(gn > _SENSITIVE, np.inf, 0.0))
        k = int(np.argmax(eff)) if eff.size else 0
        if eff.size:
            shift[i], worst[i] = float(eff[k]), (k if eff[k] > 0 else -1)
    return shift, worst


@dataclass(frozen=True, eq=False)
class LocalReliability:
    """What :func:`local_reliability` gives, gathered for the result (each entry computed by its anchor): per
    sample (``problem``'s measurements) ``r``, ``q`` and ``mdb_m`` from its owner's sub-network (NaN where the owner
    could not compute them); per anchor ``shift_m``, ``worst_link`` (a global sample index, -1 if none),
    ``subnetwork_anchors`` (how many anchors its sub-network solved for; 0: none) and ``scale`` (its ŝ); ``lam0``,
    the flooding ``rounds`` and their ``comm`` (the exchange's totals since the start)."""

    r: FloatArray
    q: FloatArray
    mdb_m: FloatArray
    shift_m: FloatArray
    worst_link: IntArray
    subnetwork_anchors: IntArray
    scale: FloatArray
    lam0: float
    rounds: int
    comm: Any

    def as_external(self) -> ExternalReliability:
        """The numbers in :class:`ExternalReliability`'s form (``scale``: the median of the anchors' ŝ)."""
        sc = self.scale[np.isfinite(self.scale)]
        same = {name: getattr(self, name) for name in ("r", "mdb_m", "shift_m", "worst_link", "lam0", "q")}
        return ExternalReliability(**same, scale=float(np.median(sc)) if sc.size else 1.0)


def local_reliability(
    problem: RangingData,
    estimates_m: FloatArray,
    options: ReliabilityOptions,
    *,
    offsets_m: FloatArray | None = None,
    hops: int = 3,
    exchange: Exchange | None = None,
) -> LocalReliability:
    """Every anchor's reliability numbers from its ``hops``-hop neighbourhood's link records, learned in ``hops``
    flooding rounds through ``exchange`` (module docstring). ``estimates_m``: the anchors' estimates of themselves
    (a distributed solver's ``result.estimates``; each block reads its own rows); ``offsets_m``: the solution's range
    offsets (one common value every anchor holds, or one per anchor) as ``options.offsets`` says."""
    if hops < 1:
        raise ModelError(f"hops must be ≥ 1, got {hops}")
    est = checked_estimates(problem, estimates_m)
    off = _checked_offsets(problem, options.offsets, offsets_m)
    ex = exchange_for(problem, exchange)
    before = ex.comm_totals().snapshot()
    table = _own_records(problem, est, off, options.offsets)
    known = _flood(problem, ex, est, table, hops)
    m, nl = problem.n_meas, ex.n_local
    owner = np.where(problem.estimated[problem.meas_a], problem.meas_a, problem.meas_b)
    r_loc, q_loc, mdb_loc = (np.full((nl, m), np.nan) for _ in range(3))
    shift, worst = np.zeros(nl), np.full(nl, -1, np.int64)
    size, scale = np.zeros(nl, np.int64), np.full(nl, np.nan)
    lam0 = noncentrality(options.level, options.power)
    for li in range(nl):
        me = int(ex.nodes[li])
        if not (problem.estimated[me] or np.any(owner == me)):
            continue
        ball = _ball(problem, table, known[li], me, hops, off, options.offsets)
        if ball is None:
            continue
        sub, samples, anchors, x = ball
        rel = _numbers(sub, x, options)
        if rel is None:
            continue
        mine = int(np.flatnonzero(anchors == me)[0])
        owned = owner[samples] == me
        r_loc[li, samples[owned]] = rel.r[owned]
        mdb_loc[li, samples[owned]] = rel.mdb_m[owned]
        if rel.q is not None:
            q_loc[li, samples[owned]] = rel.q[owned]
        shift[li] = rel.shift_m[mine]
        worst[li] = samples[rel.worst_link[mine]] if rel.worst_link[mine] >= 0 else -1
        size[li], scale[li] = int(sub.estimated.sum()), rel.scale
    glob = ex.gather_nodes  # assembling the result: monitoring only (every entry was computed by its anchor)

    def per_sample(local: FloatArray) -> FloatArray:  # each sample's numbers from its owner's row
        return np.asarray(glob(local)[owner, np.arange(m)])

    return LocalReliability(
        r=per_sample(r_loc),
        q=per_sample(q_loc),
        mdb_m=per_sample(mdb_loc),
        shift_m=np.where(problem.estimated, glob(shift), 0.0),
        worst_link=np.asarray(glob(worst), np.int64),
        subnetwork_anchors=np.asarray(glob(size), np.int64),
        scale=glob(scale),
        lam0=lam0,
        rounds=hops + 1,
        comm=ex.comm_totals().since(before),
    )


def _checked_offsets(problem: RangingData, offsets: str, offsets_m: FloatArray | None) -> FloatArray:
    if offsets == "common_delays":  # LM's only: the distributed solvers refuse it (ranging.options.RunOptions)
        raise ModelError("the neighbourhoods' reliability takes offsets none, common or per_anchor, not common_delays")
    want = {"none": 0, "common": 1, "per_anchor": problem.n_anchors}[offsets]
    off = np.zeros(0) if offsets_m is None else np.atleast_1d(np.asarray(offsets_m, float))
    if offsets == "none":
        return np.zeros(0)
    if off.shape != (want,) or not np.all(np.isfinite(off)):
        raise ModelError(f"offsets {offsets!r} need {want} finite offset(s) of the solution, got {off.shape}")
    return off


def _own_records(problem: RangingData, est: FloatArray, off: FloatArray, offsets: str) -> FloatArray:
    """Every sample's record ``[sample, a, b, d, r̂_a, r̂_b (, b̂_a, b̂_b)]`` (module docstring): what either end
    can write after one exchange of estimates with the other, and what the flooding carries."""
    a, b = problem.meas_a, problem.meas_b
    cols = [np.arange(problem.n_meas, dtype=float)[:, None], a[:, None], b[:, None], problem.range_m[:, None]]
    cols += [est[a], est[b]]
    if offsets == "per_anchor":
        cols += [off[a][:, None], off[b][:, None]]
    rec: FloatArray = np.concatenate(cols, axis=1).astype(float)
    return rec


def _flood(problem: RangingData, ex: Exchange, est: FloatArray, table: FloatArray, hops: int) -> np.ndarray:
    """``known (n_local, m)``: which samples' records each local anchor holds: first its own links (the far end's
    estimate by one broadcast of the estimates), then after ``hops`` rounds in which every anchor broadcasts the
    records it learned in the round before (padded with id −1) those of every anchor within ``hops`` hops."""
    nl, m = ex.n_local, problem.n_meas
    ex.broadcast(est[ex.nodes])  # every anchor's own estimate to its neighbours (the records' far-end r̂)
    local_of = np.full(problem.n_anchors, -1, np.int64)
    local_of[ex.nodes] = np.arange(nl)
    known = np.zeros((nl, m), bool)
    for ends in (problem.meas_a, problem.meas_b):
        mine = local_of[ends] >= 0
        known[local_of[ends[mine]], np.flatnonzero(mine)] = True
    new = known.copy()
    width = table.shape[1]
    for _ in range(hops):
        counts = new.sum(axis=1)
        k = int(ex.allreduce(int(counts.max(initial=0)), "max"))  # the padding: one float per anchor, monitoring
        if k == 0:
            break
        out = np.full((nl, k, width), -1.0)
        rows, cols = np.nonzero(new)
        slot = np.arange(rows.size) - np.searchsorted(rows, rows)  # position within each anchor's list
        out[rows, slot] = table[cols]
        inbox = ex.broadcast(out.reshape(nl, k * width))
        got = inbox.values.reshape(-1, k, width)[inbox.delivered]
        dst = np.repeat(inbox.dst[inbox.delivered], k)
        ids = got.reshape(-1, width)[:, 0].astype(np.int64)
        valid = ids >= 0
        if not np.array_equal(got.reshape(-1, width)[valid], table[ids[valid]]):
            raise ModelError("a flooded link record differs from its owner's (inconsistent estimates)")
        after = known.copy()
        after[dst[valid], ids[valid]] = True
        new, known = after & ~known, after
    return known


def _ball(
    problem: RangingData, table: FloatArray, known: np.ndarray, me: int, hops: int, off: FloatArray, offsets: str
) -> tuple[RangingData, IntArray, IntArray, FloatArray] | None:
    """Anchor ``me``'s sub-network from the records it holds: the anchors within ``hops`` hops of it over the known
    links (``S``, their own free coordinates) and the ring beyond them (held at the records' estimates), the known
    samples among them; returns ``(sub-problem, its samples' global indices, its anchors' global ids, its free
    vector)`` or None without a free coordinate."""
    dim = problem.dim
    samples = np.flatnonzero(known)
    rec = table[samples]
    a, b = rec[:, 1].astype(np.int64), rec[:, 2].astype(np.int64)
    anchors = np.unique(np.concatenate([a, b, [me]]))
    loc = {int(v): k for k, v in enumerate(anchors)}
    la = np.array([loc[int(v)] for v in a], np.int64)
    lb = np.array([loc[int(v)] for v in b], np.int64)
    dist = _hops_from(anchors.size, la, lb, loc[me])
    inside = dist <= hops
    pos = np.zeros((anchors.size, dim))
    pos[la], pos[lb] = rec[:, 4 : 4 + dim], rec[:, 4 + dim : 4 + 2 * dim]
    free = problem.free[anchors] & inside[:, None]
    if not free.any():
        return None
    sub = RangingData(
        ids=tuple(problem.ids[int(v)] for v in anchors),
        dim=dim,
        positions_m=np.where(problem.free[anchors], pos, problem.positions_m[anchors]),
        free=free,
        meas_a=la,
        meas_b=lb,
        range_m=rec[:, 3].copy(),
    )
    tail: FloatArray = np.zeros(0)
    if offsets == "common":
        tail = off[:1].copy()  # the common offset: every anchor holds the solution's
    elif offsets == "per_anchor":
        tail = np.zeros(anchors.size)
        tail[la], tail[lb] = rec[:, 4 + 2 * dim], rec[:, 5 + 2 * dim]
    x = np.concatenate([sub.to_vector(pos), tail])
    return sub, samples, anchors, x


def _hops_from(n: int, a: IntArray, b: IntArray, start: int) -> IntArray:
    """Breadth-first hop counts from ``start`` over the links ``(a, b)`` (a large number where unreachable)."""
    dist = np.full(n, n + 1, np.int64)
    dist[start] = 0
    frontier = np.array([start])
    d = 0
    while frontier.size:
        d += 1
        hit = np.isin(a, frontier)
        nxt = np.concatenate([b[hit], a[np.isin(b, frontier)]])
        nxt = np.unique(nxt[dist[nxt] > d])
        dist[nxt] = d
        frontier = nxt
    return dist
