"""``csr @ dense`` without scipy's per-call dispatch, for the many small products of the UWB iterations.

scipy's ``csr_matrix @ ndarray`` checks and converts its operands on every call (tens of µs) before it runs its
compiled CSR kernel; the neighbourhood solvers make ~100 such products per iteration on arrays of a few thousand
entries, where that overhead is most of the cost. :func:`csr_times` calls the same kernel directly, so the
arithmetic — and the result, bit for bit — is scipy's; it falls back to ``@`` for anything but a float64 CSR
matrix times a float64 vector or matrix (or if scipy's private kernel module moves).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

try:  # scipy's compiled CSR kernels (private: guarded)
    from scipy.sparse import _sparsetools as _kernels
except ImportError:  # pragma: no cover
    _kernels = None

__all__ = ["csr_times"]


def csr_times(mat: sp.csr_matrix, x: np.ndarray) -> np.ndarray:
    """``mat @ x`` for a CSR ``mat`` and a 1-D or 2-D ``x`` (the same result as scipy's ``@``, bit for bit)."""
    kernels: Any = _kernels
    if (kernels is None or mat.format != "csr" or mat.dtype != np.float64 or x.dtype != np.float64
            or x.ndim not in (1, 2) or x.shape[0] != mat.shape[1]):
        return np.asarray(mat @ x)
    xc = np.ascontiguousarray(x)
    m, n = mat.shape
    if xc.ndim == 1:
        out = np.zeros(m)
        kernels.csr_matvec(m, n, mat.indptr, mat.indices, mat.data, xc, out)
        return out
    out = np.zeros((m, xc.shape[1]))
    kernels.csr_matvecs(m, n, xc.shape[1], mat.indptr, mat.indices, mat.data, xc.ravel(), out.ravel())
    return out
