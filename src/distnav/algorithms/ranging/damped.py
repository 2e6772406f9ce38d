"""The damped normal-equation solves of global LM (:func:`~distnav.algorithms.ranging.lm.levenberg_marquardt`).

``(GᵀWG + λ diag(GᵀWG)) δ = −GᵀWg`` (paper 002 eq. (8), Fletcher's scaling) for one fixed sparsity pattern of ``G``:
banded Cholesky (reverse Cuthill–McKee order), bordered (a few dense columns by their Schur complement), dense
Cholesky or SuperLU. Split from :mod:`distnav.algorithms.ranging.lm` (which uses :class:`DampedSolver`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import reverse_cuthill_mckee

__all__ = ["DampedSolver"]


class DampedSolver:
    """Solves ``(A + λ diag(A)) δ = b`` for the normal matrix ``A = GᵀWG`` of one fixed sparsity pattern.

    Sparse Jacobians: the unknowns are reordered by reverse Cuthill–McKee (structural pattern of ``|G|ᵀ|G|``) and
    the damped matrix is factorised in LAPACK's banded Cholesky when the band is narrow (anchor networks are
    geometric graphs, so it is); otherwise a dense Cholesky (small problems) or SuperLU (large ones). A few
    *dense* unknowns (a common range offset touches every range: one full row and column of ``A``, which makes
    any band as wide as the matrix) are ordered last and eliminated by their Schur complement (``"bordered"``):
    the banded Cholesky of the rest solves for ``[b₁, C]``, then the small system
    ``(E − Cᵀ B⁻¹ C) δ₂ = b₂ − Cᵀ B⁻¹ b₁`` gives the dense unknowns (the same solution, to rounding).
    """

    MAX_DENSE_COLUMNS = 8

    def __init__(self, jac0: Any, dense_limit: int) -> None:
        n = jac0.shape[1]
        self.n = n
        self.mode = "dense"
        if sp.issparse(jac0) and n > 0:
            jac0 = sp.csr_matrix(jac0)
            pat = sp.csr_matrix((np.ones(jac0.nnz), jac0.indices, jac0.indptr), shape=jac0.shape)
            struct = (pat.T @ pat).tocsr()
            perm = np.asarray(reverse_cuthill_mckee(struct, symmetric_mode=True), np.int64)
            band = _band(struct, perm)
            self.dense_cols = np.zeros(0, np.int64)
            degree = np.diff(struct.indptr)
            wide = np.flatnonzero(degree > max(8, n // 4))
            if band > max(8, n // 4) and 0 < wide.size <= self.MAX_DENSE_COLUMNS and wide.size < n:
                rest = np.setdiff1d(np.arange(n), wide)
                sub = struct[rest][:, rest]
                perm_r = rest[np.asarray(reverse_cuthill_mckee(sp.csr_matrix(sub), symmetric_mode=True), np.int64)]
                band_r = _band(struct[perm_r][:, perm_r], np.arange(rest.size))
                if band_r <= max(8, rest.size // 4):
                    perm, band, self.dense_cols = perm_r, band_r, wide
            inv = np.full(n, -1, np.int64)
            inv[perm] = np.arange(perm.size)
            self.perm, self.inv, self.band = perm, inv, band
            if self.dense_cols.size:
                self.mode = "bordered"
                self.dense_pos = np.full(n, -1, np.int64)
                self.dense_pos[self.dense_cols] = np.arange(self.dense_cols.size)
            elif band <= max(8, n // 4):
                self.mode = "banded"
            elif n > dense_limit:
                self.mode = "sparse"

    def _pairs(self, jac: sp.csr_matrix) -> None:
        """Precompute, for a fixed CSR pattern of ``G``, where every product ``G_lp G_lq`` lands in ``GᵀWG``."""
        m = jac.shape[0]
        counts = np.diff(jac.indptr)
        rows = np.repeat(np.arange(m), counts)
        # all ordered pairs (p, q) of stored entries within each row
        ps, qs = [], []
        for c in np.unique(counts):
            rsel = np.flatnonzero(counts == c)
            if c == 0 or rsel.size == 0:
                continue
            base = jac.indptr[rsel][:, None]
            a_idx, b_idx = np.meshgrid(np.arange(c), np.arange(c), indexing="ij")
            ps.append((base + a_idx.ravel()[None, :]).ravel())
            qs.append((base + b_idx.ravel()[None, :]).ravel())
        p = np.concatenate(ps) if ps else np.zeros(0, np.int64)
        q = np.concatenate(qs) if qs else np.zeros(0, np.int64)
        if self.mode == "sparse":
            self._sparse_pattern(jac)
            order = np.argsort(rows[p], kind="stable")  # every sum in row order, as scipy's GᵀG product adds
            p, q = p[order], q[order]
            keep = np.ones(p.size, bool)
            self._target = np.searchsorted(self._sp_keys, jac.indices[q] * self.n + jac.indices[p])
            self._size = self._sp_keys.size
        elif self.mode == "banded":
            r, c = self.inv[jac.indices[p]], self.inv[jac.indices[q]]
            keep = r <= c
            self._target = (self.band + r[keep] - c[keep]) * self.n + c[keep]
            self._size = (self.band + 1) * self.n
        elif self.mode == "bordered":  # [upper band of B | C (nb × k) | E (k × k)]
            nb, k = self.perm.size, self.dense_cols.size
            r, c = self.inv[jac.indices[p]], self.inv[jac.indices[q]]
            dr, dc = self.dense_pos[jac.indices[p]], self.dense_pos[jac.indices[q]]
            in_b = (r >= 0) & (c >= 0) & (r <= c)
            in_c = (r >= 0) & (dc >= 0)
            in_e = (dr >= 0) & (dc >= 0)
            keep = in_b | in_c | in_e
            off_c, off_e = (self.band + 1) * nb, (self.band + 1) * nb + nb * k
            target = np.where(
                in_b, (self.band + r - c) * nb + c, np.where(in_c, off_c + r * k + dc, off_e + dr * k + dc)
            )
            self._target = target[keep]
            self._size = off_e + k * k
        else:
            keep = np.ones(p.size, bool)
            self._target = jac.indices[p] * self.n + jac.indices[q]
            self._size = self.n * self.n
        self._p, self._q, self._prow = p[keep], q[keep], rows[p[keep]]
        self._rows = rows
        self._pattern = (jac.indptr.copy(), jac.indices.copy())

    def _sparse_pattern(self, jac: sp.csr_matrix) -> None:
        """The CSC pattern of ``GᵀG`` (canonical: rows ascending in every column), its entry keys
        ``column·n + row`` and the positions of the diagonal (``_sp_fast`` False if a diagonal entry is missing:
        then the damping adds entries and the generic path runs)."""
        n = self.n
        pat = sp.csr_matrix((np.ones(jac.nnz), jac.indices, jac.indptr), shape=jac.shape)
        struct = sp.csc_matrix(pat.T @ pat)
        struct.sort_indices()
        self._sp_indptr, self._sp_indices = struct.indptr, struct.indices
        self._sp_col = np.repeat(np.arange(n), np.diff(struct.indptr))
        self._sp_keys = self._sp_col * n + struct.indices
        diag_keys = np.arange(n) * (n + 1)
        self._sp_diag = np.minimum(np.searchsorted(self._sp_keys, diag_keys), max(self._sp_keys.size - 1, 0))
        self._sp_fast = bool(self._sp_keys.size) and bool(np.array_equal(self._sp_keys[self._sp_diag], diag_keys))

    def normal(self, jac: Any, w: np.ndarray | None, g: np.ndarray) -> tuple[Any, np.ndarray]:
        """``(GᵀWG, GᵀWg)``, the matrix in the form :meth:`solve` needs (banded storage, dense or sparse)."""
        if sp.issparse(jac) and (self.mode in ("banded", "bordered", "dense") or (self.mode == "sparse" and w is None)):
            jac = jac.tocsr()
            pat = getattr(self, "_pattern", None)
            if (
                pat is None
                or pat[0].size != jac.indptr.size
                or pat[1].size != jac.indices.size
                or not (np.array_equal(pat[0], jac.indptr) and np.array_equal(pat[1], jac.indices))
            ):
                self._pairs(jac)
            if self.mode == "sparse" and not self._sp_fast:
                return self._normal_generic(jac, w, g)
            d = jac.data
            prod = d[self._p] * d[self._q]
            wd = d if w is None else d * w[self._rows]
            if w is not None:
                prod = prod * w[self._prow]
            a = np.bincount(self._target, prod, minlength=self._size)
            grad = np.bincount(jac.indices, wd * g[self._rows], minlength=self.n)
            if self.mode == "sparse":  # the values of GᵀG on its CSC pattern: what scipy's product gives, bit for bit
                return a, grad
            if self.mode == "banded":
                return a.reshape(self.band + 1, self.n), grad
            if self.mode == "bordered":
                nb, k = self.perm.size, self.dense_cols.size
                off_c = (self.band + 1) * nb
                return (
                    a[:off_c].reshape(self.band + 1, nb),
                    a[off_c : off_c + nb * k].reshape(nb, k),
                    a[off_c + nb * k :].reshape(k, k),
                ), grad
            return a.reshape(self.n, self.n), grad
        return self._normal_generic(jac, w, g)

    def _normal_generic(self, jac: Any, w: np.ndarray | None, g: np.ndarray) -> tuple[Any, np.ndarray]:
        jw = jac if w is None else (jac.multiply(w[:, None]).tocsr() if sp.issparse(jac) else jac * w[:, None])
        a = jw.T @ jac
        if self.mode == "dense":
            a = a.toarray() if sp.issparse(a) else np.asarray(a)
        else:
            a = sp.csr_matrix(a)
        return a, np.asarray(jw.T @ g).ravel()

    def _solve_bordered(
        self, a: tuple[np.ndarray, np.ndarray, np.ndarray], b: np.ndarray, lam: float
    ) -> np.ndarray | None:
        ab, cm, em = a
        d, de = ab[self.band], np.diag(em)
        floor = 1e-12 * max(float(d.max(initial=0.0)), float(de.max(initial=0.0)), 1e-300)
        ab = ab.copy()
        ab[self.band] = d + lam * np.maximum(d, floor)
        e = em + np.diag(lam * np.maximum(de, floor))
        try:
            cb = sla.cholesky_banded(ab, lower=False, check_finite=False)
            y = sla.cho_solve_banded((cb, False), np.column_stack([b[self.perm], cm]), check_finite=False)
            schur = e - cm.T @ y[:, 1:]
            x2 = sla.solve(schur, b[self.dense_cols] - cm.T @ y[:, 0], assume_a="pos", check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None
        res = np.empty(self.n)
        res[self.perm] = y[:, 0] - y[:, 1:] @ x2
        res[self.dense_cols] = x2
        return res if np.all(np.isfinite(res)) else None

    def solve(self, a: Any, b: np.ndarray, lam: float) -> np.ndarray | None:
        if self.mode == "bordered":
            return self._solve_bordered(a, b, lam)
        if self.mode == "banded":
            d = a[self.band]
            floor = 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
            ab = a.copy()
            ab[self.band] = d + lam * np.maximum(d, floor)
            try:
                out = sla.solveh_banded(ab, b[self.perm], lower=False, check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                return None
            res = np.empty(self.n)
            res[self.perm] = out
            return res if np.all(np.isfinite(res)) else None
        if self.mode == "dense":
            d = np.diag(a).copy()
            floor = 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
            m = a + np.diag(lam * np.maximum(d, floor))
            try:
                return np.asarray(sla.cho_solve(sla.cho_factor(m, check_finite=False), b, check_finite=False))
            except (np.linalg.LinAlgError, ValueError):
                return None
        if isinstance(a, np.ndarray):  # GᵀG's values on its CSC pattern (see normal)
            m = self._damped_csc(a, lam)
        else:
            d = a.diagonal()
            floor = 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
            m = (a + sp.diags(lam * np.maximum(d, floor))).tocsc()
        try:
            out = spla.spsolve(m, b)
        except RuntimeError:
            return None
        return None if not np.all(np.isfinite(out)) else np.asarray(out)

    def _damped_csc(self, a: np.ndarray, lam: float) -> sp.csc_matrix:
        """``(A + diags(λ max(d, floor))).tocsc()`` built from A's values on its CSC pattern: the same entries, values
        and order (an entry that is exactly 0 is left out, as scipy's sums leave it out), without the sparse
        additions and conversions."""
        d = a[self._sp_diag]
        floor = 1e-12 * max(float(d.max(initial=0.0)), 1e-300)
        data = a.copy()
        data[self._sp_diag] = d + lam * np.maximum(d, floor)
        nz = data != 0
        if nz.all():
            return sp.csc_matrix((data, self._sp_indices, self._sp_indptr), shape=(self.n, self.n))
        counts = np.bincount(self._sp_col[nz], minlength=self.n)
        indptr = np.concatenate([[0], np.cumsum(counts)]).astype(self._sp_indptr.dtype)
        return sp.csc_matrix((data[nz], self._sp_indices[nz], indptr), shape=(self.n, self.n))


def _band(struct: sp.csr_matrix, perm: np.ndarray) -> int:
    """Half-bandwidth of the symmetric pattern ``struct`` with its unknowns in the order ``perm``."""
    inv = np.empty(perm.size, np.int64)
    inv[perm] = np.arange(perm.size)
    coo = struct.tocoo()
    return int(np.max(np.abs(inv[coo.row] - inv[coo.col]), initial=0))
