"""The prepared consensus round of an exchange (:meth:`~distnav.exchange.base.Exchange.mixer`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from distnav import _dropround
from distnav._optional import scipy_sparse as sp
from distnav._sparse import csr_times
from distnav.errors import ExchangeError
from distnav.exchange._arrays import _flat, _masked_count, _segment_matrix
from distnav.exchange.faults import FaultPlan

if TYPE_CHECKING:
    from collections.abc import Callable

    from distnav._dropround import DropRound
    from distnav.exchange.core import ExchangeCore

__all__ = ["Mixer"]

_F64 = np.dtype(np.float64)


def _block_csr(
    in_dst: np.ndarray,
    below: np.ndarray,
    in_src_col: np.ndarray,
    edge_w: Callable[[int, int], np.ndarray],
    local_col: np.ndarray,
    self_w: np.ndarray,
    n_cols: int,
) -> sp.csr_matrix:
    """The local block of ``W`` in CSR, each row's entries stored by ascending *global* sender id (the diagonal
    merged in at its place), whatever the column numbering. A row's product then sums its terms in the same order
    on every backend and in every local node order, so results agree bitwise; explicit zeros are left out (as
    scipy's ``+`` does). Needs the incoming edges grouped by receiver with senders ascending (:func:`incoming_edges`);
    the merge is one linear pass, no sort, and writes the CSR arrays in place, in chunks of edges (``edge_w(a, b)``:
    the weights of in-edges ``a:b``), so no edge-sized temporary is made."""
    n, n_e = local_col.size, in_dst.size
    row_len = _masked_count(in_dst, None, n)
    # below: senders before the diagonal in global order (``in_src < nodes[in_dst]``)
    total = n_e + n
    idx_dtype = np.int32 if max(n_cols, total) < 2**31 - 1 else np.int64
    # row r holds its row_len[r] edges and one diagonal slot: it starts at row_start[r] + r
    slot_start = np.zeros(n + 1, np.int64)
    np.cumsum(row_len + 1, out=slot_start[1:])
    n_below = np.zeros(n, np.int64)
    has = row_len > 0
    if n_e:
        starts = (slot_start[:-1] - np.arange(n))[has]  # each non-empty row's first edge
        n_below[has] = np.add.reduceat(below, starts, dtype=np.int64)
    data = np.empty(total)
    cols = np.empty(total, idx_dtype)
    for a in range(0, n_e, _CSR_CHUNK):
        b = min(a + _CSR_CHUNK, n_e)
        pos: np.ndarray = np.arange(a, b, dtype=idx_dtype)
        np.add(pos, in_dst[a:b], out=pos, casting="same_kind")
        np.add(pos, ~below[a:b], out=pos, casting="same_kind")  # an edge after the diagonal moves one slot on
        data[pos], cols[pos] = edge_w(a, b), in_src_col[a:b]
    pos_d = slot_start[:-1] + n_below
    data[pos_d], cols[pos_d] = self_w, local_col
    keep = data != 0
    if keep.all():
        ptr = slot_start
    else:
        # entries kept per row: its slots less the few dropped (no edge-sized integer copy of ``keep``)
        dropped = np.searchsorted(slot_start, np.flatnonzero(~keep), side="right") - 1
        kept = np.diff(slot_start) - np.bincount(dropped, minlength=n)
        del dropped
        _compact(data, keep)
        _compact(cols, keep)
        ptr = np.zeros(n + 1, np.int64)
        np.cumsum(kept, out=ptr[1:])
    return sp.csr_matrix((data, cols, ptr.astype(idx_dtype)), shape=(n, n_cols))


def _compact(arr: np.ndarray, keep: np.ndarray) -> None:
    """``arr`` becomes ``arr[keep]`` in place (its own buffer, shrunk): a chunk of :data:`_CSR_CHUNK` entries at a
    time, each kept entry moved down (never past an entry still to be read), so no second array of its size."""
    w = 0
    for a in range(0, arr.size, _CSR_CHUNK):
        part = arr[a : a + _CSR_CHUNK][keep[a : a + _CSR_CHUNK]]
        arr[w : w + part.size] = part
        w += part.size
    arr.resize(w, refcheck=False)  # the array owns its buffer and nothing else refers to it


_CSR_CHUNK = 1 << 15  # edges per pass when the mixer's block is written (a few MB of temporaries)


class Mixer:
    """A prepared consensus round ``x_i ← w_ii x_i + Σ_{j∈N_i} w_ij x_j`` on an exchange.

    Built by :meth:`Exchange.mixer`; holds the local CSR block of ``W`` so a fault-free round costs one sparse
    product. With faults, a lost message's weight moves to the receiver's self-weight. ``active``: a mask over the
    whole graph's edges, or (on a graph part, which has none) a pair of masks over the block's own in- and out-edge
    rows. ``counts``: the messages each local node sends and receives per round, where the caller knows them (a
    round and its reverse on a graph whose links run both ways: the one's received counts are the other's sent
    ones); the out-edge mask may then be None (fault-free only: a fault round reads it), and the out-edge tables
    are not read.
    """

    def __init__(
        self,
        exchange: ExchangeCore,
        edge_weight: np.ndarray,
        self_weight: np.ndarray,
        active: np.ndarray | tuple[np.ndarray, np.ndarray | None] | None,
        *,
        rows: tuple[np.ndarray, np.ndarray] | None = None,
        counts: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        ex = exchange
        self.exchange = ex
        self._edge_weight = edge_weight  # kept by reference (the caller's weights hold it): no copy
        # which entries of the weight arrays belong to the in-edges and nodes: global ids, or a part's positions
        self._weight_rows = (ex.in_edges, ex.nodes) if rows is None else rows
        every_edge = active is None
        if isinstance(active, tuple):  # masks over this block's own in- and out-edge rows (a graph part)
            if active[1] is None and (counts is None or ex.faults.active):
                raise ExchangeError("a mixer without its out-edge mask needs its counts and no fault schedule")
            self._act_in = np.asarray(active[0], bool) & ex._real_in
            self._act_out = np.zeros(0, bool) if active[1] is None else np.asarray(active[1], bool) & ex._real_out
            active = None
        else:
            self._act_in = ex._real_in if active is None else np.asarray(active, bool)[ex.in_edges] & ex._real_in
            self._act_out = ex._real_out if active is None else np.asarray(active, bool)[ex.out_edges] & ex._real_out
        self._active_global = active
        self._self_w = np.asarray(self_weight, float)[self._weight_rows[1]]
        # fault-free: the fused local block of W over [local nodes | halo columns], each row's terms in global
        # sender order. Under faults only the edge part in incoming-edge order is held (its data are the in-edge
        # weights themselves, the lost entries zeroed for one product and restored), the self-weights apart: one
        # edge-sized float array in all, no fused block that fault rounds never use
        self._w_full: sp.csr_matrix | None = None
        self._w_masked: sp.csr_matrix | None = None
        self._kernel: DropRound | None | bool = False  # the compiled fault round, prepared at the first one
        self._kernel_sent: tuple[np.ndarray, int] | tuple[()] = ()  # the kernel's sent counts, when fixed
        self._kernel_lost: tuple[int, np.ndarray] | None = None  # the exchange's lost counter for a message size
        self._kernel_dead = 0  # the first round a failed link or silent sender kills a message
        # the shape of one float per node where the kernel takes such values without apply's general path (a block
        # without remote senders), and the lost counter of 8-byte messages; () where not
        self._kernel_vector: tuple[int, ...] = ()
        self._kernel_lost_8 = np.zeros(0, np.int64)
        if ex.faults.active:
            self._w_masked = _segment_matrix(
                ex.in_dst, ex.n_local, ex.n_columns, self._in_edge_weights(), ex.in_src_col
            )
        else:
            self._w_full = _block_csr(
                ex.in_dst,
                ex._sender_below(),
                ex.in_src_col,
                self._in_edge_weights,
                ex.local_col,
                self._self_w,
                ex.n_columns,
            )
        if every_edge:  # the exchange's own counts over its real edges (the same mask: the same numbers)
            self._sent_counts, self._recv_counts = ex._all_sent, ex._all_recv
        elif counts is not None:
            self._sent_counts, self._recv_counts = counts
        else:
            self._sent_counts = _masked_count(ex.out_src, self._act_out, ex.n_local)
            self._recv_counts = _masked_count(ex.in_dst, self._act_in, ex.n_local)
        self._sent_total = int(self._sent_counts.sum())

    def drop_fault_state(self) -> None:
        """Release what only a fault round reads — the in- and out-edge masks, the self-weights, the whole graph's
        edge mask and the weights' row maps — on a fault-free mixer of this class (its rounds are one product with
        the fused block; a subclass may read them in its own rounds and keeps them). For a caller that refuses
        fault schedules (the aggregated ADMM rounds): an edge mask less per direction and the self-weights per
        node."""
        if type(self) is not Mixer or self._w_full is None:
            return
        self._act_in = self._act_out = np.zeros(0, bool)
        self._self_w = np.zeros(0)
        self._active_global = None
        empty = np.zeros(0, np.int64)
        self._weight_rows = (empty, empty)  # where the weights sat: read only while the block was written

    def share_with(self, other: Mixer) -> None:
        """Let this mixer read what it holds equal to ``other``'s from ``other``'s arrays: the fused block's weights
        when every weight of both is the same value (two 0/1 mixers: all ones; a prefix of the longer array), and
        its per-node message counts where they equal ``other``'s (a round and its reverse: the one's sent counts
        are the other's received ones). The products and counts are unchanged (the same values)."""
        a, b = self._w_full, other._w_full
        if a is not None and b is not None and 0 < a.nnz <= b.nnz:
            v = b.data[0]
            if bool((a.data == v).all()) and bool((b.data == v).all()):
                a.data = b.data[: a.nnz]
        for mine in ("_sent_counts", "_recv_counts"):
            for theirs in ("_sent_counts", "_recv_counts"):
                if np.array_equal(getattr(self, mine), getattr(other, theirs)):
                    setattr(self, mine, getattr(other, theirs))
                    break

    def apply(self, x_local: np.ndarray) -> np.ndarray:
        """One consensus round on local values ``x_local`` of shape ``(n_local, ...)``."""
        if (
            self._kernel_vector
            and x_local.__class__ is np.ndarray
            and x_local.dtype is _F64
            and x_local.shape == self._kernel_vector
        ):
            return self._kernel_vector_round(x_local)
        ex = self.exchange
        x = np.asarray(x_local, dtype=float)
        if x.shape[0] != ex.n_local:
            raise ExchangeError(f"mixer needs {ex.n_local} local rows, got array of shape {x.shape}")
        flat, tail = _flat(x)
        cols = ex._columns(flat, self._active_global)
        msg_bytes = flat.shape[1] * flat.itemsize
        if self._w_full is not None:
            ex._account(self._sent_counts, self._recv_counts, msg_bytes, self._sent_total)
            out = csr_times(self._w_full, cols.ravel() if x.ndim == 1 else cols)
            return out.reshape(x.shape)
        compiled = self._kernel_round(x, flat, cols, msg_bytes)
        if compiled is not None:
            return compiled
        # fault round: the prepared edge matrix with its lost entries zeroed for the product, lost weight to the
        # self-weight (the lost messages are a tenth of the edges: counters and lost weight are summed over them
        # alone, in edge order, which adds the same terms in the same order as a pass over every edge). Entries
        # not delivered but not lost either are inactive edges and self-loops, whose weight is already 0.
        m = self._w_masked
        assert m is not None
        ok = ex._fault_plan.delivered(ex.round_index)
        lost_e = np.flatnonzero(self._act_in > ok)  # active and not delivered
        sent, sent_total = ex._sent_counts(self._act_out, cache=True)
        lost_dst = ex.in_dst[lost_e]
        ex._account_dropped(sent, sent_total, self._recv_counts, lost_dst, msg_bytes)
        lost_w = m.data[lost_e]
        lost = np.bincount(lost_dst, weights=lost_w, minlength=ex.n_local)
        m.data[lost_e] = lost_w * 0.0  # w·0 as a masked product would hold it
        try:
            out = csr_times(m, cols)
        finally:
            m.data[lost_e] = lost_w
        out += (self._self_w + lost)[:, None] * flat
        return out.reshape(x.shape)

    def _kernel_round(self, x: np.ndarray, flat: np.ndarray, cols: np.ndarray, msg_bytes: int) -> np.ndarray | None:
        """The fault round by the compiled kernel (:mod:`distnav._dropround`: the same drops, the same bits as the
        numpy path below), or None where it is not built: one pass over the in-edge rows, the lost messages added
        to the exchange's lost counter (folded into the received counts lazily, as a fault-free round's are).
        What does not change between rounds is looked up once (:meth:`_prepare_kernel`): the round costs the call
        and the exchange's round count."""
        kernel = self._kernel
        if kernel is False:
            kernel = self._prepare_kernel()
        if not isinstance(kernel, _dropround.DropRound):
            return None
        ex = self.exchange
        k = ex.round_index
        sent, sent_total = self._kernel_sent or ex._sent_counts(self._act_out, cache=True)
        lost = self._kernel_lost
        if lost is None or lost[0] != msg_bytes:
            lost = self._kernel_lost = (msg_bytes, ex._lost_counter(msg_bytes))
        dead = None if k < self._kernel_dead else ex._fault_plan.dead_from(k)
        out = kernel.run(x, flat, cols, lost[1], k, dead)
        ex._account(sent, self._recv_counts, msg_bytes, sent_total)
        return out

    def _kernel_vector_round(self, x: np.ndarray) -> np.ndarray:
        """:meth:`_kernel_round` for one float64 per node in a block without remote senders (its columns are its
        values): what :meth:`apply` makes of other values — the ``(n, k)`` view, the columns, the message size — is
        known, so the round is the kernel's call and the exchange's count (issue 27: ≈ 0.3 µs of a 10 µs round at
        10³ nodes)."""
        ex, kernel = self.exchange, self._kernel
        assert isinstance(kernel, _dropround.DropRound)
        k = ex.round_index
        sent, sent_total = self._kernel_sent or ex._sent_counts(self._act_out, cache=True)
        dead = None if k < self._kernel_dead else ex._fault_plan.dead_from(k)
        out = kernel.run(x, x, x, self._kernel_lost_8, k, dead, 1)
        ex._account(sent, self._recv_counts, 8, sent_total)
        return out

    def _prepare_kernel(self) -> DropRound | None:
        """The compiled fault round for this mixer's in-edge block (None without the kernel, or where the exchange's
        plan is not the schedule's own: the field's also drops what its network lost), with what it reads that does
        not change between rounds: the seed, the drop threshold, the first round a failed link or silent sender
        kills a message and (without silent senders, whose silencing changes them) the sent counts."""
        m, ex = self._w_masked, self.exchange
        assert m is not None
        plan = ex._fault_plan
        if type(plan) is not FaultPlan:
            self._kernel = None
            return None
        kernel = self._kernel = _dropround.prepare(m, plan.edge_ids, self._act_in, self._self_w)
        if kernel is not None:
            kernel.set_faults(ex.faults.seed, plan.drop_threshold)
            self._kernel_sent = () if ex.faults.silent_nodes else ex._sent_counts(self._act_out, cache=True)
            self._kernel_dead = plan.first_dead
            if ex.n_columns == ex.n_local:  # no remote sender: the columns are the block's own values
                self._kernel_lost_8 = ex._lost_counter(8)
                self._kernel_vector = (ex.n_local,)
        return kernel

    def _in_edge_weights(self, a: int = 0, b: int | None = None) -> np.ndarray:
        """``w_ij`` on the incoming edges ``a:b`` (zero on inactive edges and self-loops)."""
        w: np.ndarray = np.asarray(self._edge_weight, float)[self._weight_rows[0][a:b]]
        w[~self._act_in[a:b]] = 0.0
        return w
