"""The optional compiled fault round: one pass over a mixer's in-edge CSR rows that decides each message's drop by
the SplitMix64 hash of :func:`distnav.exchange.faults.uniform_hash` and does the masked product, the lost weight
and the lost-message counts at once.

``_dropround.c`` (plain C, no Python.h) is built by pip from ``setup.py`` as the optional extension
``distnav._dropround_c`` and loaded here with ctypes. Where it was not built (no compiler, a failed compile, a
platform without it) or ``DISTNAV_NO_KERNEL`` is set, :func:`prepare` returns None and the mixer takes its numpy
path. The two give the same bits (tested): the hash decides in integers exactly as
:class:`~distnav.exchange.faults.FaultPlan` (``z ≥ ⌈p·2⁵³⌉·2¹¹``); each row sums its delivered terms, with
``w·0`` for a lost one, in the stored CSR order as scipy's ``csr_matvec`` does; the lost weight is summed in edge
order from 0 as ``np.bincount`` does; then ``(self_w + lost) · x`` is added. Why: the numpy path hashes every edge
in several array passes, each as long as the product, so a round with 10 % drops cost 4–5 fault-free rounds
(issue 27); fused with the product, the hash (vectorized where the CPU allows) costs a fraction of one.

Layering: a utility below every package (like :mod:`distnav._sparse`), it takes plain arrays and knows nothing of
exchanges.
"""

from __future__ import annotations

import ctypes
import importlib.machinery
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["DropRound", "library", "lost_mask", "prepare"]

_ABI = 2  # 2: the kernels take the seed and make the round key themselves
_LIB: list[Any] = []  # the loaded library, or None: looked up once, at the first fault round
_P, _I, _U = ctypes.c_void_p, ctypes.c_int64, ctypes.c_uint64
_ROUND_ARGS = [_I, _I, _P, _P, _P, _P, _P, _P, _I, _U, _U, _P, _P, _P, _P, _P]
_MASK_ARGS = [_I, _P, _P, _P, _I, _U, _U, _P]
_MASK64 = 0xFFFFFFFFFFFFFFFF


def library() -> Any:
    """The kernel's ctypes library, or None where it is not built (or ``DISTNAV_NO_KERNEL`` is set)."""
    if not _LIB:
        _LIB.append(None if os.environ.get("DISTNAV_NO_KERNEL") else _load())
    return _LIB[0]


def _load() -> Any:
    here = os.path.dirname(
        os.path.realpath(__file__)
    )  # os.path, not pathlib: the MPI path's start-up imports no pathlib
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = os.path.join(here, f"_dropround_c{suffix}")
        if not os.path.isfile(path):
            continue
        try:
            lib = ctypes.CDLL(path)
            if lib.dn_abi_version() != _ABI:
                return None
        except (OSError, AttributeError):  # not loadable here, or another build's library: the numpy path
            return None
        for name in ("i32_e32", "i32_e64", "i64_e32", "i64_e64"):
            fn = getattr(lib, f"dn_fault_round_{name}")
            fn.argtypes, fn.restype = _ROUND_ARGS, None
        for name in ("e32", "e64"):
            fn = getattr(lib, f"dn_lost_mask_{name}")
            fn.argtypes, fn.restype = _MASK_ARGS, None
        lib.dn_round_key.argtypes, lib.dn_round_key.restype = [_U, _U], _U
        return lib
    return None


def _tag(a: np.ndarray) -> str | None:
    return {np.dtype(np.int32): "32", np.dtype(np.int64): "64"}.get(a.dtype)


def _ptr(a: np.ndarray | None) -> int | None:
    return None if a is None else int(a.ctypes.data)


