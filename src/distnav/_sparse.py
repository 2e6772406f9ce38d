"""``csr @ dense`` by scipy's own compiled CSR kernel, without the ``@`` operator's per-call dispatch.

scipy's ``csr_matrix @ ndarray`` checks and converts its operands on every call (≈ 8 µs, tens of µs for small 2-D
operands) before it runs its CSR kernel. A 10³-node consensus round is one such product (the dispatch is a fifth of
it) and the UWB neighbourhood solvers make ~100 per iteration on arrays of a few thousand entries, where it is most
of the cost. :func:`csr_times` calls the same kernel the operator calls — ``csr_matvec`` for a vector or a single
column, ``csr_matvecs`` for several columns — so the arithmetic, and the result bit for bit, is scipy's. Anything
else (not float64 CSR, other shapes, a scipy whose private kernel module has moved) goes through ``@``.

scipy is looked up at the first product, not at import: an MPI job's start-up does not pay for scipy.sparse
(docs/scale.md). Used by the exchange's mixer and the UWB solvers; one implementation for both.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["csr_times"]

_KERNELS: list[Any] = []  # scipy's (csr_matvec, csr_matvecs), found at the first product; (None, None) if absent


def _kernels() -> tuple[Any, Any]:
    if not _KERNELS:
        try:
            st: Any = importlib.import_module("scipy.sparse._sparsetools")
        except ImportError:  # pragma: no cover - another scipy layout: the public operator
            st = None
        _KERNELS.extend((getattr(st, "csr_matvec", None), getattr(st, "csr_matvecs", None)))
    return _KERNELS[0], _KERNELS[1]


def csr_times(mat: sp.csr_matrix, x: np.ndarray) -> np.ndarray:
    """``mat @ x`` for a CSR ``mat`` and a 1-D or 2-D ``x``: the same result as scipy's ``@``, bit for bit."""
    matvec, matvecs = _kernels()
    if (
        matvec is None
        or matvecs is None
        or getattr(mat, "format", None) != "csr"
        or mat.dtype != np.float64
        or x.dtype != np.float64
        or x.ndim not in (1, 2)
        or x.shape[0] != mat.shape[1]
    ):
        return np.asarray(mat @ x)
    xc = np.ascontiguousarray(x)
    rows, cols = mat.shape
    if xc.ndim == 1 or xc.shape[1] == 1:  # one column: the single-vector kernel, as scipy's ``@`` does
        out = np.zeros(rows if xc.ndim == 1 else (rows, 1))
        matvec(rows, cols, mat.indptr, mat.indices, mat.data, xc.ravel(), out.ravel())
    else:
        out = np.zeros((rows, xc.shape[1]))
        matvecs(rows, cols, xc.shape[1], mat.indptr, mat.indices, mat.data, xc.ravel(), out.ravel())
    return out
