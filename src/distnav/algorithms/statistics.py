"""Test statistics of least-squares residuals: w-tests, the variance factor and centralized data snooping.

These are the building blocks of quality control in every solver family. They are written once here and computed
by each node on what it holds (its residuals and their variances); the distributed solvers supply those, and the
models map the statistics to their observations (a UWB link, a GNSS arc).

Notation (Baarda's data snooping; Teunissen, *Testing Theory*, 2006, ch. 4): the model ``E{y} = A x``,
``D{y} = σ² R``, the BLUE ``x̂`` with covariance ``Q_x̂ = (Aᵀ R⁻¹ A)⁻¹`` (a generalized inverse where A is rank
deficient: ``Q_ê`` below does not depend on which), residuals ``ê = y − A x̂`` with covariance
``Q_ê = R − A Q_x̂ Aᵀ``. The w-test of observation i (the alternative "observation i has a gross error") is

    w_i = (R⁻¹ ê)_i / sqrt((R⁻¹ Q_ê R⁻¹)_ii),

which for uncorrelated observations is ``ê_i / sqrt((Q_ê)_ii)``; under H0 it is N(0, 1). The a-posteriori variance
factor is ``σ̂² = êᵀ R⁻¹ ê / r`` with redundancy ``r = m − rank(A)``; under H0, ``r σ̂²`` is χ²(r).

Reliability (Baarda, *A testing procedure for use in geodetic networks*, 1968; Teunissen 2006 §4.4): for
uncorrelated observations with weights ``p_i = 1/σ_i²`` the **redundancy number** ``r_i = 1 − p_i a_i Q_x̂ a_iᵀ``
(the diagonal of ``Q_ê R⁻¹``; ``Σ r_i = m − rank(A)``) is the share of a gross error ``∇_i`` that shows in its own
residual. The **minimal detectable bias** ``∇_i = σ_i √(λ0 / r_i)`` is the error the w-test finds with probability
``power`` at level α, ``λ0 = (k_α + Φ⁻¹(power))²`` (17.07 for α = 0.001, power 0.8: Baarda's δ0 = 4.13). Its
effect on the estimate, ``∇x̂_i = Q_x̂ a_iᵀ p_i ∇_i``, is the **external reliability**: what an error just too small
to be found does to the unknowns. ``r_i ≈ 0``: nothing checks observation i (∇_i infinite).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from distnav._checks import real_number
from distnav.errors import ModelError
from distnav.typing import ArrayLike, BoolArray, FloatArray, IntArray

__all__ = [
    "SnoopingOutcome",
    "critical_value",
    "data_snooping",
    "minimal_detectable_bias",
    "noncentrality",
    "redundancy_numbers",
    "residual_covariance",
    "variance_factor",
    "variance_factor_test",
    "w_statistics",
]

_TINY_VARIANCE = 1e-12


def critical_value(level: float) -> float:
    """Two-sided critical value of the w-test: |w| > k_α rejects at false-alarm probability ``level``.

    ``level`` = 0.001 gives 3.29 (Baarda's choice; with power 80 % it detects a gross error that shifts w by 4.13).

    Examples
    --------
    >>> from distnav.algorithms.statistics import critical_value
    >>> round(critical_value(0.001), 2), round(critical_value(0.05), 2)
    (3.29, 1.96)
    """
    level = real_number(level, "test level", error=ModelError)
    if not 0.0 < level < 1.0:
        raise ModelError(f"test level must lie in (0, 1), got {level!r}")
    return float(-special.ndtri(level / 2.0))  # N(0, 1) upper quantile (scipy.stats.norm.isf's own formula)


def w_statistics(
    weighted_residual: ArrayLike, variance: ArrayLike, *, relative_floor: float = _TINY_VARIANCE
) -> FloatArray:
    """w-test statistics ``w_i = v_i / sqrt(q_i)`` (NaN where ``q_i`` is zero: an observation nobody else checks).

    Parameters
    ----------
    weighted_residual : ``(R⁻¹ ê)_i`` per observation (``ê_i / σ_i²`` for uncorrelated ones), or ``ê_i`` itself when
        ``variance`` is the residual variance ``(Q_ê)_ii`` (the two forms agree for uncorrelated observations).
    variance : matching variance: ``(R⁻¹ Q_ê R⁻¹)_ii`` for the weighted form, ``(Q_ê)_ii`` for the plain form.
    relative_floor : a variance below ``relative_floor × max(variance)`` counts as zero (rounding of ``R − A Q Aᵀ``).
    """
    v = np.asarray(weighted_residual, dtype=float)
    q = np.asarray(variance, dtype=float)
    if v.shape != q.shape:
        raise ModelError(f"residuals {v.shape} and variances {q.shape} differ in shape")
    if np.any(q < -1e-9 * max(float(np.max(np.abs(q), initial=0.0)), 1.0)):
        raise ModelError("residual variances must be non-negative")
    floor = relative_floor * float(np.max(q, initial=0.0))
    out = np.full(v.shape, np.nan)
    ok = q > floor
    out[ok] = v[ok] / np.sqrt(q[ok])
    return out


def variance_factor(weighted_ssr: float, redundancy: float) -> float | None:
    """A-posteriori variance factor ``σ̂² = êᵀ R⁻¹ ê / r``; ``None`` without redundancy (nothing to estimate it from).

    Examples
    --------
    >>> from distnav.algorithms.statistics import variance_factor
    >>> variance_factor(12.0, 10), variance_factor(3.0, 0) is None
    (1.2, True)
    """
    if weighted_ssr < 0.0 or not np.isfinite(weighted_ssr):
        raise ModelError(f"weighted residual sum of squares must be finite and ≥ 0, got {weighted_ssr!r}")
    if redundancy <= 0:
        return None
    return float(weighted_ssr / redundancy)


def variance_factor_test(
    weighted_ssr: float, redundancy: float, level: float = 0.05
) -> tuple[float | None, tuple[float, float], bool]:
    """Two-sided χ² test of ``σ̂²`` against 1: returns ``(σ̂², (lower, upper) bounds for σ̂², accepted)``."""
    s2 = variance_factor(weighted_ssr, redundancy)
    if s2 is None:
        return None, (float("nan"), float("nan")), True
    # χ²(r) quantiles by scipy.stats.chi2's own formulas (scipy.special: importing scipy.stats costs ~1.3 s CPU)
    lo = float(2.0 * special.gammaincinv(redundancy / 2.0, level / 2.0) / redundancy)
    hi = float(special.chdtri(redundancy, level / 2.0) / redundancy)
    return s2, (lo, hi), bool(lo <= s2 <= hi)


def noncentrality(level: float = 0.001, power: float = 0.8) -> float:
    """``λ0 = (k_α + Φ⁻¹(power))²``: the non-centrality of the (two-sided, one-dimensional) w-test at false-alarm
    probability ``level`` that a gross error must reach to be found with probability ``power`` (the far tail of
    the two-sided test neglected, as in Baarda's tables: 17.07 for 0.001 / 0.8)."""
    if not 0.0 < power < 1.0:
        raise ModelError(f"test power must lie in (0, 1), got {power!r}")
    return float((critical_value(level) + special.ndtri(power)) ** 2)


def redundancy_numbers(A: ArrayLike, weight: ArrayLike, Qx: ArrayLike) -> FloatArray:
    """Redundancy numbers ``r_i = 1 − p_i a_i Q_x̂ a_iᵀ`` of uncorrelated observations with weights ``p_i`` (the
    diagonal of ``I − A Q_x̂ Aᵀ P``, module docstring), clipped to [0, 1]; ``A`` dense or scipy sparse."""
    p = np.asarray(weight, dtype=float)
    Q = np.asarray(Qx, dtype=float)
    if hasattr(A, "toarray"):
        AQ = np.asarray(A @ Q)
        h = np.asarray(A.multiply(AQ).sum(axis=1)).ravel()  # type: ignore[union-attr]
    else:
        A_ = np.atleast_2d(np.asarray(A, dtype=float))
        h = np.einsum("ij,jk,ik->i", A_, Q, A_)
    if h.shape != p.shape:
        raise ModelError(f"{h.size} observations but {p.size} weights")
    return np.asarray(np.clip(1.0 - p * h, 0.0, 1.0))


def minimal_detectable_bias(
    sigma: ArrayLike,
    redundancy: ArrayLike,
    lam0: float,
    *,
    residual_variance: ArrayLike | None = None,
    min_redundancy: float = 1e-6,
) -> FloatArray:
    """Minimal detectable bias ``∇_i = σ_i √λ0 √q_i / r_i`` (module docstring): the gross error that moves observation
    i's w-statistic ``ê_i / (σ_i √q_i)`` by ``√λ0``. ``q_i`` is the variance of its standardized residual the test
    divides by: ``r_i`` itself for least squares with the weights of the model (the default; then
    ``∇_i = σ_i √(λ0 / r_i)``), otherwise e.g. that of a robust fit with fixed weights. Infinite where
    ``r_i < min_redundancy`` (an observation nothing else checks)."""
    s = np.asarray(sigma, dtype=float)
    r = np.asarray(redundancy, dtype=float)
    q = r if residual_variance is None else np.asarray(residual_variance, dtype=float)
    s, r, q = np.broadcast_arrays(s, r, q)
    out = np.full(r.shape, np.inf)
    ok = r >= min_redundancy
    out[ok] = s[ok] * np.sqrt(lam0 * np.maximum(q[ok], 0.0)) / r[ok]
    return out


def residual_covariance(A: FloatArray, R: FloatArray, Qx: FloatArray) -> FloatArray:
    """``Q_ê = R − A Q_x̂ Aᵀ`` (symmetrized)."""
    Q = R - A @ Qx @ A.T
    return 0.5 * (Q + Q.T)


@dataclass(frozen=True, eq=False)
class SnoopingOutcome:
    """Result of centralized iterative data snooping (the reference for the distributed procedures).

    ``x`` the BLUE without the removed observations, ``covariance`` its ``Q_x̂`` (σ² = 1), ``w`` the w-statistics of
    every observation in the final solution (removed ones: NaN), ``removed`` the observation indices in the order
    they were removed, ``flagged`` |w| > critical value in the final solution (empty when the loop ended normally),
    ``variance_factor`` σ̂² of the final solution, ``redundancy`` its m − rank(A).
    """

    x: FloatArray
    covariance: FloatArray
    w: FloatArray
    removed: tuple[int, ...]
    flagged: BoolArray
    variance_factor: float | None
    redundancy: int
    critical_value: float


def _blue(A: FloatArray, y: FloatArray, R: FloatArray, rcond: float) -> tuple[FloatArray, FloatArray, int]:
    Ri = np.linalg.inv(R)
    N = A.T @ Ri @ A
    Qx: FloatArray = np.asarray(np.linalg.pinv(N, rcond=rcond, hermitian=True), dtype=float)
    rank = int(np.linalg.matrix_rank(N, tol=rcond * max(float(np.abs(N).max(initial=0.0)), 1e-300), hermitian=True))
    return Qx @ (A.T @ Ri @ y), Qx, rank


def data_snooping(
    A: ArrayLike,
    y: ArrayLike,
    R: ArrayLike,
    *,
    level: float = 0.001,
    max_removals: int | None = None,
    keep: ArrayLike | None = None,
    rcond: float = 1e-10,
) -> SnoopingOutcome:
    """Centralized iterative data snooping: remove the observation with the largest |w| above the critical value,
    re-solve, repeat until nothing is flagged (or ``max_removals``, or no observation may go without losing rank).

    ``keep`` (boolean per observation) marks observations that must not be removed. An observation whose removal
    would make a parameter inestimable is never removed (its residual variance is zero, so its w is NaN anyway).
    """
    A_ = np.atleast_2d(np.asarray(A, dtype=float))
    y_ = np.asarray(y, dtype=float)
    R_ = np.asarray(R, dtype=float)
    m = A_.shape[0]
    if y_.shape != (m,):
        raise ModelError(f"y must have shape ({m},), got {y_.shape}")
    if R_.ndim == 1:
        R_ = np.diag(R_)
    if R_.shape != (m, m):
        raise ModelError(f"R must be ({m}, {m}) or ({m},), got {R_.shape}")
    removable = np.ones(m, dtype=bool) if keep is None else ~np.asarray(keep, dtype=bool)
    k = critical_value(level)
    active: IntArray = np.arange(m)
    removed: list[int] = []
    limit = m if max_removals is None else int(max_removals)
    while True:
        Aa, ya, Ra = A_[active], y_[active], R_[np.ix_(active, active)]
        x, Qx, rank = _blue(Aa, ya, Ra, rcond)
        e = ya - Aa @ x
        Ri = np.linalg.inv(Ra)
        Qe = residual_covariance(Aa, Ra, Qx)
        v = Ri @ e
        q = np.sum((Ri @ Qe) * Ri, axis=1)  # diag(R⁻¹ Q_ê R⁻¹) in O(m²) after one product (R⁻¹ is symmetric)
        w = w_statistics(v, q)
        aw = np.where(np.isfinite(w) & removable[active], np.abs(w), -np.inf)
        worst = int(np.argmax(aw))
        if aw[worst] <= k or len(removed) >= limit:
            break
        removed.append(int(active[worst]))
        active = np.delete(active, worst)
    w_all = np.full(m, np.nan)
    w_all[active] = w
    flagged = np.zeros(m, dtype=bool)
    flagged[active] = np.abs(np.nan_to_num(w)) > k
    redundancy = len(active) - rank
    return SnoopingOutcome(
        x=x,
        covariance=Qx,
        w=w_all,
        removed=tuple(removed),
        flagged=flagged,
        variance_factor=variance_factor(float(e @ Ri @ e), redundancy),
        redundancy=redundancy,
        critical_value=k,
    )
