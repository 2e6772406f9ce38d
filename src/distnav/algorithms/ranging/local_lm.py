"""The local Levenberg–Marquardt step of N-CLM (paper 002 eq. (22)), batched over a block's anchors.

Split from :mod:`distnav.algorithms.ranging.neighbourhood` (which re-exports :class:`LocalLM`); see its docstring for
N-CLM as a whole.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from distnav._blas import single_threaded_blas
from distnav._sparse import csr_times

if TYPE_CHECKING:
    from distnav.algorithms.ranging.neighbourhoods import Neighbourhoods

__all__ = ["LocalLM"]


def _elements(rows: np.ndarray, d: int) -> np.ndarray:
    """The flat element indices of ``rows`` of a C-contiguous ``(·, d)`` array: gathering them from the flat array
    copies the same values as ``a[rows]``, several times faster on these short rows."""
    return (rows[:, None] * d + np.arange(d)).ravel()


class LocalLM:
    """Batched per-anchor LM steps on the partial costs (paper 002 eq. (22)).

    ``G⁽ⁱ⁾ᵀG⁽ⁱ⁾`` is an arrowhead matrix: the own block couples with every neighbour block, neighbour blocks do
    not couple with each other (a range involves anchor ``i`` and one neighbour), and a neighbour block is
    rank one, ``c_s v_s v_sᵀ`` (``c_s`` samples of the link, ``v_s = 2(r_i − r_s)``). The damped system is solved
    by Sherman–Morrison on the neighbour blocks and the Schur complement on the own ``dim × dim`` block,
    vectorized over all anchors and links: no ``(K·dim)²`` matrix is formed or factorised.
    """

    def __init__(self, nb: Neighbourhoods, damping: str, lambda_min: float = 0.1) -> None:
        self.nb = nb
        self.damping = damping
        self.lambda_min = lambda_min
        key = nb.h_own * nb.K + nb.h_slot
        uniq, first, inv, count = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        self.ls_own, self.ls_slot = uniq // nb.K, uniq % nb.K
        self.first, self.count, self.inv = first, count.astype(float), inv
        nls = uniq.size
        self.O = sp.csr_matrix((np.ones(nls), (self.ls_own, np.arange(nls))), shape=(nb.nl, nls))  # → anchors
        self.fo = nb.free_slot[:, 0, :]
        self.fs = nb.free_slot[self.ls_own, self.ls_slot, :]
        self.mo = self.fo[:, :, None] & self.fo[:, None, :]
        self.n_free = self.fo.sum(axis=1) + np.asarray(self.O @ self.fs.sum(axis=1).astype(float))
        self.n_free_1 = np.maximum(self.n_free, 1)
        self.fo_ls = self.fo[self.ls_own]  # the own anchor's free columns, per link
        d = nb.dim
        self.e_first = _elements(first, d)  # diff[first]
        self.e_ls = _elements(self.ls_own * nb.K + self.ls_slot, d)  # [ls_own, ls_slot, :] of a (nl, K, d) array
        self.e_own = _elements(self.ls_own, d)  # d0[ls_own]
        self.eye = np.eye(nb.dim)

    def gain_update(
        self, f0: np.ndarray, f_new: np.ndarray, pred: np.ndarray, lam: np.ndarray, nu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each anchor's step accepted where its partial cost fell (gain ratio ``ρ > 0``), and its new ``(λ, ν)``
        (Nielsen's update, floored at ``lambda_min``)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(pred > 0, (f0 - f_new) / pred, -1.0)
        acc = (rho > 0) & np.isfinite(f_new)
        new_lam = np.where(acc, lam * np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), lam * nu)
        new_nu = np.where(acc, 2.0, nu * 2.0)
        return acc, np.minimum(np.maximum(new_lam, self.lambda_min), 1e12), new_nu  # np.clip without its wrapper

    def step(
        self,
        P: np.ndarray,
        diff: np.ndarray,
        g: np.ndarray,
        f0: np.ndarray,
        grad: np.ndarray,
        lam: np.ndarray,
        nu: np.ndarray,
        wt: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nb = self.nb
        nl, d = nb.nl, nb.dim
        robust = nb.loss != "linear" and wt is not None
        if nb.metres:  # rows u/σ_s: per link the unit vector u, and c = Σ_s w_s / σ_s²
            iw = 1.0 / nb.h_sigma**2 * (wt if robust and wt is not None else 1.0)
            c = np.bincount(self.inv, iw, minlength=self.count.size)
            norm = np.linalg.norm(diff[self.first], axis=1)
            v = diff[self.first] / np.where(norm > 0, norm, np.inf)[:, None]
        else:
            c = np.bincount(self.inv, wt, minlength=self.count.size) if robust else self.count  # Σ sample weights
            v = 2.0 * diff.reshape(-1)[self.e_first].reshape(-1, d)  # diff[first] (links, d): one per link
        u = v * self.fs  # neighbour columns that are free
        w = v * self.fo_ls  # own columns that are free
        A0 = csr_times(self.O, (c[:, None, None] * v[:, :, None] * v[:, None, :]).reshape(-1, d * d))
        A0 = A0.reshape(nl, d, d)
        dA = A0.reshape(nl, d * d)[:, :: d + 1] * self.fo  # the diagonals
        dB = c[:, None] * u * u
        if self.damping == "fletcher":  # eq. (8) literally: λ diag(GᵀG)
            floor = 1e-12 * np.maximum(dA.max(axis=1), 1e-300)
            lam_a = lam[:, None] * np.maximum(dA, floor[:, None])
            lam_b = lam[self.ls_own][:, None] * np.maximum(dB, floor[self.ls_own][:, None])
        else:  # Levenberg: λ · mean free diagonal · I (one value per anchor, broadcast over its columns)
            mean = (dA.sum(axis=1) + csr_times(self.O, dB.sum(axis=1))) / self.n_free_1
            lam_mean = lam * np.maximum(mean, 1e-300)
            lam_a, lam_b = lam_mean[:, None], lam_mean[self.ls_own][:, None]
        t = np.where(self.fs, lam_b, 1.0)  # D_s = diag(t) + c u uᵀ
        tu = u / t
        q = np.einsum("ij,ij->i", u, tu)
        den = 1.0 + c * q
        b0 = -grad[:, 0, :]
        bs = -grad.reshape(-1)[self.e_ls].reshape(-1, d)  # grad[ls_own, ls_slot, :]
        # Schur complement: S = A − Σ_s C_s D_s⁻¹ C_sᵀ with C_s = −c w uᵀ  ⇒  C D⁻¹ Cᵀ = c² q/(1+cq) w wᵀ
        Am = A0 * self.mo + self.eye * np.where(self.fo, lam_a, 1.0)[:, :, None]
        coef = c * c * q / den
        S = Am - csr_times(self.O, (coef[:, None, None] * w[:, :, None] * w[:, None, :]).reshape(-1, d * d)).reshape(
            nl, d, d
        )
        tub = np.einsum("ij,ij->i", tu, bs)
        r0 = b0 + csr_times(self.O, (c * tub / den)[:, None] * w)
        with single_threaded_blas():
            d0 = np.linalg.solve(S, r0[:, :, None])[:, :, 0]
        x = bs + (c * np.einsum("ij,ij->i", w, d0.reshape(-1)[self.e_own].reshape(-1, d)))[:, None] * u  # b_s − C_sᵀ δ0
        ds = x / t - (c * np.einsum("ij,ij->i", tu, x) / den)[:, None] * tu  # D_s⁻¹ x (Sherman–Morrison)
        delta = np.zeros(P.shape)  # C-contiguous: written through its flat view below
        delta[:, 0, :] = d0
        delta.reshape(-1)[self.e_ls] = ds.reshape(-1)  # delta[ls_own, ls_slot, :] = ds
        delta = np.where(nb.free_slot, delta, 0.0)
        # gain ratio of each anchor's own partial cost (local evaluation, like the line searches)
        dd = nb.differences(delta)
        if nb.metres:
            a = g
            lin = a + np.einsum("ij,ij->i", nb.jrows(diff), dd)  # r + Jδ
            r = nb.residual_of(np.einsum("ij,ij->i", diff + dd, diff + dd))
        else:
            a = np.einsum("ij,ij->i", diff, diff) - nb.h_d2
            lin = a + 2.0 * np.einsum("ij,ij->i", diff, dd)  # g + Gδ
            r = lin + np.einsum("ij,ij->i", dd, dd)
        f_new = np.bincount(nb.h_own, nb.terms(r), minlength=nl)
        if robust:  # reduction of the weighted quadratic model Σ w (g + Gδ)²
            assert wt is not None
            pred = np.bincount(nb.h_own, wt * (a * a - lin * lin), minlength=nl)
        else:
            pred = f0 - np.bincount(nb.h_own, lin * lin, minlength=nl)
        acc, new_lam, new_nu = self.gain_update(f0, f_new, pred, lam, nu)
        U = P + np.where(acc[:, None, None], delta, 0.0)
        return U, new_lam, new_nu
