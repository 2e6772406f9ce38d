"""External reliability of a field solve: which anchors one undetected bad link could move unseen.

The numbers themselves (redundancy numbers, MDB, worst shift) are computed in
:mod:`distnav.algorithms.ranging.reliability`: centrally for LM, by every anchor from its neighbourhood's link
records for the distributed solvers (:data:`LOCAL_HOPS` hops; issue 28 item 5). This module maps them to anchors
(weak, with a reason) and to ``summary.json``.

The link tests (w-tests, :mod:`distnav.algorithms.ranging.qc`) find an NLOS link only when its bias shows in its
own residual. Baarda's reliability (:mod:`distnav.algorithms.statistics`, module docstring) says how large a bias
must be to be found — the **minimal detectable bias** of link l, ``∇_l = σ_l ŝ √λ0 √q_l / r_l`` — and what a bias
of that size, still undetected, does to the anchors: ``∇x̂_l = Q J_lᵀ w_l ∇_l / σ_l`` (``J`` the whitened Jacobian
of the metres objective at the solution, ``W`` the final IRLS weights of the robust loss, ``Q = (JᵀWJ)⁻¹``,
``r_l = 1 − w_l j_l Q j_lᵀ`` the redundancy number, ``q_l`` the residual variance the w-test divides by, ``ŝ`` the
test's robust scale, ``λ0`` the non-centrality of α = ``FieldOptions.level`` and power 0.8). This is the
linearization at the solution; the tests check it against re-fitting with the bias added to the range.

An anchor is reported **weak** (reason ``reliability``) when the largest such shift over all kept links,
measured on its free coordinates, exceeds both ``limit_m`` (``FieldOptions.reliability_limit_m``: the error a user
would call wrong, default 0.3 m — the stress bench's definition of an anchor "off") and 3 × its own σ (σ already
warns of a shift within 3σ). The rule has a statistical reason (a bias the test misses with 20 % probability moves
the anchor further than its σ and the limit admit), no threshold fitted to the halls reported (docs/uwb.md, "External
reliability"). A link with ``r_l ≈ 0`` is checked by nothing: its MDB is infinite and every anchor it moves is weak.

Departures: Baarda's MDB is for least squares with known weights; here the weights are the robust loss's at the
solution (for a link inside the loss scale ≈ 1) and σ is scaled by the test's robust scale ``ŝ`` (the w-tests use
it). Per-anchor antenna delays are not in this model (the precision *considers* them; a delay is a bias on every
link of one anchor, not one link's). Dense ``Q``: skipped with a note above :data:`MAX_FREE` free coordinates.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import special

from distnav.algorithms.ranging.qc import robust_scale
from distnav.algorithms.ranging.reliability import (
    MAX_FREE,
    POWER,
    ExternalReliability,
    ReliabilityOptions,
    external_reliability,
    local_reliability,
)
from distnav.errors import ModelError
from distnav.models.uwb.communication import gathered_up
from distnav.models.uwb.problems import RangingProblem
from distnav.network.gather import gather_cost
from distnav.typing import BoolArray, FloatArray

__all__ = [
    "LOCAL_HOPS",
    "MAX_FREE",
    "POWER",
    "RELIABILITY_LIMIT_M",
    "WEAK_RMS_M",
    "ExternalReliability",
    "ReliabilityOptions",
    "check_reliability",
    "undetected_nlos_covariance",
    "with_covariance",
    "distributed_free_vector",
    "external_reliability",
    "reliability_weak",
    "weak_anchor_reasons",
    "weak_anchors",
]

RELIABILITY_LIMIT_M = 0.3  # default shift one undetected link may cause before the anchor is reported weak
LOCAL_HOPS = 4  # the distributed solvers' neighbourhoods (docs/uwb.md, "Reliability from the anchors' neighbourhoods")


def reliability_weak(
    problem: RangingProblem, rel: ExternalReliability, sigma_m: FloatArray, *, limit_m: float = RELIABILITY_LIMIT_M
) -> dict[str, str]:
    """Anchors whose worst undetected-link shift exceeds ``limit_m`` and 3 × their σ (the norm of σ over their free
    coordinates), each with its reason: which link would go undetected, its MDB, and how far it would move it."""
    sig = np.sqrt(np.nansum(np.where(problem.free, np.asarray(sigma_m, float), 0.0) ** 2, axis=1))
    out: dict[str, str] = {}
    for i in np.flatnonzero(problem.estimated & (rel.shift_m > np.maximum(limit_m, 3.0 * sig))):
        k = int(rel.worst_link[i])
        a, b = problem.ids[problem.meas_a[k]], problem.ids[problem.meas_b[k]]
        mdb = float(rel.mdb_m[k])
        out[problem.ids[i]] = (
            f"reliability: link {a}-{b} is checked by nothing else (redundancy number {rel.r[k]:.2g})"
            if not np.isfinite(mdb)
            else f"reliability: an undetected bias of {mdb:.2f} m on link {a}-{b} (its minimal "
            f"detectable bias; redundancy number {rel.r[k]:.2f}) would move it "
            f"{rel.shift_m[i]:.2f} m"
        )
    return out


def describe(rel: ExternalReliability | None, weak: dict[str, str], limit_m: float) -> dict[str, Any]:
    """The summary.json entry: what was tested and what it found."""
    if rel is None:
        return {"tested": False}
    fin = rel.shift_m[np.isfinite(rel.shift_m) & (rel.shift_m > 0)]
    return {
        "tested": True,
        "lambda0": rel.lam0,
        "power": POWER,
        "robust_scale": rel.scale,
        "limit_m": limit_m,
        "max_shift_m": float(fin.max()) if fin.size else None,
        "unchecked_links": int(np.sum(~np.isfinite(rel.mdb_m))),
        "weak": sorted(weak),
    }


WEAK_RMS_M = 0.15


def weak_anchor_reasons(
    problem: RangingProblem,
    residual_m: FloatArray,
    excluded: BoolArray,
    flagged: BoolArray,
    *,
    limit_m: float = WEAK_RMS_M,
) -> dict[str, str]:
    """Anchors with an excluded or flagged link whose kept links still misfit by more than ``limit_m`` RMS (or 3 ×
    the network's robust residual scale, if larger) at the solution: the exclusions could not find a consistent
    subset of their links; and anchors with at most one redundant link left (3 links for 2 coordinates, with or
    without exclusions: one NLOS link among them moves the anchor by metres while its residuals stay at a few cm,
    and 4 links of which 2 are NLOS fit the wrong pair exactly). Each with its reason (``misfit: …``, ``thin: …``)."""
    kept = ~np.asarray(excluded, bool)
    n = problem.n_anchors
    a, b = problem.meas_a, problem.meas_b
    e2 = np.where(kept, residual_m**2, 0.0)
    ssr = np.bincount(a, e2, minlength=n) + np.bincount(b, e2, minlength=n)
    cnt = np.bincount(a[kept], minlength=n) + np.bincount(b[kept], minlength=n)
    touched = np.zeros(n, bool)
    bad = ~kept | np.asarray(flagged, bool)
    touched[a[bad]] = True
    touched[b[bad]] = True
    rms = np.sqrt(ssr / np.maximum(cnt, 1))
    scale = robust_scale(residual_m[kept]) if kept.any() else 0.0
    limit = max(limit_m, 3.0 * scale)  # a network whose every link misfits (range bias) is not "weak" here
    # at most one redundant link (kept): one NLOS link there shifts the anchor with residuals too small to test,
    # and could not be located if it were detected
    need = problem.free.sum(axis=1)
    thin = cnt <= need + 1
    misfit = touched & (rms > limit)
    out: dict[str, str] = {}
    for i in np.flatnonzero(problem.estimated & (misfit | thin)):
        out[problem.ids[i]] = (
            f"misfit: its kept links misfit by {rms[i]:.2f} m RMS after the exclusions (limit {limit:.2f} m)"
            if misfit[i]
            else f"thin: {int(cnt[i])} kept links for {int(need[i])} coordinates"
        )
    return out


def weak_anchors(
    problem: RangingProblem,
    residual_m: FloatArray,
    excluded: BoolArray,
    flagged: BoolArray,
    *,
    limit_m: float = WEAK_RMS_M,
) -> tuple[str, ...]:
    """The anchors of :func:`weak_anchor_reasons`, in problem order."""
    return tuple(weak_anchor_reasons(problem, residual_m, excluded, flagged, limit_m=limit_m))


def distributed_free_vector(problem: RangingProblem, result: Any) -> FloatArray | None:
    """``x = [free coordinates, offsets]`` (:class:`~distnav.algorithms.ranging.objective.RangeObjective`'s layout)
    of a distributed solver's result (``estimates``, ``offsets_m``); None without estimates."""
    est = getattr(result, "estimates", None)
    if est is None:
        return None
    off = getattr(result, "offsets_m", None)
    tail = np.zeros(0) if off is None else np.atleast_1d(np.asarray(off, float))
    x: FloatArray = np.concatenate([problem.to_vector(np.asarray(est, float)), tail])
    return x


def undetected_nlos_covariance(
    problem: RangingProblem, rel: ExternalReliability | None, bias_m: FloatArray, weak: BoolArray | None = None
) -> FloatArray:
    """Per anchor ``(n, dim, dim)`` (m², zero at known coordinates): what NLOS links the exclusions left in may do to
    it — a *consider* covariance (Tapley, Schutz & Born 2004, §6.4) of the kept links' undetected biases, from the
    run's own data (issue 28: the tail of ``e/σ``, anchors 1.5–2.3 m off with σ of 0.1 m, were anchors one kept
    NLOS link moved unseen).

    ``problem`` holds the kept links, ``bias_m`` the excluded links' biases (their prediction residuals read long,
    ≥ 0). A kept link ``l`` is NLOS with the prior probability ``p`` = the share of the run's links excluded, with
    a bias drawn from the excluded ones, and left in when the w-test missed it: probability
    ``Φ(k − (k + z_β) b / MDB_l)`` (``k + z_β = √λ0``: 1 − power at the MDB, ≈ 1 at 0; 1 for an unchecked link). Its
    second moment ``E_l = p · mean_k(b_k² · P_miss,l(b_k))`` moves the anchors through the gain ``g_l = ∂x̂/∂b_l``
    (:class:`~distnav.algorithms.ranging.reliability.ExternalReliability`), the links independent:
    ``C_i = Σ_l E_l g_il g_ilᵀ``. Well-checked links (MDB of a few decimetres against NLOS biases of metres) add
    almost nothing. In a ``weak`` anchor's own block (per anchor; the run's reasons: thin, cut, misfit,
    reliability) its own links count as unchecked (``P_miss`` = 1): the test that would find their bias is what
    the anchor lacks, and the linearization at a wrong choice of links does not see it (a thin anchor whose good
    link was excluded and whose NLOS link was kept fits its 3 links exactly; the kept NLOS link then has r = 0.02
    and an MDB of 0.5 m, yet its 1.1 m bias went unseen: docs/uwb.md, "A σ that tells the truth"). Zero without
    excluded links (no prior to take) or central numbers (``rel.gain``)."""
    n, dim = problem.free.shape
    out = np.zeros((n, dim, dim))
    b = np.maximum(np.asarray(bias_m, float), 0.0)
    if rel is None or rel.gain is None or b.size == 0:
        return out
    share = b.size / (b.size + problem.n_meas)
    z_beta = float(special.ndtri(POWER))
    k = np.sqrt(rel.lam0) - z_beta
    mdb = np.asarray(rel.mdb_m, float)
    finite = np.isfinite(mdb)[:, None]
    ratio = np.where(finite, b[None, :] / np.where(finite, mdb[:, None], 1.0), 0.0)
    miss = np.where(finite, special.ndtr(k - (k + z_beta) * ratio), 1.0)  # (m kept, n excluded)
    e2 = share * np.mean(b[None, :] ** 2 * miss, axis=1)
    unchecked = share * float(np.mean(b**2))
    weak_mask = np.zeros(n, bool) if weak is None else np.asarray(weak, bool)
    col = np.full(problem.free.shape, -1, np.int64)
    col[problem.free] = np.arange(problem.n_free)
    for i in np.flatnonzero(problem.free.any(axis=1)):
        axes = np.flatnonzero(col[i] >= 0)
        g = rel.gain[col[i][axes]]
        own = np.where((problem.meas_a == i) | (problem.meas_b == i), unchecked, e2) if weak_mask[i] else e2
        out[i][np.ix_(axes, axes)] = (g * own) @ g.T
    return out


def with_covariance(sigma_m: FloatArray, covariance_m2: FloatArray | None, extra_m2: FloatArray) -> dict[str, Any]:
    """``{"sigma_m", "covariance_m2"}`` with the per-anchor blocks ``extra_m2`` added (σ from the new diagonal;
    NaN σ stay NaN, missing blocks stay missing)."""
    sigma = np.sqrt(np.asarray(sigma_m, float) ** 2 + np.diagonal(extra_m2, axis1=1, axis2=2))
    cov = None if covariance_m2 is None else np.asarray(covariance_m2, float) + extra_m2
    return {"sigma_m": sigma, "covariance_m2": cov}


def check_reliability(
    problem: RangingProblem,
    result: Any,
    anchor_sigma_m: FloatArray,
    options: ReliabilityOptions,
    *,
    limit_m: float,
    exchange: Any = None,
    hops: int = LOCAL_HOPS,
    gathered: bool = False,
) -> tuple[dict[str, str], dict[str, Any], str, ExternalReliability | None]:
    """:func:`external_reliability` and :func:`reliability_weak` on ``problem`` (the kept links): of an LM result
    centrally; of a distributed solver's by every anchor from its ``hops``-hop neighbourhood through ``exchange``
    (:func:`~distnav.algorithms.ranging.reliability.local_reliability`; None: in-process), its messages and bytes
    in the entry. ``gathered``: the run's σ already gathered every kept range and estimate at one anchor
    (``models.uwb.field_precision.gathered_precision``), which then computes the numbers exactly as LM's on this
    network and sends each anchor its own back with its covariance block (:func:`gathered_return_bytes`) —
    a 4-hop flood would cost a thousand times that on a plant-like hall (docs/economy_uwb.md). Returns ``(weak
    anchors with reasons, the summary.json entry, a note for the message, the numbers or None)``."""
    if problem.n_free > MAX_FREE:
        return (
            {},
            {"tested": False},
            (
                f"; external reliability not tested: {problem.n_free} free coordinates "
                f"(> {MAX_FREE}, the dense covariance it needs)"
            ),
            None,
        )
    x = getattr(result, "x", None)
    cost: dict[str, Any] = {}
    if x is not None:
        rel = external_reliability(problem, np.asarray(x, float), options)
        computed = "centrally on LM's solution"
    elif getattr(result, "estimates", None) is None:
        return {}, {"tested": False}, "; external reliability not tested (the solver gives no estimates)", None
    elif gathered:
        x_free = distributed_free_vector(problem, result)
        assert x_free is not None  # the result has estimates (the branch above)
        rel = external_reliability(problem, x_free, options)
        computed = "at the anchor that gathered the ranges for σ (the same numbers as LM's on this network)"
        per_anchor = options.offsets == "per_anchor"
        cost = {"rounds": 0, "messages": 0, "bytes": gathered_return_bytes(problem, per_anchor_offsets=per_anchor)}
    else:
        off = getattr(result, "offsets_m", None)
        try:
            loc = local_reliability(
                problem, np.asarray(result.estimates, float), options, offsets_m=off, hops=hops, exchange=exchange
            )
        except ModelError as err:  # e.g. a lost message
            return {}, {"tested": False}, f"; external reliability not tested ({err})", None
        rel = loc.as_external()
        computed = (
            f"by every anchor from the link records of its {hops}-hop neighbourhood ({loc.rounds} message rounds; "
            "the same numbers as LM's where the neighbourhood spans the network)"
        )
        cost = {
            "hops": hops,
            "rounds": loc.rounds,
            "messages": int(loc.comm.messages),
            "bytes": int(loc.comm.bytes),
            "largest_subnetwork": int(loc.subnetwork_anchors.max(initial=0)),
        }
    if rel is None:
        return {}, {"tested": False}, "; external reliability not tested (singular normal matrix)", None
    weak = reliability_weak(problem, rel, anchor_sigma_m, limit_m=limit_m)
    entry = {**describe(rel, weak, limit_m), "computed": computed, **cost}
    entry["shift_m"] = {  # per estimated anchor: its worst undetected-link shift (None: an unchecked link moves it)
        problem.ids[i]: (float(rel.shift_m[i]) if np.isfinite(rel.shift_m[i]) else None)
        for i in np.flatnonzero(problem.estimated)
    }
    return weak, entry, "", rel


#: What each estimated anchor gets back from the gathering anchor: its worst undetected-link shift (one value per
#: axis) and the smallest MDB of its links, float64.
RETURN_VALUES = 4


def gathered_return_bytes(problem: RangingProblem, *, per_anchor_offsets: bool = False) -> int:
    """Bytes that carry every estimated anchor's reliability numbers (:data:`RETURN_VALUES` float64) from the
    anchor that gathered the ranges for σ (the same sink and tree,
    :func:`~distnav.models.uwb.communication.gathered_up`) down to it, relayed hop by hop; they ride on the
    gathered σ's messages down (no message of their own)."""
    graph, up = gathered_up(problem, per_anchor_offsets=per_anchor_offsets)
    sink = up.sink
    per_anchor = 8 * RETURN_VALUES * problem.estimated.astype(np.int64)
    return int(gather_cost(graph, per_anchor, sink=sink).total_hop_bytes)
