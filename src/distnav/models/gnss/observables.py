"""GNSS code observables of paper 000 §5.1: frequency coefficients, ionosphere-free and geometry-free
combinations, the triple-frequency code-bias observable, between-satellite differencing, the S-basis, and the
elevation-dependent weighting with full variance propagation.

Conventions (paper 000, eqs. (24)–(26); typo of (25) fixed as in the papers README):

* ``μ_j = (f₁/f_j)²`` (μ₁ = 1);
* ionosphere-free  ``ȳ_IF = (μ₂ ȳ₁ − μ₁ ȳ₂)/(μ₂ − μ₁)``  — removes the first-order ionosphere;
* geometry-free    ``ȳ_GF = (ȳ₂ − ȳ₁)/(μ₂ − μ₁)``        — the slant ionospheric delay on f₁ plus biases;
* code-bias observable (24) ``y = ȳ₃ − ȳ_IF − μ₃ ȳ_GF`` — free of geometry (range, clocks, troposphere) and of
  the first-order ionosphere; only code biases (and noise) remain. As one linear combination
  ``y = c₁ȳ₁ + c₂ȳ₂ + c₃ȳ₃`` with ``c₁ = (μ₃ − μ₂)/(μ₂ − μ₁)``, ``c₂ = (μ₁ − μ₃)/(μ₂ − μ₁)``, ``c₃ = 1``
  (Σc = 0, Σcμ = 0).
* ``D_mᵀ`` (26) is ``[−e_{m−1}, I_{m−1}]``: each satellite minus the first (pivot) satellite.

The combinations of the same measurements are correlated; :func:`combination_covariance` propagates a full
covariance ``Q`` as ``C Q Cᵀ``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from distnav.errors import ModelError
from distnav.models.gnss.constants import mu

__all__ = [
    "mu_coefficients",
    "ionosphere_free",
    "geometry_free",
    "codebias_coefficients",
    "codebias_observable",
    "combination_matrix",
    "combination_covariance",
    "between_satellite_operator",
    "sbasis_design",
    "euler_goad_sigma",
    "sine_sigma",
    "elevation_sigma",
]


def mu_coefficients(bands: Sequence[int] = (1, 2, 5)) -> np.ndarray:
    """``μ_j = (f₁/f_j)²`` for the given RINEX bands (first band is f₁)."""
    return np.array([mu(b, bands[0]) for b in bands])


def ionosphere_free(y1: np.ndarray, y2: np.ndarray, mu1: float = 1.0, mu2: float | None = None) -> np.ndarray:
    """Ionosphere-free combination, paper 000 eq. (25) (typo fixed): ``(μ₂ ȳ₁ − μ₁ ȳ₂)/(μ₂ − μ₁)``."""
    m2 = mu(2) if mu2 is None else mu2
    return (m2 * np.asarray(y1) - mu1 * np.asarray(y2)) / (m2 - mu1)


def geometry_free(y1: np.ndarray, y2: np.ndarray, mu1: float = 1.0, mu2: float | None = None) -> np.ndarray:
    """Geometry-free combination, paper 000 eq. (25): ``(ȳ₂ − ȳ₁)/(μ₂ − μ₁)`` (the f₁ slant ionosphere)."""
    m2 = mu(2) if mu2 is None else mu2
    return np.asarray((np.asarray(y2) - np.asarray(y1)) / (m2 - mu1))


def codebias_coefficients(mus: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """Coefficients ``(c₁, c₂, c₃)`` of ``y = ȳ₃ − ȳ_IF − μ₃ ȳ_GF`` (paper 000 eq. (24)) for ``(μ₁, μ₂, μ₃)``."""
    m1, m2, m3 = mu_coefficients((1, 2, 5)) if mus is None else np.asarray(mus, dtype=float)
    d = m2 - m1
    return np.array([(m3 - m2) / d, (m1 - m3) / d, 1.0])


def codebias_observable(
    y1: np.ndarray, y2: np.ndarray, y3: np.ndarray, mus: Sequence[float] | np.ndarray | None = None
) -> np.ndarray:
    """The triple-frequency code-bias observable of paper 000 eq. (24): ``ȳ₃ − ȳ_IF − μ₃ ȳ_GF``.

    ``y1, y2, y3`` are code observations on f₁, f₂, f₃ (GPS L1, L2, L5) in metres; NaN propagates.
    """
    m1, m2, m3 = mu_coefficients((1, 2, 5)) if mus is None else np.asarray(mus, dtype=float)
    y_if = ionosphere_free(y1, y2, m1, m2)
    y_gf = geometry_free(y1, y2, m1, m2)
    return np.asarray(np.asarray(y3) - y_if - m3 * y_gf)


def combination_matrix(mus: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """Rows mapping ``[ȳ₁, ȳ₂, ȳ₃]`` to ``[ȳ_IF, ȳ_GF, y]`` (IF, GF of eq. (25), code-bias observable of (24))."""
    m1, m2, m3 = mu_coefficients((1, 2, 5)) if mus is None else np.asarray(mus, dtype=float)
    d = m2 - m1
    return np.array(
        [
            [m2 / d, -m1 / d, 0.0],
            [-1.0 / d, 1.0 / d, 0.0],
            codebias_coefficients((m1, m2, m3)),
        ]
    )


def combination_covariance(coefficients: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Full covariance ``C Q Cᵀ`` of linear combinations ``C`` (k, m) of observations with covariance ``Q``.

    ``q`` may be ``(m, m)``, a vector of variances ``(m,)``, or a stack ``(..., m, m)`` / ``(..., m)``.
    The combinations of the same measurements are correlated (e.g. IF and GF): keep the off-diagonals.
    """
    c = np.asarray(coefficients, dtype=float)
    qq = np.asarray(q, dtype=float)
    m = c.shape[-1]
    if qq.ndim >= 2 and qq.shape[-2:] == (m, m):
        pass  # full covariance (or a stack of them)
    elif qq.ndim >= 1 and qq.shape[-1] == m:
        qq = qq[..., :, None] * np.eye(m)
    else:
        raise ModelError(f"covariance of shape {qq.shape} does not match {m} combination coefficients")
    return np.asarray(np.einsum("ij,...jk,lk->...il", c, qq, c))


