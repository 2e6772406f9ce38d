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
import struct
import sys
from typing import TYPE_CHECKING, Any, cast

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["DropRound", "library", "lost_mask", "prepare"]

_ABI = 4  # 4: what changes per round at the struct's end (3: one entry point taking a struct; 2: the round key)
_LIB: list[Any] = []  # the loaded library, or None: looked up once, at the first fault round
_P, _I, _U = ctypes.c_void_p, ctypes.c_int64, ctypes.c_uint64
_MASK_ARGS = [_I, _P, _P, _P, _I, _U, _U, _P]
_MASK64 = 0xFFFFFFFFFFFFFFFF
# An output buffer is reused when its reference count shows that nothing outside refers to it. That rule holds on
# CPython 3.11–3.13 with the GIL (the same loop over plain objects run on 3.11.7, 3.12.1 and 3.13.0: a buffer held
# by a caller's name or a list is counted, a dropped one is not); 3.14 documents lower counts from borrowed stack
# references and the free-threaded build counts otherwise, so there (and on other interpreters) every round makes a
# new output: slower, never wrong.
_REUSE = sys.implementation.name == "cpython" and (3, 11) <= sys.version_info[:2] <= (3, 13)
_REUSE = _REUSE and "free-threading" not in sys.version


def library() -> Any:
    """The kernel's ctypes library, or None where it is not built (or ``DISTNAV_NO_KERNEL`` is set)."""
    if not _LIB:
        _LIB.append(None if os.environ.get("DISTNAV_NO_KERNEL") else _load())
    return _LIB[0]


def _load() -> Any:
    # os.path, not pathlib: the MPI path's start-up imports no pathlib (tests/test_lazy_imports.py)
    here = os.path.dirname(os.path.realpath(__file__))
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
        lib.dn_fault_round.restype = None  # no argtypes: its one argument is a prepared byref, passed as is
        for name in ("e32", "e64"):
            fn = getattr(lib, f"dn_lost_mask_{name}")
            fn.argtypes, fn.restype = _MASK_ARGS, None
        lib.dn_round_key.argtypes, lib.dn_round_key.restype = [_U, _U], _U
        _PACKER.append(_round_packer())
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


class _Args(ctypes.Structure):
    """``dn_round_args`` of ``_dropround.c``: one fault round's arguments, passed by one pointer; what changes from
    round to round (``_ROUND_FIELDS``) sits together at the end."""

    _fields_ = [
        ("kind", _I),
        ("n_rows", _I),
        *((name, _P) for name in ("indptr", "indices", "data", "edges", "active")),
        ("seed", _U),
        ("threshold", _U),
        *((name, _P) for name in ("self_w", "dead_from", "lost_acc")),
        ("k", _I),
        ("round_index", _I),
        *((name, _P) for name in ("cols", "xl", "y")),
    ]


_ROUND_FIELDS = ("k", "round_index", "cols", "xl", "y")


def _round_packer(args: type[ctypes.Structure] = _Args) -> tuple[struct.Struct, int]:
    """A packer writing ``_ROUND_FIELDS`` into the struct's memory in one call (a third of five ctypes attribute
    sets), laid out from ctypes' own offsets and sizes (pointers are 4 bytes on a 32-bit build), and their offset.
    Addresses are packed unsigned (an address ≥ 2³¹ on a 32-bit build, ≥ 2⁶³ on a 64-bit one, is no error), the
    two counts signed, as the C struct declares them."""
    at = first = getattr(args, _ROUND_FIELDS[0]).offset
    fmt = "="
    for name in _ROUND_FIELDS:
        field = getattr(args, name)
        code = {8: "q", 4: "i"}.get(field.size) if name in ("k", "round_index") else {8: "Q", 4: "I"}.get(field.size)
        if code is None:
            raise RuntimeError(
                f"distnav._dropround: the kernel's argument field {name!r} is {field.size} bytes on this build "
                "(4 or 8 expected); set DISTNAV_NO_KERNEL=1 to use the numpy path"
            )
        fmt += "x" * (field.offset - at) + code
        at = field.offset + field.size
    return struct.Struct(fmt), first


_PACKER: list[tuple[struct.Struct, int]] = []  # _round_packer's, made when the library loads


