"""The information kernel shared by the information filter and the CKF — paper 003 Fig. 1, Fig. 7.

:class:`InformationKernel` is a bank of information filters (one row per node or one for the network) with the
singular-noise time update of eqs. (19)–(21), optionally propagating the information-error variance of the CKF's
Fig. 7 recursion; :func:`pseudo_inverse_psd` turns (possibly singular) information into estimates per estimable
entry.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from distnav._blas import single_threaded_blas
from distnav.algorithms.kalman.dynamics import DynamicModel
from distnav.typing import BoolArray, FloatArray, IntArray

__all__ = ["EST_TOL", "RANK_RTOL", "InformationKernel", "masked_std", "pseudo_inverse_psd"]

RANK_RTOL = 1e-10
"""Eigenvalues below ``RANK_RTOL · λ_max`` count as zero information."""
EST_TOL = 1e-8
"""Entry ``k`` is estimable when the squared projection of ``e_k`` on the null space is below this."""


def pseudo_inverse_psd(info: FloatArray, *, rtol: float = RANK_RTOL) -> tuple[FloatArray, BoolArray]:
    """Batched pseudo-inverse of PSD information matrices ``(k, p, p)`` and the estimable entries ``(k, p)``.

    Entries with zero diagonal (never observed) are dropped first; the rest is tried with a batched inverse
    (accepted when every variance-inflation factor ``(I⁻¹)_jj I_jj`` lies in [1, 1e7)) and otherwise falls back to
    an eigen-decomposition of the unit-diagonal scaled matrix (eigenvalues below ``rtol·λ_max`` are zero; on one
    BLAS thread), where entry ``j`` is estimable when its squared projection on the null space is below 1e-8.
    The fallback is taken only for singular or ill-conditioned information (BELE + DGAR from 06:00: 347 of 1,205
    calls in the first 2 h, each with one zero eigenvalue; 5 calls in the full day from 00:00); a Cholesky test
    would not spare it (it also succeeds on some of those singular matrices). The returned matrix is a
    generalized inverse (the pseudo-inverse when ``I`` is invertible or its singular part is unit-free); on the
    estimable entries every generalized inverse gives the same estimates and variances.
    """
    k, p, _ = info.shape
    if k == 0:
        return np.zeros_like(info), np.zeros((k, p), bool)
    d = info.diagonal(axis1=1, axis2=2)
    seen = d > 0  # exactly zero: no information ever (structural); the rest is decided scale-free below
    if seen.all():
        return _inv_or_pinv(info, rtol)
    inv = np.zeros_like(info)
    est = np.zeros((k, p), bool)
    if k == 1:  # one filter (central, single-receiver): the observed entries by one grid
        cols, flat = _grid(seen[0])
        if cols.size:
            sub_inv, sub_est = _inv_or_pinv(info.reshape(p * p)[flat].reshape(1, cols.size, cols.size), rtol)
            inv.reshape(p * p)[flat] = sub_inv.reshape(-1)
            est[0, cols] = sub_est[0]
        return inv, est
    if (seen == seen[0]).all():
        groups: list[tuple[np.ndarray, BoolArray]] = [(np.arange(k), seen[0])]
    else:
        keys, inverse = np.unique(seen, axis=0, return_inverse=True)
        inverse = np.asarray(inverse).reshape(-1)
        groups = [(np.flatnonzero(inverse == g), keys[g]) for g in range(keys.shape[0])]
    for rows, mask in groups:
        cols = np.flatnonzero(mask)
        if cols.size == 0:
            continue
        sub = info[rows].take(cols, axis=1).take(cols, axis=2)
        sub_inv, sub_est = _inv_or_pinv(sub, rtol)
        inv[np.ix_(rows, cols, cols)] = sub_inv
        est[np.ix_(rows, cols)] = sub_est
    return inv, est


_GRIDS: dict[bytes, tuple[IntArray, IntArray]] = {}


def _grid(seen: BoolArray) -> tuple[IntArray, IntArray]:
    """The observed entries ``cols`` of one filter and the flat indices of their ``cols × cols`` block in its
    ``p × p`` matrix (the pattern changes rarely: remembered for the last few hundred patterns)."""
    key = seen.tobytes()
    got = _GRIDS.get(key)
    if got is None:
        cols = np.flatnonzero(seen)
        got = (cols, (cols[:, None] * seen.size + cols[None, :]).reshape(-1))
        if len(_GRIDS) > 256:
            _GRIDS.clear()
        _GRIDS[key] = got
    return got


def _inv_or_pinv(sub: FloatArray, rtol: float) -> tuple[FloatArray, BoolArray]:
    k, m, _ = sub.shape
    try:
        inv = np.linalg.inv(sub)
        # well-conditioned PD check: 1 ≤ (I⁻¹)_jj I_jj (Cauchy–Schwarz), large values flag near-singularity
        vif = inv.diagonal(axis1=1, axis2=2) * sub.diagonal(axis1=1, axis2=2)
        if vif.min() >= 1.0 - 1e-6 and vif.max() < 1e-3 / rtol and np.isfinite(inv).all():  # NaN fails both
            sym: np.ndarray = inv + inv.swapaxes(1, 2)
            sym *= 0.5  # 0.5 (I⁻¹ + I⁻ᵀ) in place: the same products, one temporary less
            return sym, np.ones((k, m), bool)
    except np.linalg.LinAlgError:
        pass
    # eigen-decomposition of the scaled matrix C = D^-1/2 I D^-1/2 (unit diagonal): the rank decision does not
    # depend on the units of the state entries. G = D^-1/2 C⁺ D^-1/2 is a generalized inverse of I, and for
    # estimable entries e_kᵀ G i and e_kᵀ G Q G e_k do not depend on which generalized inverse is used.
    dsq = np.sqrt(sub.diagonal(axis1=1, axis2=2))
    scale = 1.0 / np.where(dsq > 0, dsq, 1.0)
    C = sub * scale[:, :, None] * scale[:, None, :]
    with single_threaded_blas():  # OpenBLAS's 2 threads make this p ≲ 50 eigh 15–60× dearer in CPU (measured)
        w, U = np.linalg.eigh(C)
    keep = w > rtol * np.maximum(w[:, -1:], 1e-300)
    winv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    inv = ((U * winv[:, None, :]) @ U.swapaxes(1, 2)) * scale[:, :, None] * scale[:, None, :]
    null_proj = np.einsum("kij,kj->ki", U**2, (~keep).astype(float))
    return inv, null_proj < EST_TOL


class InformationKernel:
    """A bank of ``k`` information filters: ``I (k,p,p)``, ``i (k,p)`` and optionally ``Q (k,p,p)``.

    The state is the information matrix ``I_t|t`` and vector ``i_t|t`` of every row (a node, or the network),
    starting from zero information (the BLUP start of paper 003 §2.3). With ``track_error`` the kernel also
    propagates the information-error variance ``Q = D(I x − i)`` of the CKF's Fig. 7 recursion (``Q = I P I`` when
    ``I`` is invertible), which stays finite while ``I`` is singular; ``P = I⁺ Q I⁺`` on the estimable entries.

    Time update (paper 003 Fig. 1 with eqs. (19)–(21)), ``M = Φ⁻ᵀ I Φ⁻¹``, ``K = Hᵀ M H + S̃⁻¹``:
    ``I⁻ = M − M H K⁻¹ Hᵀ M``, ``i⁻ = (I − M H K⁻¹ Hᵀ) Φ⁻ᵀ i``. With ``B = I − M H K⁻¹ Hᵀ`` the information
    error ``u = I x − i`` evolves as ``u⁻ = B Φ⁻ᵀ u + B M H e_t`` (``d_t = H e_t``), hence
    ``Q⁻ = B Φ⁻ᵀ Q Φ⁻¹ Bᵀ + (M H K⁻¹ S̃⁻¹) S̃ (M H K⁻¹ S̃⁻¹)ᵀ`` — the paper's ``P⁻ = Φ P Φᵀ + S`` pre- and
    post-multiplied by ``I⁻``, but valid for singular ``I`` as well. Only ``K`` (q×q, always positive definite)
    is inverted.

    Measurement update (Fig. 1 / Fig. 6): ``I += s N``, ``i += s r`` with ``s = 1`` for a filter fed its own
    normals and ``s = n`` for the CKF fed consensus averages; ``Q += extra_error`` adds the Fig. 7 term
    ``n² Σ_j l_ij² N_j``.

    Parameters
    ----------
    k : number of filters (rows). p : number of states. track_error : propagate ``Q`` as well.
    n_errors : how many information-error variances to propagate side by side with ``track_error`` (e.g. the
        exact Fig. 7 value and a node-local one); :attr:`Q` is the first, :attr:`Qs` all of them.

    Cost per epoch: O(k p² q) for the time update (q = rank of the system noise), O(k p²) for the measurement
    update, O(k p³) for :meth:`estimates`.
    """

    def __init__(self, k: int, p: int, track_error: bool, *, n_errors: int = 1) -> None:
        self.I: FloatArray = np.zeros((k, p, p))
        self.i: FloatArray = np.zeros((k, p))
        self.Qs: list[FloatArray] = [np.zeros((k, p, p)) for _ in range(n_errors)] if track_error else []
        self.p = p

    @property
    def Q(self) -> FloatArray | None:
        """The first information-error variance (``None`` without ``track_error``)."""
        return self.Qs[0] if self.Qs else None

    def time_update(self, dyn: DynamicModel, t: int) -> None:
        """Predict from epoch ``t − 1`` to ``t`` with the model of that step (eqs. (19)–(21)); ``Q`` alongside."""
        Finv, H, _St, St_inv, sel = dyn.update_at(t)
        M, v = self.I, self.i
        Qs = self.Qs
        if Finv is not None:
            M = Finv.T @ M @ Finv
            v = v @ Finv  # (Φ⁻ᵀ i) row-wise
            Qs = [Finv.T @ Q @ Finv for Q in Qs]
        q = H.shape[1]
        if q == 0:
            self.I, self.i, self.Qs = M, v, Qs
            return
        if sel is not None:  # H = columns `sel` of the identity (eq. (20)): slicing instead of products
            MH = M[:, :, sel]  # (k,p,q)
            K = MH[:, sel, :] + St_inv
        else:
            MH = M @ H
            K = MH.swapaxes(1, 2) @ H + St_inv  # Hᵀ M H + S̃⁻¹, (k,q,q)
        G = MH @ np.linalg.inv(K)  # M H K⁻¹, (k,p,q)
        I_new = G @ MH.swapaxes(1, 2)
        np.subtract(M, I_new, out=I_new)
        I_sym = I_new + I_new.swapaxes(1, 2)
        I_sym *= 0.5
        self.I = I_sym
        vH = v[:, sel] if sel is not None else v @ H
        self.i = v - (G @ vH[..., None])[..., 0]
        new: list[FloatArray] = []
        for Q in Qs:
            # B Q Bᵀ with B = I − G Hᵀ as rank-q corrections, plus F S̃ Fᵀ with F = B M H = G S̃⁻¹
            HtQ = Q[:, sel, :] if sel is not None else H.swapaxes(0, 1) @ Q  # (k,q,p)
            BQ = Q - G @ HtQ
            BQH = BQ[:, :, sel] if sel is not None else BQ @ H  # (k,p,q)
            F = G @ St_inv
            Q_new = BQ - BQH @ G.swapaxes(1, 2) + F @ (_St @ F.swapaxes(1, 2))
            Q_sym = Q_new + Q_new.swapaxes(1, 2)
            Q_sym *= 0.5
            new.append(Q_sym)
        self.Qs = new

    def measurement_update(
        self,
        N: FloatArray,
        r: FloatArray,
        scale: float = 1.0,
        extra_error: FloatArray | None = None,
        extra_errors: Sequence[FloatArray | None] = (),
    ) -> None:
        """``I += scale N``, ``i += scale r`` (Fig. 1 / Fig. 6); ``Q += extra_error`` (Fig. 7).

        ``extra_errors`` gives one term per propagated variance (:attr:`Qs`) instead (``None`` entries: nothing).
        """
        if scale == 1.0:  # 1·x is x: the same sums without the products
            self.I, self.i = self.I + N, self.i + r
        else:
            self.I, self.i = self.I + scale * N, self.i + scale * r
        terms: Sequence[FloatArray | None] = extra_errors if extra_errors else [extra_error]
        for j, term in enumerate(terms):
            if j < len(self.Qs) and term is not None:
                self.Qs[j] = self.Qs[j] + term

    def error_covariance(self, inverse: FloatArray, which: int = 0) -> FloatArray:
        """``P = I⁺ Q I⁺`` of variance ``which`` (symmetrized), given ``inverse`` = ``I⁺`` from :meth:`estimates`."""
        P = inverse @ self.Qs[which] @ inverse
        out: FloatArray = P + P.swapaxes(1, 2)
        out *= 0.5
        return out

    def estimates(self) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray | None]:
        """``(x̂ (NaN where not estimable), estimable, I⁺, P = I⁺ Q I⁺ or None)``."""
        inv, est = pseudo_inverse_psd(self.I)
        x = (inv @ self.i[..., None])[..., 0]
        if not est.all():
            x[~est] = np.nan
        P = self.error_covariance(inv) if self.Qs else None
        return x, est, inv, P


def masked_std(cov: FloatArray, estimable: BoolArray) -> FloatArray:
    """Standard deviations ``sqrt(diag cov)`` (negative round-off clipped to 0), NaN where not ``estimable``."""
    s = np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))
    out: FloatArray = np.where(estimable, s, np.nan)
    return out
