"""A Chebyshev semi-iteration for the LM phase's inner solve (issue 27, message economy): no dot product per
iteration, only bounds of the preconditioned matrix's spectrum (an option beside CG: :data:`INNER_SOLVER`).

Why: per CG iteration of :func:`~distnav.algorithms.ranging.refine.pcg` on the plant-like 28-anchor hall the two
dot products (spanning-tree all-reductions, ``2(n − 1)`` messages each) cost more bytes than the neighbours'
products. The Chebyshev semi-iteration (Saad 2003, Alg. 12.1 with a preconditioner; Gutknecht & Röllin 2002)
needs instead an interval ``[λ_lo, λ_hi]`` holding the spectrum of ``M⁻¹A`` — ``A = N + μD`` the damped normal
matrix (Marquardt's ``D = diag N``), ``M`` its block-Jacobi part (every anchor's own damped block) — and stops
after a fixed number of iterations set from the bounds and the forcing term (Saad 2003, eq. 12.9: the A-norm
error falls by at least ``2qᵐ``, ``q = (√κ − 1)/(√κ + 1)``, ``κ = λ_hi/λ_lo``), or, with :data:`CHECK_EVERY`,
on ``rᵀz`` every few iterations.

The bounds (:func:`spectrum_bounds`, one reduction of three floats per inner solve):

* **upper**: ``λ_max(M⁻¹A) ≤ ‖M⁻¹A‖_∞``, the largest absolute row sum, which every anchor takes over its own
  rows (its own block, its links' couplings to the neighbours and to the common offset) — Gershgorin; the common
  offset's row needs a sum over the anchors (the same reduction);
* **lower**: ``xᵀAx ≥ μ xᵀDx`` (N is positive semidefinite) and ``xᵀMx ≤ (β + μ) xᵀDx`` with ``β`` the largest
  eigenvalue over the anchors of ``D_i^{-1/2} N_ii D_i^{-1/2}`` (a block with unit diagonal: ``β ≤ P``), so
  ``λ_min(M⁻¹A) ≥ μ/(β + μ)``. **Departure from the brief's μ/(1 + μ)**: that bound holds for point Jacobi
  (``β = 1``); with a block preconditioner the block's own coupling enters, ``β`` between 1 and the block size.

The common offset's row of ``A v`` is a network total (each anchor's share, :meth:`NormalSystem.matvec
<distnav.algorithms.ranging.refine.NormalSystem.matvec>`): with a common offset every iteration still reduces one
float per right-hand side (CG reduces it together with its two dot products).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

__all__ = ["INNER_SOLVER", "CHECK_EVERY", "Operator", "spectrum_bounds", "iterations_for", "chebyshev"]

#: the LM phase's inner solver: ``"cg"`` (:func:`~distnav.algorithms.ranging.refine.pcg`) or ``"chebyshev"``
#: (:func:`chebyshev`); measured in docs/economy_uwb.md ("tried")
INNER_SOLVER = "cg"
#: 0: a fixed number of iterations from the bounds (:func:`iterations_for`); k > 0: also stop on ``rᵀz`` checked
#: every k iterations (one reduction each)
CHECK_EVERY = 0
BOUND_MARGIN = 1e-3  # relative widening of the interval (the bounds travel as float32)

Gathered = Callable[[np.ndarray, type[np.floating]], np.ndarray]


class Operator(Protocol):
    """What :func:`chebyshev` needs of :class:`~distnav.algorithms.ranging.refine.NormalSystem`."""

    @property
    def damp_c(self) -> float: ...

    @property
    def common(self) -> bool: ...

    def matvec(self, v: np.ndarray, vc: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def spectrum_bounds(
    lin: object,
    owner: np.ndarray,
    free: np.ndarray,
    damp: np.ndarray,
    damp_c: float,
    pre_inv: np.ndarray,
    pre_c: float,
    mu: float,
    gathered: Gathered,
) -> tuple[float, float]:
    """``(λ_lo, λ_hi)`` holding the spectrum of ``M⁻¹A`` (module docstring) from the linearization ``lin``
    (:class:`~distnav.algorithms.ranging.refine._Linearization`: rows ``a``, ``cn``, ``e``, weights ``w``, own
    blocks, the common offset's curvature ``dc``) and the damping ``damp = μ·diag N``; one reduction
    (``gathered``) of each anchor's largest row sum, its ``β`` and its share of the common offset's row sum."""
    a, cn, e, w = lin.a, lin.cn, lin.e, lin.w  # type: ignore[attr-defined]
    own_block, dc = lin.own_block, lin.dc  # type: ignore[attr-defined]
    nl, P = free.shape
    mask = free[:, :, None] & free[:, None, :]
    a_own = (own_block + damp[:, :, None] * np.eye(P)) * mask
    rows = np.sum(np.abs(np.einsum("nab,nbc->nac", pre_inv, a_own)), axis=2)  # (n_local, P)
    u = np.abs(np.einsum("hab,hb->ha", pre_inv[owner], w[:, None] * a))  # |M_i⁻¹ w a_l|
    coupling = np.sum(np.abs(cn), axis=1) + np.abs(e)
    np.add.at(rows, owner, u * coupling[:, None])
    upper = np.max(np.where(free, rows, 0.0), axis=1, initial=0.0)
    d_over_mu = np.where(free, damp, 1.0) / mu  # D_i (damp = μ·max(diag N, 1e-12))
    s = 1.0 / np.sqrt(d_over_mu)
    beta = np.max(np.linalg.eigvalsh(own_block * mask * s[:, :, None] * s[:, None, :]), axis=1, initial=0.0)
    share = np.bincount(owner, np.abs(w * e) * np.sum(np.abs(a), axis=1), minlength=nl)
    got = gathered(np.c_[upper, beta, share], np.float32)
    hi = float(np.max(got[:, 0], initial=0.0))
    if pre_c > 0 and np.any(e):
        hi = max(hi, (float(np.sum(got[:, 2])) + dc + damp_c) / pre_c)
    beta_max = max(float(np.max(got[:, 1], initial=0.0)), 1.0)
    lo = mu / (beta_max + mu)
    return lo * (1.0 - BOUND_MARGIN), hi * (1.0 + BOUND_MARGIN)


def iterations_for(lo: float, hi: float, rtol: float) -> int:
    """Iterations after which the A-norm error has fallen by ``rtol``: the least ``m`` with ``2qᵐ ≤ rtol``
    (Saad 2003, eq. 12.9), ``q = (√κ − 1)/(√κ + 1)``, ``κ = hi/lo``."""
    root = math.sqrt(max(hi / lo, 1.0))
    q = (root - 1.0) / (root + 1.0)
    if q <= 0.0:
        return 1
    return max(1, math.ceil(math.log(rtol / 2.0) / math.log(q)))


def chebyshev(
    system: Operator,
    b: np.ndarray,
    bc: np.ndarray,
    pre_inv: np.ndarray,
    pre_c: float,
    total: Gathered,
    bounds: tuple[float, float],
    max_its: int,
    rtol: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The preconditioned Chebyshev semi-iteration (Saad 2003, Alg. 12.1) for ``A x = b`` on the block's rows
    ``(n_local, P, k)`` and the common offset's row ``bc`` ``(k,)``, from ``x = 0``, over the interval ``bounds``:
    :func:`iterations_for` iterations (at most ``max_its``), or fewer with :data:`CHECK_EVERY`. Per iteration one
    broadcast (the product) and, with a common offset, one reduction of its row (``total``: each anchor's
    shares summed over the network)."""
    lo, hi = bounds
    theta, delta = 0.5 * (hi + lo), 0.5 * (hi - lo)
    sigma1 = theta / delta
    k = b.shape[2]
    x, xc = np.zeros_like(b), np.zeros(k)
    res, rc = b.copy(), np.asarray(bc, float).copy()
    z, zc = np.einsum("nab,nbk->nak", pre_inv, res), rc / pre_c
    rr0 = _rz(total, res, z, rc, zc) if CHECK_EVERY else None
    if rr0 is not None and not np.any(rr0 > 0.0):
        return x, xc, 0
    d, dcv = z / theta, zc / theta
    rho = 1.0 / sigma1
    m = min(iterations_for(lo, hi, rtol), max_its)
    its = 0
    while its < m:
        its += 1
        x += d
        xc += dcv
        q, q_share = system.matvec(d, dcv)
        qc = np.sum(total(q_share, np.float32), axis=0) + system.damp_c * dcv if system.common else np.zeros(k)
        res -= q
        rc -= qc
        z, zc = np.einsum("nab,nbk->nak", pre_inv, res), rc / pre_c
        if rr0 is not None and its % CHECK_EVERY == 0 and np.all(_rz(total, res, z, rc, zc) <= rtol**2 * rr0):
            break
        rho_new = 1.0 / (2.0 * sigma1 - rho)
        d = rho_new * rho * d + (2.0 * rho_new / delta) * z
        dcv = rho_new * rho * dcv + (2.0 * rho_new / delta) * zc
        rho = rho_new
    return x, xc, its


def _rz(total: Gathered, r: np.ndarray, z: np.ndarray, rc: np.ndarray, zc: np.ndarray) -> np.ndarray:
    """The network's ``rᵀz`` per column (one reduction)."""
    return np.asarray(np.sum(total(np.einsum("nak,nak->nk", r, z), np.float32), axis=0) + rc * zc)