def between_satellite_operator(m: int) -> np.ndarray:
    """The ``m × (m−1)`` between-satellite differencing operator ``D_m`` of paper 000 eq. (26).

    ``D_mᵀ = [−e, I_{m−1}]``: row k of ``D_mᵀ y`` is ``y_{k+1} − y_1`` (first satellite as pivot).
    """
    if m < 1:
        raise ModelError(f"between-satellite differencing needs at least one satellite, got m={m}")
    return np.vstack([-np.ones((1, m - 1)), np.eye(m - 1)])


def sbasis_design(visible: np.ndarray, n_satellites: int, *, reference_receiver: bool) -> np.ndarray:
    """Design matrix ``A_i`` of paper 000 §5.1 in the S-basis with receiver 1's bias lumped into the satellites.

    ``Ā_i`` holds the rows of ``I_p`` of the ``m_i`` visible satellites (indices ``visible``, in order);
    ``A_1 = Ā_1`` for the reference receiver and ``A_i = D_{m_i}ᵀ Ā_i`` otherwise.
    """
    vis = np.asarray(visible, dtype=int)
    if vis.size and (vis.min() < 0 or vis.max() >= n_satellites):
        raise ModelError(f"visible satellite index out of range 0..{n_satellites - 1}: {vis.tolist()}")
    a_bar = np.eye(n_satellites)[vis]
    if reference_receiver:
        return np.asarray(a_bar)
    return np.asarray(between_satellite_operator(vis.size).T @ a_bar)


def euler_goad_sigma(
    el_rad: np.ndarray, sigma0_m: float, *, a: float = 10.0, el0_rad: float = np.deg2rad(10.0)
) -> np.ndarray:
    """Elevation-dependent standard deviation of Euler & Goad (1991): ``σ(θ) = σ₀ (1 + a·exp(−θ/θ₀))``.

    With a = 10 and θ₀ = 10° (paper 000 §5.1 via the papers README), σ(90°) ≈ σ₀ (zenith-referenced).
    """
    return sigma0_m * (1.0 + a * np.exp(-np.asarray(el_rad, dtype=float) / el0_rad))


def sine_sigma(el_rad: np.ndarray, sigma0_m: float) -> np.ndarray:
    """``σ(θ) = σ₀ / sin θ`` (variance σ₀²/sin²θ)."""
    return np.asarray(sigma0_m / np.sin(np.asarray(el_rad, dtype=float)))


def elevation_sigma(el_rad: np.ndarray, sigma0_m: float, model: str = "euler-goad") -> np.ndarray:
    """Dispatch: ``model`` is ``"euler-goad"``, ``"sin"`` (1/sin²θ variance) or ``"constant"``."""
    if model == "euler-goad":
        return euler_goad_sigma(el_rad, sigma0_m)
    if model == "sin":
        return sine_sigma(el_rad, sigma0_m)
    if model == "constant":
        return np.full(np.shape(el_rad), float(sigma0_m))
    raise ModelError(f"unknown elevation weighting {model!r}; use 'euler-goad', 'sin' or 'constant'")
