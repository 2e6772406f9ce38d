"""Per-anchor precision that admits the antenna delays the model does not estimate (a *consider* covariance).

LM's a-posteriori covariance ``σ̂² (JᵀWJ)⁻¹`` (:func:`distnav.algorithms.ranging.qc.centralized_quality`) treats
the range errors as independent. Per-node antenna delays are not: anchor ``i``'s delay ``δ_i`` lengthens every
range it takes part in, ``d_ab + δ_a + δ_b`` (the convention of ``range_offsets="per_anchor"``). A common offset
(the default) removes their mean; what is left moves the anchors coherently, and on simulated halls with
delays N(0, (1.5 cm)²) per node (``HallConfig.antenna_delay_sd_m`` 3 cm on ``(δ_a + δ_b)/2``) the plain
covariance covers 2σ in 77–94 % instead of 95 %.

Rather than estimate 28 more unknowns (which a plant-like network with 7.5 links per anchor cannot carry: the
RMSE doubles, docs/uwb.md), the delays are *considered* (the orbit determiners' consider covariance, e.g.
Tapley, Schutz & Born, *Statistical Orbit Determination*, 2004, §6.4): with ``G`` the ``∂range/∂δ`` incidence
(1 at both ends of every link) whitened like ``J``, the estimate's error from delays of covariance
``σ_δ² I`` is ``−(JᵀWJ)⁻¹ JᵀW G δ``, so

    C = σ̂²_noise Q + σ_δ² B Bᵀ,   Q = (JᵀWJ)⁻¹,   B = Q JᵀW G,

where ``σ̂²_noise`` is the a-posteriori variance factor less the delays' expected share of the weighted residual
sum, ``σ_δ² tr(Gᵀ Pᵀ W P G) / redundancy`` (``P = I − J Q JᵀW``; a variance-component split, at least
:data:`MIN_NOISE_SHARE` of σ̂²): without it the delays are counted twice (a 12-anchor Monte Carlo: 99 % coverage
of 2σ instead of 95 %).

The estimates do not change (no RMSE is traded), only their σ. ``σ_δ`` is a prior (``FieldOptions.delay_sigma_m``;
0 switches it off); its default was chosen by Monte Carlo over simulated halls (docs/uwb.md, "Precision"). With
``estimate_delays`` (``FieldOptions.estimate_delays``, the default in ``uwb solve``) the prior is a floor: the
delays' σ is also estimated from the residuals (:func:`delay_sigma_estimate`, a two-component variance estimate)
and the larger is used — uncalibrated hardware with 5 cm delays per anchor no longer gets 1.5 cm σ
(docs/uwb.md, "Stress test"). What is used is the estimate's one-sided 95 % upper bound (:data:`DELAY_UPPER_Z`):
the estimate from one network of 28 anchors scatters widely (0.023–0.062 m for true 0.038–0.059 m), and one too
low leaves σ too small — anchors 3σ off reported plainly ``estimated`` (docs/uwb.md, "External reliability").
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from distnav.algorithms.ranging.covariance import MIN_NOISE_SHARE
from distnav.algorithms.ranging.losses import robust_weights
from distnav.algorithms.ranging.objective import RangeObjective
from distnav.models.uwb.problems import RangingProblem
from distnav.typing import FloatArray

__all__ = [
    "consider_sigma",
    "consider_precision",
    "DELAY_UPPER_Z",
    "MIN_NOISE_SHARE",
    "delay_sigma_estimate",
    "delay_variance_estimate",
]


def consider_sigma(problem: RangingProblem, result: Any, **settings: Any) -> FloatArray | None:
    """σ per anchor and axis ``(n, dim)`` (0 at known coordinates) of an LM metres-objective ``result`` on
    ``problem`` (the links it was fitted on), with per-anchor delays of σ ``delay_sigma_m`` considered (module
    docstring). None when the result carries no free vector or variance factor, or the normal matrix is singular.
    ``settings``: those of :func:`consider_precision` (``sigma_m``, ``offsets``, ``loss``, ``loss_scale_m``,
    ``delay_sigma_m``, ``offset_prior_sigma_m``, ``estimate_delays``).
    """
    out = consider_precision(problem, result, **settings)
    return None if out is None else out[0]


def delay_variance_estimate(J: Any, G: Any, r: FloatArray, w: FloatArray, Q: FloatArray) -> tuple[float, float]:
    """``(σ̂_δ², its standard deviation)`` (m²) of the per-anchor delays from the residuals by a two-component
    variance estimate (MINQUE-like moment equations; Koch, *Parameter Estimation and Hypothesis Testing in Linear
    Models*, 1999, §3.6): with the whitened residual maker ``M = I − W½ J Q Jᵀ W½`` and ``G̃ = W½ G``, ``ẽ = W½ r``
    has ``E ẽᵀẽ = s² tr M + σ_δ² tr A`` and ``E ‖G̃ᵀẽ‖² = s² tr A + σ_δ² tr A²`` (``A = G̃ᵀ M G̃``): delays show as
    residuals that share an anchor. The standard deviation is that of the moment estimate for normal errors:
    ``Cov(ẽᵀBᵢẽ, ẽᵀBⱼẽ) = 2 tr(Bᵢ Σ Bⱼ Σ)`` with ``B₁ = I``, ``B₂ = G̃G̃ᵀ`` and ``Σ = s² M + σ_δ² M G̃ G̃ᵀ M`` at the
    estimates (negative components as 0), mapped through the inverse of the 2 × 2 system. σ̂_δ² may be negative
    (no delays seen); ``(0, 0)`` when the system is singular. Dense (``m × m``): small networks only."""
    sw = np.sqrt(np.asarray(w, float))
    Jt = np.asarray(J.toarray() if sp.issparse(J) else J) * sw[:, None]
    Gt = np.asarray(G.toarray() if sp.issparse(G) else G) * sw[:, None]
    e = sw * np.asarray(r, float)
    M = np.eye(e.size) - Jt @ Q @ Jt.T
    A = Gt.T @ M @ Gt
    lhs = np.array([[np.trace(M), np.trace(A)], [np.trace(A), float(np.sum(A * A))]])
    rhs = np.array([float(e @ e), float(np.sum((Gt.T @ e) ** 2))])
    try:
        inv = np.linalg.inv(lhs)
    except np.linalg.LinAlgError:
        return 0.0, 0.0
    s2, d2 = inv @ rhs
    if d2 > 0 and s2 <= 0:  # the delays explain all the scatter (the noise weight σ was set too large)
        d2, s2 = rhs[1] / lhs[1, 1], 0.0
    MG = M @ Gt
    S = max(s2, 0.0) * M + max(d2, 0.0) * (MG @ MG.T)
    SB = (S, Gt @ (Gt.T @ S))  # Σ B₁, B₂ Σ (symmetric factors: tr(Bᵢ Σ Bⱼ Σ) = Σ (BᵢΣ) ∘ (BⱼΣ)ᵀ)
    C = np.array([[2.0 * float(np.sum(SB[i] * SB[j].T)) for j in range(2)] for i in range(2)])
    var = inv @ C @ inv.T
    return float(d2), float(np.sqrt(max(var[1, 1], 0.0)))


def delay_sigma_estimate(J: Any, G: Any, r: FloatArray, w: FloatArray, Q: FloatArray, *, upper_z: float = 0.0) -> float:
    """σ_δ (m) of the per-anchor delays from :func:`delay_variance_estimate`: ``√(σ̂_δ² + upper_z · sd)``
    (``upper_z`` 0: the point estimate; 1.645: its one-sided 95 % upper bound); 0 when that is ≤ 0."""
    d2, sd = delay_variance_estimate(J, G, r, w, Q)
    v = d2 + upper_z * sd
    return float(np.sqrt(v)) if v > 0 else 0.0


DELAY_UPPER_Z = 1.645  # σ_δ from the residuals: the one-sided 95 % upper bound of the estimate, not the estimate


ESTIMATE_MAX_ROWS = 2000  # the delay estimate forms an m × m residual maker: skipped on larger networks


def consider_precision(
    problem: RangingProblem,
    result: Any,
    *,
    sigma_m: float,
    offsets: str,
    loss: str,
    loss_scale_m: float,
    delay_sigma_m: float,
    offset_prior_sigma_m: float = 0.1,
    estimate_delays: bool = False,
) -> tuple[FloatArray, FloatArray] | None:
    """``(σ, covariance blocks)`` of :func:`consider_sigma`: σ ``(n, dim)`` and each anchor's ``dim × dim`` block
    ``(n, dim, dim)`` of ``C = σ̂²_noise Q + σ_δ² B Bᵀ`` in m² (zero rows and columns at known coordinates), so
    the ellipses drawn from the blocks are those of the σ written."""
    x = getattr(result, "x", None)
    prec = getattr(result, "precision", None)
    if x is None or prec is None or prec.variance_factor is None:
        return None
    obj = RangeObjective(problem, "metres", sigma_m, offsets, offset_prior_sigma_m)
    x = np.asarray(x, float)
    if x.size != obj.n_x:
        return None
    J = sp.csr_matrix(obj.jacobian(x))
    r = obj.residual(x)
    w = robust_weights(r, obj.loss_scale(loss_scale_m), loss)[0] if loss != "linear" else np.ones_like(r)
    JW = sp.csr_matrix(J.T @ sp.diags(w))
    N = np.asarray((JW @ J).toarray())
    try:
        Q = sla.cho_solve(sla.cho_factor(N, check_finite=False), np.eye(obj.n_x), check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return None
    m, n = problem.n_meas, problem.n_anchors
    inv_sigma = 1.0 / obj.sigma
    G = sp.csr_matrix(
        (
            np.concatenate([inv_sigma, inv_sigma]),
            (np.concatenate([np.arange(m)] * 2), np.concatenate([problem.meas_a, problem.meas_b])),
        ),
        shape=(J.shape[0], n),
    )
    if estimate_delays and J.shape[0] <= ESTIMATE_MAX_ROWS:  # the prior is a floor: larger delays seen are used
        delay_sigma_m = max(delay_sigma_m, delay_sigma_estimate(J, G, r, w, Q, upper_z=DELAY_UPPER_Z))
    JWG = np.asarray((JW @ G).toarray())  # n_x × n
    B = Q @ JWG
    # the variance factor σ̂² = Σ w r² / redundancy also holds the delays' share of the residuals,
    # σ_δ² tr(Gᵀ Pᵀ W P G) / redundancy with P G = G − J B (the residual maker): taken out, not counted twice.
    # tr(Gᵀ Pᵀ W P G) = tr(GᵀWG) − tr(BᵀJᵀWG) (N B = JᵀWG), without forming the m × n product
    trace = float(np.sum(w[:m] * 2.0 * inv_sigma**2)) - float(np.sum(JWG * B))
    redundancy = float(prec.redundancy) if prec.redundancy else 0.0
    share = delay_sigma_m**2 * trace / redundancy if redundancy > 0 else 0.0
    s2 = max(float(prec.variance_factor) - share, MIN_NOISE_SHARE * float(prec.variance_factor))
    var = s2 * np.diag(Q) + delay_sigma_m**2 * np.einsum("ij,ij->i", B, B)
    out = np.zeros(problem.free.shape)
    out[problem.free] = np.sqrt(np.maximum(var[: problem.n_free], 0.0))
    idx = np.full(problem.free.shape, -1)
    idx[problem.free] = np.arange(problem.n_free)  # the free coordinates lead x, anchor by anchor
    valid = idx >= 0
    at = np.where(valid, idx, 0)
    pair = valid[:, :, None] & valid[:, None, :]
    Bq = B[at] * valid[..., None]  # (n, dim, n_anchors)
    blocks = np.where(pair, s2 * Q[at[:, :, None], at[:, None, :]], 0.0) + delay_sigma_m**2 * (
        Bq @ Bq.transpose(0, 2, 1)
    )
    return out, blocks
