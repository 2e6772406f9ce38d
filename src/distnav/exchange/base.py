"""The exchange interface: directed-edge message rounds over a block of nodes.

An :class:`Exchange` holds a *block* of the graph's nodes (all of them in-process; a partition under MPI).
Algorithms see only local arrays with a leading node axis (``n_local``) or edge axis, and talk to other
nodes only through message rounds:

* :meth:`Exchange.send` — one value per *outgoing* edge of the block (edge order :attr:`out_edges`);
  returns an :class:`Inbox` with one value per *incoming* edge (order :attr:`in_edges`) and a
  ``delivered`` mask (a dropped message is visible, never a silent zero).
* :meth:`Exchange.broadcast` — one value per local node, sent along all its (active) outgoing edges.
* :meth:`Exchange.mixer` — a fused "broadcast, then weighted sum over incoming edges" round for consensus
  ``x_i ← w_ii x_i + Σ_j w_ij x_j`` (paper 003 eq. (31)); a message that is lost is replaced by the
  receiver's own value, i.e. its weight moves to the self-weight (row sums stay 1).

Every round is counted: messages and bytes sent and received per node, and totals per round. Faults come
from a :class:`~distnav.exchange.faults.FaultSchedule` evaluated on global edge ids, so all backends drop
the same messages. Global reductions (:meth:`allreduce`, :meth:`gather_nodes`) are for monitoring and
results only — they model nothing a real node does.

Subclasses implement the transport: :meth:`_columns` (local values plus the values of remote senders
needed by this block) and :meth:`_move_edges` (per-edge values from senders to receivers).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import numpy as np

from distnav._optional import lazy
from distnav.errors import ExchangeError
from distnav.exchange.faults import FaultPlan, FaultSchedule
from distnav.exchange.route import Route
from distnav.network.graph import Graph

if TYPE_CHECKING:
    import scipy.sparse as sp

    from distnav.network.weights import ConsensusWeights
else:  # imported on first use (start-up of an MPI job)
    sp = lazy("scipy.sparse")

__all__ = ["Exchange", "Inbox", "Mixer", "CommTotals", "incoming_edges"]

ReduceOp = Literal["sum", "max", "min"]
#: What :meth:`Exchange.allreduce` reduces: a number or an array (returned as the same kind).
Reducible = TypeVar("Reducible", bound="float | np.ndarray")


@dataclass(frozen=True, eq=False)
class CommTotals:
    """Communication totals of a run, over the whole network (gathered from every block).

    ``messages_sent[i]``/``bytes_sent[i]`` count what node ``i`` transmitted (one message per directed edge,
    dropped ones included, silent nodes excluded); ``messages_received``/``bytes_received`` what arrived.
    ``messages_per_round``/``bytes_per_round`` are network totals per round.
    """

    rounds: int
    messages_sent: np.ndarray
    bytes_sent: np.ndarray
    messages_received: np.ndarray
    bytes_received: np.ndarray
    messages_per_round: np.ndarray
    bytes_per_round: np.ndarray

    @property
    def messages(self) -> int:
        return int(self.messages_sent.sum())

    @property
    def bytes(self) -> int:
        return int(self.bytes_sent.sum())

    @property
    def messages_dropped(self) -> int:
        return int(self.messages_sent.sum() - self.messages_received.sum())

    def as_dict(self) -> dict[str, Any]:
        return {
            "rounds": self.rounds,
            "messages": self.messages,
            "bytes": self.bytes,
            "messages_dropped": self.messages_dropped,
            "max_messages_per_node": int(self.messages_sent.max()) if self.messages_sent.size else 0,
            "max_bytes_per_node": int(self.bytes_sent.max()) if self.bytes_sent.size else 0,
        }

    @staticmethod
    def empty(n_nodes: int) -> CommTotals:
        z = np.zeros(n_nodes, np.int64)
        return CommTotals(0, z, z.copy(), z.copy(), z.copy(), np.zeros(0, np.int64), np.zeros(0, np.int64))


def _segment_matrix(dst_local: np.ndarray, n_rows: int, n_cols: int, data: np.ndarray,
                    col_index: np.ndarray | None = None) -> sp.csr_matrix:
    """CSR matrix with one entry per edge at (dst_local[e], col_index[e]); rows must be sorted."""
    counts = np.bincount(dst_local, minlength=n_rows)
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    cols = np.arange(dst_local.size, dtype=np.int64) if col_index is None else col_index
    idx_dtype = np.int32 if max(n_cols, dst_local.size) < 2**31 - 1 else np.int64
    return sp.csr_matrix((data, cols.astype(idx_dtype), ptr.astype(idx_dtype)), shape=(n_rows, n_cols))


def incoming_edges(graph: Graph, nodes: np.ndarray) -> np.ndarray:
    """Global ids of the edges into ``nodes``, grouped by receiver in the order of ``nodes`` (senders ascending
    within a receiver, as in the graph's own edge order)."""
    ptr = graph.in_ptr
    starts, counts = ptr[nodes], ptr[nodes + 1] - ptr[nodes]
    total = int(counts.sum())
    offsets = np.zeros(nodes.size, np.int64)
    if nodes.size > 1:
        np.cumsum(counts[:-1], out=offsets[1:])
    return np.asarray(np.repeat(starts - offsets, counts) + np.arange(total, dtype=np.int64))


def _masked_count(index: np.ndarray, mask: np.ndarray, n: int) -> np.ndarray:
    """``np.bincount(index[mask], minlength=n)`` without the edge-sized copy ``index[mask]`` (exact integers)."""
    return np.bincount(index, weights=mask, minlength=n).astype(np.int64)


def _block_csr(in_dst: np.ndarray, below: np.ndarray, in_src_col: np.ndarray,
               edge_w: Callable[[int, int], np.ndarray], local_col: np.ndarray, self_w: np.ndarray,
               n_cols: int) -> sp.csr_matrix:
    """The local block of ``W`` in CSR, each row's entries stored by ascending *global* sender id (the diagonal
    merged in at its place), whatever the column numbering. A row's product then sums its terms in the same order
    on every backend and in every local node order, so results agree bitwise; explicit zeros are left out (as
    scipy's ``+`` does). Needs the incoming edges grouped by receiver with senders ascending (:func:`incoming_edges`);
    the merge is one linear pass, no sort, and writes the CSR arrays in place, in chunks of edges (``edge_w(a, b)``:
    the weights of in-edges ``a:b``), so no edge-sized temporary is made."""
    n, n_e = local_col.size, in_dst.size
    row_len = np.bincount(in_dst, minlength=n)
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
        kept = np.add.reduceat(keep, slot_start[:-1], dtype=np.int64) if n else np.zeros(0, np.int64)
        data, cols = data[keep], cols[keep]
        ptr = np.zeros(n + 1, np.int64)
        np.cumsum(kept, out=ptr[1:])
    return sp.csr_matrix((data, cols, ptr.astype(idx_dtype)), shape=(n, n_cols))


_CSR_CHUNK = 1 << 18  # edges per pass when the mixer's block is written (a few MB of temporaries)


_KERNELS: list[Any] = []  # scipy's CSR (matvec, matvecs), looked up at the first product (not at import)


def _csr_product(m: sp.csr_matrix, x: np.ndarray) -> np.ndarray:
    """``m @ x`` (float CSR; float64 vector or ``(n, k)`` array) by scipy's kernel, without the ``@`` dispatch
    (≈ 8 µs a call, a fifth of a 10³-node round)."""
    if not _KERNELS:  # (None, None) on other scipy layouts: then the public operator
        st = getattr(sp, "_sparsetools", None)
        _KERNELS.extend((getattr(st, "csr_matvec", None), getattr(st, "csr_matvecs", None)))
    _MATVEC, _MATVECS = _KERNELS
    if _MATVEC is None or m.dtype != np.float64 or x.dtype != np.float64:
        return np.asarray(m @ x)
    x = np.ascontiguousarray(x)
    rows, cols = m.shape
    if x.ndim == 1 or x.shape[1] == 1:  # one column: the single-vector kernel (as scipy's ``@`` does)
        out = np.zeros(rows if x.ndim == 1 else (rows, 1))
        _MATVEC(rows, cols, m.indptr, m.indices, m.data, x.ravel(), out.ravel())
    else:
        out = np.zeros((rows, x.shape[1]))
        _MATVECS(rows, cols, x.shape[1], m.indptr, m.indices, m.data, x.ravel(), out.ravel())
    return out


def _flat(values: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    tail = values.shape[1:]
    return values.reshape(values.shape[0], math.prod(tail)), tail


@dataclass(eq=False)
class Inbox:
    """What the local block received in one round: a value per incoming edge and whether it arrived.

    ``values[e]`` is meaningful only where ``delivered[e]``; elsewhere it holds zeros.
    ``dst`` is the local receiver index, ``src`` the sender's global id, ``edges`` the global edge id.
    """

    values: np.ndarray
    delivered: np.ndarray
    dst: np.ndarray
    src: np.ndarray
    edges: np.ndarray
    n_local: int

    def sum(self, weights: np.ndarray | None = None) -> np.ndarray:
        """``Σ_e w_e values[e]`` over delivered incoming edges, per local receiver → ``(n_local, ...)``."""
        data = self.delivered.astype(float) if weights is None else np.where(self.delivered, weights, 0.0)
        m = _segment_matrix(self.dst, self.n_local, self.values.shape[0], data)
        flat, tail = _flat(self.values)
        return np.asarray(m @ flat).reshape((self.n_local, *tail))

    def count(self) -> np.ndarray:
        """Number of delivered messages per local receiver."""
        return np.bincount(self.dst[self.delivered], minlength=self.n_local)


class Mixer:
    """A prepared consensus round ``x_i ← w_ii x_i + Σ_{j∈N_i} w_ij x_j`` on an exchange.

    Built by :meth:`Exchange.mixer`; holds the local CSR block of ``W`` so a fault-free round costs one sparse
    product. With faults, a lost message's weight moves to the receiver's self-weight.
    """

    def __init__(self, exchange: Exchange, edge_weight: np.ndarray, self_weight: np.ndarray,
                 active: np.ndarray | None) -> None:
        ex = exchange
        self.exchange = ex
        self._edge_weight = edge_weight  # kept by reference: the fault rounds' in-edge weights come from it
        self._act_in = ex._real_in if active is None else np.asarray(active, bool)[ex.in_edges] & ex._real_in
        self._act_out = ex._real_out if active is None else np.asarray(active, bool)[ex.out_edges] & ex._real_out
        self._active_global = active
        self._self_w = np.asarray(self_weight, float)[ex.nodes]
        # fused local block of W over [local nodes | halo columns], each row's terms in global sender order; the
        # in-edge weights are kept only where fault rounds need them (an edge-sized array less at 10⁶ nodes)
        ew_in = (lambda a, b: self._ew_in[a:b]) if ex.faults.active else self._in_edge_weights
        self._w_full = _block_csr(ex.in_dst, ex._sender_below(), ex.in_src_col, ew_in, ex.local_col,
                                  self._self_w, ex.n_columns)
        if active is None:  # the exchange's own counts over its real edges (the same mask: the same numbers)
            self._sent_counts, self._recv_counts = ex._all_sent, ex._all_recv
        else:
            self._sent_counts = _masked_count(ex.out_src, self._act_out, ex.n_local)
            self._recv_counts = _masked_count(ex.in_dst, self._act_in, ex.n_local)
        self._sent_total = int(self._sent_counts.sum())

    def apply(self, x_local: np.ndarray) -> np.ndarray:
        """One consensus round on local values ``x_local`` of shape ``(n_local, ...)``."""
        ex = self.exchange
        x = np.asarray(x_local, dtype=float)
        if x.shape[0] != ex.n_local:
            raise ExchangeError(f"mixer needs {ex.n_local} local rows, got array of shape {x.shape}")
        flat, tail = _flat(x)
        cols = ex._columns(flat, self._active_global)
        msg_bytes = flat.shape[1] * flat.itemsize
        if not ex.faults.active:
            ex._account(self._sent_counts, self._recv_counts, msg_bytes, self._sent_total)
            out = _csr_product(self._w_full, cols.ravel() if x.ndim == 1 else cols)
            return out.reshape(x.shape)
        # fault round: the same prepared matrix with its data masked in place, lost weight to the self-weight
        # (the lost messages are a tenth of the edges: counters and lost weight are summed over them alone, in
        # edge order, which adds the same terms in the same order as a pass over every edge)
        ok = ex._fault_plan.delivered(ex.round_index)
        lost_e = np.flatnonzero(self._act_in > ok)  # active and not delivered
        sent, sent_total = ex._sent_counts(self._act_out, cache=True)
        lost_dst = ex.in_dst[lost_e]
        ex._account_dropped(sent, sent_total, self._recv_counts, lost_dst, msg_bytes)
        m = self._w_masked
        np.multiply(self._ew_in, ok, out=m.data)
        lost = np.bincount(lost_dst, weights=self._ew_in[lost_e], minlength=ex.n_local)
        out = _csr_product(m, cols)
        out += (self._self_w + lost)[:, None] * flat
        return out.reshape(x.shape)

    def _in_edge_weights(self, a: int = 0, b: int | None = None) -> np.ndarray:
        """``w_ij`` on the incoming edges ``a:b`` (zero on inactive edges and self-loops)."""
        w: np.ndarray = np.asarray(self._edge_weight, float)[self.exchange.in_edges[a:b]]
        w[~self._act_in[a:b]] = 0.0
        return w

    @cached_property
    def _ew_in(self) -> np.ndarray:
        return self._in_edge_weights()

    @cached_property
    def _w_masked(self) -> sp.csr_matrix:
        """The edge part of the local block of ``W`` in incoming-edge order (data rewritten every fault round)."""
        ex = self.exchange
        return _segment_matrix(ex.in_dst, ex.n_local, ex.n_columns, self._ew_in.copy(), ex.in_src_col)


class Exchange(ABC):
    """Directed-edge message passing for one block of nodes. See the module docstring.

    Attributes (all local to the block; node arrays hold *global* ids unless named ``..._local``)
    ----------
    graph : the full communication graph.
    nodes : global ids of the block's nodes in the block's *local order* (``n_local`` of them): the user's order
        restricted to the block, or a locality order (:func:`~distnav.network.partition.locality_order`) chosen
        once at set-up. Per-node arrays of an algorithm follow it; :meth:`local` and :meth:`gather_nodes` convert
        from and to the user's order, so results come back in the user's ids.
    in_edges, in_dst, in_src : incoming edges (global ids), their local receiver index, their sender's global id;
        grouped by local receiver (senders ascending within a receiver).
    out_edges, out_src, out_dst : outgoing edges (global ids), local sender index, receiver's global id.
    in_src_col : column of each incoming edge's sender in the array returned by :meth:`_columns`.
    local_col : column of each local node in that array.
    """

    backend: str = "abstract"
    #: True where a message on out-edge row ``r`` arrives on in-edge row ``r`` with nothing moved (in-process).
    _moves_rows_in_place: bool = False

    def __init__(self, graph: Graph, faults: FaultSchedule | None = None) -> None:
        self.graph = graph
        self.faults = faults if faults is not None else FaultSchedule()
        self.faults.validate_for(graph.n_nodes, graph.links.tolist() if self.faults.failed_links else None)
        self.round_index = 0
        self._round_messages: list[int] = []
        self._round_bytes: list[int] = []

    # ------------------------------------------------------------- set by subclasses
    nodes: np.ndarray
    in_edges: np.ndarray
    in_dst: np.ndarray
    in_src: np.ndarray
    in_src_col: np.ndarray
    local_col: np.ndarray
    out_edges: np.ndarray
    out_src: np.ndarray
    out_dst: np.ndarray
    n_columns: int

    def _init_accounting(self) -> None:
        n = self.n_local
        self._pending: list[tuple[np.ndarray, np.ndarray | None, int]] = []
        self._recv_edges: dict[int, np.ndarray] = {}
        self._sent_cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, int]] = {}
        self.messages_sent = np.zeros(n, np.int64)
        self.bytes_sent = np.zeros(n, np.int64)
        self.messages_received = np.zeros(n, np.int64)
        self.bytes_received = np.zeros(n, np.int64)
        real_out, real_in = self._real_edges()
        self._all_sent = _masked_count(self.out_src, real_out, n)
        self._all_recv = _masked_count(self.in_dst, real_in, n)
        self._all_sent_total = int(self._all_sent.sum())
        self._real_out = real_out
        self._real_in = real_in

    def _real_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Masks over the out- and in-edges that are not self-loops."""
        return self.out_dst != self.nodes[self.out_src], self.in_src != self.nodes[self.in_dst]

    def _sender_below(self) -> np.ndarray:
        """Over the in-edges: is the sender's global id below the receiver's?"""
        return np.asarray(self.in_src < self.nodes[self.in_dst])

    @property
    def n_local(self) -> int:
        return int(self.nodes.size)

    @property
    def n_nodes(self) -> int:
        return self.graph.n_nodes

    # ------------------------------------------------------------- transport (backend)
    @abstractmethod
    def _columns(self, flat_local: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        """Local node values followed by the values of the remote senders this block needs."""

    @abstractmethod
    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        """Values on outgoing edges → values on incoming edges (in :attr:`in_edges` order)."""

    @abstractmethod
    def allreduce(self, value: Reducible, op: ReduceOp = "sum") -> Reducible:
        """Reduce a scalar or array over all blocks (monitoring only)."""

    @abstractmethod
    def gather_nodes(self, local: np.ndarray) -> np.ndarray:
        """Assemble a per-node array ``(n_local, ...)`` of every block into ``(n_nodes, ...)`` on every block."""

    @abstractmethod
    def barrier(self) -> None:
        """Wait for every block (no-op in-process)."""

    @property
    def is_root(self) -> bool:
        """True on the block that writes files (the only one in-process; rank 0 under MPI)."""
        return True

    def local(self, global_array: np.ndarray) -> np.ndarray:
        """This block's rows of a per-node array with leading axis ``n_nodes``."""
        arr = np.asarray(global_array)
        if arr.shape[0] != self.n_nodes:
            raise ExchangeError(f"expected a per-node array with {self.n_nodes} rows, got shape {arr.shape}")
        return np.asarray(arr[self.nodes])

    # ------------------------------------------------------------- rounds
    @cached_property
    def _fault_plan(self) -> FaultPlan:
        """The fault schedule compiled for this block's incoming edges (once)."""
        return FaultPlan(self.faults, self.in_src, self.nodes[self.in_dst], self.in_edges)

    def _delivered(self, active_in: np.ndarray) -> np.ndarray:
        if not self.faults.active:
            return active_in.copy()
        return np.asarray(self._fault_plan.delivered(self.round_index) & active_in)

    def _sent_counts(self, act_out: np.ndarray, *, cache: bool) -> tuple[np.ndarray, int]:
        """Messages each local node transmits this round on the outgoing edges ``act_out`` (silent senders send
        nothing). They change only when a silencing begins, so a persistent ``act_out`` is counted once per stage."""
        stage = self._fault_plan.silent_stage(self.round_index) if self.faults.silent_nodes else 0
        key = (id(act_out), stage)
        hit = self._sent_cache.get(key) if cache else None
        if hit is not None:
            return hit[1], hit[2]
        sel = act_out
        if stage:
            silent = self.faults.silent_mask(self.round_index, self.nodes)
            sel = act_out & ~silent[self.out_src]
        counts = np.bincount(self.out_src[sel], minlength=self.n_local)
        total = int(counts.sum())
        if cache:
            self._sent_cache[key] = (act_out, counts, total)  # act_out kept alive so its id stays unique
        return counts, total

    def _account_faulty(self, sent: np.ndarray, sent_total: int, delivered: np.ndarray, msg_bytes: int) -> None:
        """Count a fault round lazily: ``sent`` is a reused count array, ``delivered`` a mask over incoming edges
        added to a per-edge counter (one pass), turned into per-node counts only by :meth:`_flush`."""
        acc = self._recv_edges.get(msg_bytes)
        if acc is None:
            acc = self._recv_edges[msg_bytes] = np.zeros(self.in_edges.size, np.int64)
        np.add(acc, delivered, out=acc)
        self._pending.append((sent, None, msg_bytes))
        self._round_messages.append(sent_total)
        self._round_bytes.append(sent_total * msg_bytes)
        self.round_index += 1

    def _account_dropped(self, sent: np.ndarray, sent_total: int, received_all: np.ndarray, lost_dst: np.ndarray,
                         msg_bytes: int) -> None:
        """Count a fault round from its lost messages: ``sent`` a reused count array (folded in lazily),
        ``received_all`` what would arrive without losses, ``lost_dst`` the local receiver of each lost message."""
        received = received_all - np.bincount(lost_dst, minlength=self.n_local)
        self.messages_received += received
        self.bytes_received += received * msg_bytes
        self._pending.append((sent, None, msg_bytes))
        self._round_messages.append(sent_total)
        self._round_bytes.append(sent_total * msg_bytes)
        self.round_index += 1

    def _account(self, sent: np.ndarray, received: np.ndarray, msg_bytes: int, total: int | None = None) -> None:
        """Count one round. With ``total`` given, ``sent``/``received`` are count arrays reused round after round
        (a prepared mixer): they are folded in lazily (:meth:`_flush`), so such a round costs a list append, not
        four array additions. Fresh arrays are folded in at once."""
        if total is None:
            total = int(sent.sum())
            self.messages_sent += sent
            self.bytes_sent += sent * msg_bytes
            self.messages_received += received
            self.bytes_received += received * msg_bytes
        else:
            self._pending.append((sent, received, msg_bytes))
        self._round_messages.append(total)
        self._round_bytes.append(total * msg_bytes)
        self.round_index += 1

    def _flush(self) -> None:
        groups: dict[tuple[int, int, int], list[Any]] = {}
        for sent, received, msg_bytes in self._pending:
            key = (id(sent), id(received), msg_bytes)
            if key in groups:
                groups[key][3] += 1
            else:
                groups[key] = [sent, received, msg_bytes, 1]
        for sent, received, msg_bytes, times in groups.values():
            self.messages_sent += sent * times
            self.bytes_sent += sent * (times * msg_bytes)
            if received is not None:
                self.messages_received += received * times
                self.bytes_received += received * (times * msg_bytes)
        self._pending.clear()
        for msg_bytes, acc in self._recv_edges.items():
            counts = np.bincount(self.in_dst, weights=acc, minlength=self.n_local).astype(np.int64)
            self.messages_received += counts
            self.bytes_received += counts * msg_bytes
            acc[:] = 0

    def _active_slices(self, active: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        if active is None:
            return self._real_out, self._real_in
        act = np.asarray(active, bool)
        if act.shape != (self.graph.n_edges,):
            raise ExchangeError(f"active must be a mask over the {self.graph.n_edges} directed edges, got {act.shape}")
        return act[self.out_edges] & self._real_out, act[self.in_edges] & self._real_in

    def _finish_round(self, values_in: np.ndarray, act_out: np.ndarray, act_in: np.ndarray,
                      tail: tuple[int, ...], msg_bytes: int, owned: bool = False) -> Inbox:
        if self.faults.active:
            delivered = self._delivered(act_in)
            sent, total = self._sent_counts(act_out, cache=act_out is self._real_out)
            self._account_faulty(sent, total, delivered, msg_bytes)
            return self._inbox(values_in, delivered, tail, owned=owned)
        delivered = act_in.copy()
        if act_out is self._real_out:
            self._account(self._all_sent, self._all_recv, msg_bytes, self._all_sent_total)
            return self._inbox(values_in, delivered, tail, owned=owned)
        sent = np.bincount(self.out_src[act_out], minlength=self.n_local)
        recv = np.bincount(self.in_dst[delivered], minlength=self.n_local)
        self._account(sent, recv, msg_bytes)
        return self._inbox(values_in, delivered, tail, owned=owned)

    def _inbox(self, values_in: np.ndarray, delivered: np.ndarray, tail: tuple[int, ...], *,
               owned: bool = False) -> Inbox:
        if not delivered.all():
            if owned:  # a fresh array of this round: zero the undelivered rows in place
                values_in[~delivered] = 0.0
            else:
                values_in = np.where(delivered[:, None], values_in, 0.0)
        return Inbox(values=values_in.reshape((values_in.shape[0], *tail)), delivered=delivered,
                     dst=self.in_dst, src=self.in_src, edges=self.in_edges, n_local=self.n_local)

    def broadcast(self, node_values: np.ndarray, *, active: np.ndarray | None = None) -> Inbox:
        """Each local node sends its row of ``node_values`` along its (active) outgoing edges.

        ``active`` is an optional boolean mask over the graph's directed edges (e.g. a session of a
        switching graph); inactive edges carry nothing and are not counted.
        """
        x = np.asarray(node_values)
        if x.ndim == 0 or x.shape[0] != self.n_local:
            raise ExchangeError(f"broadcast needs {self.n_local} local rows, got array of shape {x.shape}")
        flat, tail = _flat(x)
        act_out, act_in = self._active_slices(active)
        cols = self._columns(flat, active)
        gathered = np.take(cols, self.in_src_col, axis=0, mode="clip")  # valid indices; "clip" skips a temporary
        return self._finish_round(gathered, act_out, act_in, tail, flat.shape[1] * flat.itemsize,
                                  owned=True)

    def send(self, edge_values: np.ndarray, *, active: np.ndarray | None = None) -> Inbox:
        """Send one value per outgoing edge (rows in :attr:`out_edges` order); receive one per incoming edge."""
        x = np.asarray(edge_values)
        if x.ndim == 0 or x.shape[0] != self.out_edges.size:
            raise ExchangeError(
                f"send needs one row per outgoing edge ({self.out_edges.size}), got array of shape {x.shape}"
            )
        flat, tail = _flat(x)
        act_out, act_in = self._active_slices(active)
        moved = self._move_edges(flat, active)
        return self._finish_round(moved, act_out, act_in, tail, flat.shape[1] * flat.itemsize,
                                  owned=not np.may_share_memory(moved, x))

    def route(self, active: np.ndarray, *, in_rows: np.ndarray | None = None,
              out_rows: np.ndarray | None = None) -> Route:
        """Prepare rounds over the edges of ``active`` on compact arrays (:class:`~distnav.exchange.route.Route`):
        the same messages, counts and faults as :meth:`broadcast`/:meth:`send` with that mask, without the
        full-length arrays."""
        return Route(self, active, in_rows=in_rows, out_rows=out_rows)

    def mixer(self, weights: ConsensusWeights, *, active: np.ndarray | None = None) -> Mixer:
        """Prepare consensus rounds with a :class:`~distnav.network.weights.ConsensusWeights` on this graph.

        For a switching graph pass the session's weights expressed on the union graph and its edge mask.
        """
        if weights.graph.n_edges != self.graph.n_edges or weights.graph.n_nodes != self.graph.n_nodes:
            raise ExchangeError("weights are defined on a different graph than this exchange")
        return Mixer(self, weights.edge_weight, weights.self_weight, active)

    # ------------------------------------------------------------- accounting
    def comm_totals(self) -> CommTotals:
        """Network-wide totals so far (gathered from every block)."""
        self._flush()
        return CommTotals(
            rounds=self.round_index,
            messages_sent=self.gather_nodes(self.messages_sent),
            bytes_sent=self.gather_nodes(self.bytes_sent),
            messages_received=self.gather_nodes(self.messages_received),
            bytes_received=self.gather_nodes(self.bytes_received),
            messages_per_round=np.asarray(self.allreduce(np.asarray(self._round_messages, np.int64), "sum")),
            bytes_per_round=np.asarray(self.allreduce(np.asarray(self._round_bytes, np.int64), "sum")),
        )

    def reset_accounting(self) -> None:
        """Zero the counters and the round index (the fault schedule restarts at round 0)."""
        self.round_index = 0
        self._round_messages.clear()
        self._round_bytes.clear()
        self._init_accounting()
