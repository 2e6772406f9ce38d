"""The two conditions a least-squares run checks before it starts (paper 000): an ADMM weight ``W`` that is
symmetric positive definite and stays finite in float64 (eq. (8)), and a normal matrix ``N = Σ N_i`` of full rank
(eq. (2)), whose failure is stated by naming the inestimable directions of ``x``.

Used by :func:`~distnav.algorithms.lsq.blue.blue` (which re-exports these names) and the ADMM front doors.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from distnav._checks import real_array
from distnav.errors import ModelError
from distnav.typing import ArrayLike

__all__ = ["MAX_WEIGHT", "MIN_WEIGHT", "inestimable_directions", "null_space_directions", "weight_matrix"]

#: The range of an ADMM weight ρ (and of W's entries) whose products and squares stay finite and nonzero in float64.
MIN_WEIGHT, MAX_WEIGHT = 1e-100, 1e100


def weight_matrix(W: ArrayLike, p: int) -> np.ndarray:
    """The ADMM weight matrix: a scalar ``ρ > 0`` gives ``ρ I_p``; a ``(p, p)`` matrix must be symmetric
    positive definite (paper 000, eq. (8))."""
    arr = real_array(W, "the weight W", error=ModelError)
    if arr.ndim == 0:
        rho = float(arr)
        if not np.isfinite(rho) or rho <= 0:
            raise ModelError(f"the weight W = ρ must be finite and > 0, got {rho}")
        if not MIN_WEIGHT <= rho <= MAX_WEIGHT:
            raise ModelError(
                f"the weight W = ρ = {rho:g} is outside {MIN_WEIGHT:g}..{MAX_WEIGHT:g}: ADMM's updates multiply by it "
                "and its square, which overflow or vanish in float64; scale the observations instead"
            )
        return rho * np.eye(p)
    if arr.shape != (p, p):
        raise ModelError(f"the weight matrix W must be a scalar ρ or ({p}, {p}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError("the weight matrix W has non-finite entries")
    if np.abs(arr).max() > MAX_WEIGHT:
        raise ModelError(f"the weight matrix W has entries above {MAX_WEIGHT:g}: its products overflow in float64")
    if np.abs(arr - arr.T).max() > 1e-10 * max(np.abs(arr).max(), 1e-300):
        raise ModelError("the weight matrix W is not symmetric")
    lam = np.linalg.eigvalsh(arr)
    if lam.min() <= 0:
        raise ModelError(f"the weight matrix W is not positive definite (smallest eigenvalue {lam.min():.3g})")
    return arr


def null_space_directions(N: np.ndarray, *, rcond: float = 1e-10) -> np.ndarray:
    """Orthonormal basis ``(p, d)`` of the directions of ``x`` that ``N`` does not determine.

    ``N`` is Jacobi-scaled first (``D N D`` with ``D = diag(N)^{-1/2}``; a parameter with zero diagonal is a null
    direction by itself), so the test ``λ ≤ rcond · λ_max`` does not depend on the parameters' units. The basis
    is returned in the original coordinates and orthonormalized.
    """
    N = np.asarray(N, float)
    d = np.diag(N)
    # A diagonal at rounding level of the largest one (e.g. 1e-30 beside 20: a column of A_i whose entries are the
    # rounding of a reparametrization) is no information: Jacobi-scaling by it would blow the rounding up to order
    # one and call the parameter estimable. The floor keeps such a row (and an unseen one, d = 0) tiny after scaling.
    floor = max(float(d.max(initial=0.0)), 1e-300) * N.shape[0] * np.finfo(float).eps
    scale = 1.0 / np.sqrt(np.maximum(d, floor))
    Ns = scale[:, None] * N * scale[None, :]
    lam, V = np.linalg.eigh(Ns)
    small = lam <= rcond * max(float(lam.max()), 1e-300)
    if not small.any():
        return np.zeros((N.shape[0], 0))
    Q, _ = np.linalg.qr(scale[:, None] * V[:, small])  # N (D v) = 0 ⇔ (D N D) v = 0
    return Q


def _describe_direction(v: np.ndarray, label: Callable[[int], str]) -> str:
    v = v / np.abs(v).max()
    if v[np.flatnonzero(np.abs(v) > 1e-8)[0]] < 0:
        v = -v
    terms = []
    for k in np.flatnonzero(np.abs(v) > 1e-8):
        c = v[k]
        sign = "−" if c < 0 else "+"
        mag = abs(c)
        coef = "" if abs(mag - 1) < 1e-8 else f"{mag:.3g}·"
        terms.append(f"{sign} {coef}{label(int(k))}")
    text = " ".join(terms)
    return text[2:] if text.startswith("+ ") else text


def inestimable_directions(N: np.ndarray, label: Callable[[int], str], *, rcond: float = 1e-10) -> str | None:
    """``None`` when ``N = Σ N_i`` is regular, else the rank statement naming a basis of the directions of ``x``
    that the data do not determine (e.g. ``x[0] − x[1]``; paper 000, eq. (2)). ``label(k)`` names parameter ``k``."""
    null = null_space_directions(N, rcond=rcond)
    if null.shape[1] == 0:
        return None
    p = N.shape[0]
    dirs = "; ".join(_describe_direction(null[:, k], label) for k in range(min(null.shape[1], 8)))
    more = f" (and {null.shape[1] - 8} more)" if null.shape[1] > 8 else ""
    return (
        f"rank(A) = {p - null.shape[1]} < p = {p} (paper 000, eq. (2)): x is not estimable from all nodes' "
        f"data; inestimable directions: {dirs}{more}"
    )