def _addr(a: np.ndarray) -> int:
    """The address of ``a``'s data: through the buffer protocol (a third of ``a.ctypes.data``'s ≈ 1 µs, which
    counts at 10³ nodes, where a round is a few µs); ``a.ctypes.data`` for read-only or empty arrays."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(cast(Any, a)))
    except (TypeError, ValueError):
        return int(a.ctypes.data)


@dataclass(frozen=True)
class DropRound:
    """A mixer's in-edge block prepared for the kernel (the arrays held, their addresses taken once)."""

    fn: Any
    lib: Any
    n_rows: int
    arrays: tuple[np.ndarray, ...]  # kept alive: the kernel reads them through the addresses below
    pointers: tuple[int | None, ...]  # indptr, indices, data, edge ids, active (None: every edge), self-weights

    def run(
        self,
        cols: np.ndarray,
        x_local: np.ndarray,
        lost_acc: np.ndarray,
        *,
        seed: int,
        round_index: int,
        threshold: int,
        dead_from: np.ndarray | None,
    ) -> np.ndarray:
        """One fault round on ``cols`` (``(n_columns, k)`` float64, C order; the first rows may be ``x_local``'s):
        returns ``(n_rows, k)``, adds each row's lost messages to ``lost_acc`` (int64). ``threshold``:
        ``⌈p·2⁵³⌉·2¹¹``; ``dead_from``: per edge, the first round its message is dead (failed link or silent
        sender), or None when no such fault has begun."""
        k = x_local.shape[1]
        y = np.empty((self.n_rows, k))
        ip, ix, data, edges, act, self_w = self.pointers
        x_addr = _addr(x_local)
        cols_addr = x_addr if cols is x_local else _addr(cols)  # in-process the columns are the local values
        self.fn(self.n_rows, k, ip, ix, data, edges, act, _ptr(dead_from), round_index, seed & _MASK64, threshold,
                cols_addr, self_w, x_addr, _addr(y), _addr(lost_acc))  # fmt: skip
        return y


def prepare(
    matrix: sp.csr_matrix, edge_ids: np.ndarray, active: np.ndarray, self_weight: np.ndarray
) -> DropRound | None:
    """The kernel for a mixer's in-edge block (``matrix``: one entry per in-edge, rows grouped by receiver, each
    entry's weight; ``edge_ids``: the global id of each entry's edge; ``active``: the edges that carry a message),
    or None for the numpy path: no kernel, index types other than int32/int64, or a weight that is not finite
    (``w·0`` would then not be the zero the lost-weight sum relies on)."""
    lib = library()
    if lib is None:
        return None
    indptr, indices, data = matrix.indptr, matrix.indices, matrix.data
    it, et = _tag(indptr), _tag(np.asarray(edge_ids))
    if it is None or et is None or _tag(indices) != it or data.dtype != np.float64 or not np.isfinite(data).all():
        return None
    arrays = tuple(np.ascontiguousarray(a) for a in (indptr, indices, data, edge_ids))
    act = np.ascontiguousarray(active, dtype=bool)
    act_u8 = None if act.all() else act.view(np.uint8)
    self_w = np.ascontiguousarray(self_weight, dtype=np.float64)
    pointers = (*(int(a.ctypes.data) for a in arrays), _ptr(act_u8), int(self_w.ctypes.data))
    fn = getattr(lib, f"dn_fault_round_i{it}_e{et}")
    held = (*arrays, act, self_w)
    return DropRound(fn=fn, lib=lib, n_rows=int(indptr.size - 1), arrays=held, pointers=pointers)


def lost_mask(
    edge_ids: np.ndarray,
    active: np.ndarray | None,
    dead_from: np.ndarray | None,
    *,
    seed: int,
    round_index: int,
    threshold: int,
) -> np.ndarray | None:
    """The kernel's lost-message decisions over ``edge_ids`` in one round (its first phase alone), or None without
    the kernel: for tests against :meth:`~distnav.exchange.faults.FaultPlan.delivered`."""
    lib = library()
    et = _tag(np.asarray(edge_ids))
    if lib is None or et is None:
        return None
    edges = np.ascontiguousarray(edge_ids)
    act = None if active is None else np.ascontiguousarray(active, dtype=bool).view(np.uint8)
    dead = None if dead_from is None else np.ascontiguousarray(dead_from, dtype=np.int64)
    out = np.zeros(edges.size, np.uint8)
    fn = getattr(lib, f"dn_lost_mask_e{et}")
    fn(edges.size, edges.ctypes.data, _ptr(act), _ptr(dead), round_index, seed & _MASK64, threshold, out.ctypes.data)
    return out.view(bool)
