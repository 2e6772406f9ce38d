"""Array helpers shared by the exchange and its mixer: counts and CSR blocks over a block's edges."""

from __future__ import annotations

import math

import numpy as np

from distnav._optional import scipy_sparse as sp

__all__: list[str] = []


def _segment_matrix(
    dst_local: np.ndarray, n_rows: int, n_cols: int, data: np.ndarray, col_index: np.ndarray | None = None
) -> sp.csr_matrix:
    """CSR matrix with one entry per edge at (dst_local[e], col_index[e]); rows must be sorted."""
    counts = _masked_count(dst_local, None, n_rows)
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    idx_dtype = np.int32 if max(n_cols, dst_local.size) < 2**31 - 1 else np.int64
    cols = np.arange(dst_local.size, dtype=idx_dtype) if col_index is None else col_index
    # the column index array is shared, not copied, when it has the index dtype already (the mixer's edge block)
    return sp.csr_matrix((data, cols.astype(idx_dtype, copy=False), ptr.astype(idx_dtype)), shape=(n_rows, n_cols))


def _masked_count(index: np.ndarray, mask: np.ndarray | None, n: int) -> np.ndarray:
    """``np.bincount(index[mask], minlength=n)`` (int64) a chunk of edges at a time: no edge-sized temporary (a
    whole-array bincount casts an int32 index to a 64-bit copy, and a weighted one makes a float copy too)."""
    counts = np.zeros(n, np.int64)
    for a in range(0, int(index.size), _COUNT_CHUNK):
        part = index[a : a + _COUNT_CHUNK]
        if mask is not None:
            part = part[mask[a : a + _COUNT_CHUNK]]
        counts += np.bincount(part, minlength=n)
    return counts


_COUNT_CHUNK = 1 << 20  # edges per bincount (8 MB of 64-bit indices)


def _flat(values: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    """``values`` as ``(n, k)`` (a view where its layout allows) and its shape after the first axis."""
    if values.ndim == 1:  # the common case of a consensus round, without the general path's ≈ 0.3 µs
        return values[:, None], ()
    tail = values.shape[1:]
    return values.reshape(values.shape[0], math.prod(tail)), tail