class DropRound:
    """A mixer's in-edge block prepared for the kernel: the arrays held, their addresses and every argument that
    does not change between rounds set once in the argument struct; a round sets only what changed (the round
    index; the value, column and output addresses when they moved) and makes one ctypes call with one prepared
    argument (issue 27: the per-round Python cost counts at 10³ nodes, where a whole round takes a few µs).

    Outputs come from two held buffers, each reused only when nothing outside this object refers to it any more
    (its reference count; on interpreters where that count is verified, ``_REUSE``): a loop ``x = mixer.apply(x)``
    alternates between them and a caller that keeps a result keeps it unchanged (a new buffer is made then). No
    round allocates in such a loop and no address is looked up: the input is the last output, whose address is
    known. Elsewhere every round makes a new output (held as the newest of the two)."""

    __slots__ = (
        *("_args", "_at", "_byref", "_call", "_cols", "_dead", "_in", "_lost", "_mem", "_out", "_pack"),
        *("arrays", "n_rows"),
    )

    def __init__(self, lib: Any, kind: int, arrays: tuple[np.ndarray, ...], active: np.ndarray | None) -> None:
        self.arrays = (*arrays, active)  # kept alive: the kernel reads them through the addresses in the struct
        self.n_rows = int(arrays[0].size - 1)
        a = self._args = _Args(kind=kind, n_rows=self.n_rows)
        a.indptr, a.indices, a.data, a.edges, a.self_w = (int(x.ctypes.data) for x in arrays)
        a.active = _ptr(active)
        self._byref = ctypes.byref(a)
        self._mem = memoryview(a).cast("B")  # the struct's bytes, for the packer
        packer, self._at = _PACKER[0]
        self._pack = packer.pack_into
        self._call = lib.dn_fault_round
        self._lost: np.ndarray | None = None  # the lost counter whose address is in the struct
        self._dead: np.ndarray | None = None  # the dead-from array whose address is in the struct
        # the output buffers with their addresses, and the last other input and column arrays with theirs: held, so
        # none is freed and its address reused by another array while it is here
        self._out: list[tuple[np.ndarray, int]] = []
        self._in: tuple[np.ndarray, int] | None = None
        self._cols: tuple[np.ndarray, int] | None = None

    def set_faults(self, seed: int, threshold: int) -> None:
        """The schedule's seed and drop threshold ``⌈p·2⁵³⌉·2¹¹``: the same every round, set once."""
        self._args.seed, self._args.threshold = seed & _MASK64, threshold

    def _values(self, key: np.ndarray, flat: np.ndarray) -> tuple[np.ndarray, int]:
        """``flat`` (the values ``key`` as ``(n, k)``) C-ordered and its address, for values that are neither an
        output of this kernel's nor the last input (:meth:`run` knows those): held when ``key``'s own memory is read."""
        if not flat.flags.c_contiguous:
            flat = np.ascontiguousarray(flat)  # a copy of this round's values: the caller holds it for the call
        addr = _addr(flat)
        if key.flags.c_contiguous:  # ``flat`` is a view of ``key``'s own values: the address stays
            self._in = (key, addr)
        return flat, addr

    def _new_output(self, key: np.ndarray) -> tuple[np.ndarray, int]:
        """A new output buffer shaped as ``key``, held in place of one that is not this round's input."""
        y = np.empty(key.shape)  # C order: the same memory as (n_rows, k)
        made = (y, _addr(y))
        out = self._out
        if len(out) < 2:
            out.append(made)
        else:  # the caller keeps the other (it is this round's input, or refers to both)
            out[0 if out[1][0] is key else 1] = made
        return made

    def run(
        self,
        key: np.ndarray,
        flat: np.ndarray,
        cols: np.ndarray,
        lost_acc: np.ndarray,
        round_index: int,
        dead: Any,
        width: int | None = None,
    ) -> np.ndarray:
        """One fault round on the values ``key`` (``(n_rows, ...)`` float64; ``flat``: the same as ``(n_rows, k)``)
        and ``cols`` (``(n_columns, k)``: the local values then the remote senders', or ``flat`` itself), with the
        seed and threshold of :meth:`set_faults`: returns the new values shaped as ``key``, adds each row's lost
        messages to ``lost_acc`` (int64, C order). ``dead``: per edge, the first round its message is dead (failed
        link or silent sender), or None when no such fault has begun. ``width``: ``k``, when ``flat`` is ``key``
        itself, 1-D (one float per node)."""
        in_place = cols is flat  # in-process the columns are the local values
        out = self._out
        x_addr = 0
        for buf, addr in out:  # a loop ``x = mixer.apply(x)``: the last output
            if buf is key:
                x_addr = addr
        if not x_addr:
            held = self._in  # the same input again
            x_addr = held[1] if held is not None and held[0] is key else 0
            if not x_addr:
                flat, x_addr = self._values(key, flat)
        for buf, addr in out if _REUSE else ():
            # a buffer nothing outside refers to: its references are the list's tuple, ``buf`` here and
            # getrefcount's argument (a caller's name, a view or a container holding it adds one)
            if sys.getrefcount(buf) <= 3 and buf.shape == key.shape:
                y, y_addr = buf, addr
                break
        else:
            y, y_addr = self._new_output(key)
        if lost_acc is not self._lost:  # the exchange's counter: the same array round after round
            self._args.lost_acc, self._lost = _addr(lost_acc), lost_acc
        if dead is not self._dead:
            self._args.dead_from, self._dead = (None if dead is None else _addr(dead)), dead
        c_addr = x_addr if in_place else self._columns(cols)
        k = flat.shape[1] if width is None else width
        self._pack(self._mem, self._at, k, round_index, c_addr, x_addr, y_addr)
        self._call(self._byref)
        return y

    def _columns(self, cols: np.ndarray) -> int:
        """The address of the columns, C-ordered: the MPI exchange's column buffer is the same array every round."""
        held = self._cols
        if held is not None and held[0] is cols:
            return held[1]
        c = np.ascontiguousarray(cols)
        addr = _addr(c)
        self._cols = (cols, addr) if c is cols else (c, addr)  # a copy is held until the next round takes another
        return addr


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
    self_w = np.ascontiguousarray(self_weight, dtype=np.float64)
    kind = ("32", "64").index(it) * 2 + ("32", "64").index(et)
    return DropRound(lib, kind, (*arrays, self_w), None if act.all() else act.view(np.uint8))


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
