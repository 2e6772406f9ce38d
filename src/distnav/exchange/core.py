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

from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange._arrays import _flat, _masked_count, _segment_matrix
from distnav.exchange.faults import FaultPlan, FaultSchedule
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart, incoming_positions

if TYPE_CHECKING:
    pass

__all__ = ["ExchangeCore", "Inbox", "CommTotals", "incoming_edges"]

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
        totals = {name: getattr(self, name) for name in ("rounds", "messages", "bytes", "messages_dropped")}
        per_node = {"max_messages_per_node": self.messages_sent, "max_bytes_per_node": self.bytes_sent}
        return {**totals, **{key: int(sent.max()) if sent.size else 0 for key, sent in per_node.items()}}

    def snapshot(self) -> CommTotals:
        """A copy of these totals (an in-process exchange hands out its live counters, updated in place)."""
        return CommTotals(
            self.rounds,
            self.messages_sent.copy(),
            self.bytes_sent.copy(),
            self.messages_received.copy(),
            self.bytes_received.copy(),
            self.messages_per_round.copy(),
            self.bytes_per_round.copy(),
        )

    def since(self, before: CommTotals) -> CommTotals:
        """The communication between ``before`` (an earlier :meth:`snapshot` of the same exchange) and these."""
        return CommTotals(
            self.rounds - before.rounds,
            self.messages_sent - before.messages_sent,
            self.bytes_sent - before.bytes_sent,
            self.messages_received - before.messages_received,
            self.bytes_received - before.bytes_received,
            self.messages_per_round[before.rounds :],
            self.bytes_per_round[before.rounds :],
        )

    @staticmethod
    def empty(n_nodes: int) -> CommTotals:
        z = np.zeros(n_nodes, np.int64)
        return CommTotals(0, z, z.copy(), z.copy(), z.copy(), np.zeros(0, np.int64), np.zeros(0, np.int64))


def _all_true_as_broadcast(out_mask: np.ndarray, in_mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The real-edge masks, each held as one read-only broadcast ``True`` when it has no self-loop to leave out (a
    graph without self-loops: two edge-sized masks less); one object for both when they were one."""
    same = out_mask is in_mask
    out_b = np.broadcast_to(np.True_, out_mask.shape) if bool(out_mask.all()) else out_mask
    in_b = out_b if same else np.broadcast_to(np.True_, in_mask.shape) if bool(in_mask.all()) else in_mask
    return out_b, in_b


def _is_all_true(mask: np.ndarray) -> bool:
    """Whether ``mask`` is a broadcast ``True`` of :func:`_all_true_as_broadcast` (one element seen everywhere)."""
    return mask.ndim == 1 and mask.size > 0 and mask.strides == (0,) and bool(mask[0])


def incoming_edges(graph: Graph, nodes: np.ndarray) -> np.ndarray:
    """Global ids of the edges into ``nodes``, grouped by receiver in the order of ``nodes`` (senders ascending
    within a receiver, as in the graph's own edge order)."""
    return incoming_positions(graph.in_ptr, nodes)


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


class ExchangeCore(ABC):
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
    #: True where the out-edge rows are the reverses of the in-edge rows (every link stored both ways, as a graph
    #: part holds them): a node's out-edges and in-edges then pair up, and its sent counts equal its received ones.
    _out_reverses_in: bool = False
    #: True where a message on out-edge row ``r`` arrives on in-edge row ``r`` with nothing moved (in-process).
    _moves_rows_in_place: bool = False

    def __init__(self, graph: Graph | GraphPart, faults: FaultSchedule | None = None) -> None:
        self._graph = graph
        self.faults = faults if faults is not None else FaultSchedule()
        # a part can check node ids only: most links are on other ranks
        links = graph.links.tolist() if self.faults.failed_links and isinstance(graph, Graph) else None
        self.faults.validate_for(graph.n_nodes, links)
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
        # per message size: messages lost per receiver (the kernel's). Zeroed in place on a reset: a mixer's compiled
        # round holds these arrays, and losses written into a replaced one would go uncounted
        lost_nodes: dict[int, np.ndarray] = self.__dict__.get("_lost_nodes", {})
        for lost in lost_nodes.values():
            lost[:] = 0
        self._lost_nodes = lost_nodes
        self._sent_cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, int]] = {}
        self.messages_sent = np.zeros(n, np.int64)
        self.bytes_sent = np.zeros(n, np.int64)
        self.messages_received = np.zeros(n, np.int64)
        self.bytes_received = np.zeros(n, np.int64)
        real_out, real_in = _all_true_as_broadcast(*self._real_edges())
        self._all_recv = _masked_count(self.in_dst, None if _is_all_true(real_in) else real_in, n)
        if self._out_reverses_in:  # the same (sender, receiver) pairs: the sent counts are the received ones
            self._all_sent = self._all_recv
        else:
            self._all_sent = _masked_count(self.out_src, None if _is_all_true(real_out) else real_out, n)
        self._all_sent_total = int(self._all_sent.sum())
        self._real_out, self._real_in = real_out, real_in

    def _real_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Masks over the out- and in-edges that are not self-loops."""
        return self.out_dst != self.nodes[self.out_src], self.in_src != self.nodes[self.in_dst]

    def _sender_below(self) -> np.ndarray:
        """Over the in-edges: is the sender's global id below the receiver's?"""
        return np.asarray(self.in_src < self.nodes[self.in_dst])

    @property
    def graph(self) -> Graph:
        """The whole communication graph (not held by an exchange built from a :class:`GraphPart`)."""
        if not isinstance(self._graph, Graph):
            raise ExchangeError(
                "this exchange was built from a graph part: the whole graph is on no rank (use "
                "n_nodes / n_edges, or build the exchange from a Graph)"
            )
        return self._graph

    @property
    def part(self) -> GraphPart | None:
        """The graph part the exchange was built from, or None when it holds the whole graph."""
        return self._graph if isinstance(self._graph, GraphPart) else None

    @property
    def n_local(self) -> int:
        return int(self.nodes.size)

    @property
    def n_nodes(self) -> int:
        return self._graph.n_nodes

    @property
    def n_edges(self) -> int:
        """Directed edges of the whole graph (global edge ids run over ``0..n_edges-1``)."""
        return self._graph.n_edges

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
        """This block's rows of a per-node array with leading axis ``n_nodes`` (user's order → local order)."""
        arr = np.asarray(global_array)
        if arr.ndim == 0 or arr.shape[0] != self.n_nodes:
            raise ExchangeError(f"expected a per-node array with {self.n_nodes} rows, got shape {arr.shape}")
        # np.take copies whole rows: 3-4x faster than fancy indexing on (n, k) arrays (10^5 x 10: 5 ms, not 20)
        return np.take(arr, self.nodes, axis=0)

    # ------------------------------------------------------------- rounds
    @cached_property
    def _fault_plan(self) -> FaultPlan:
        """The fault schedule compiled for this block's incoming edges (once)."""
        real = self._real_in  # not a self-loop: the plan needs the endpoints only for failed links / silent nodes
        return FaultPlan(
            self.faults,
            lambda: self.in_src,
            lambda: self.nodes[self.in_dst],
            self.in_edges,
            is_self=~real if not real.all() else np.zeros(real.size, bool),
        )

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
        counts = _masked_count(self.out_src, sel, self.n_local)
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

    def _account_dropped(
        self, sent: np.ndarray, sent_total: int, received_all: np.ndarray, lost_dst: np.ndarray, msg_bytes: int
    ) -> None:
        """Count a fault round from its lost messages: ``sent`` a reused count array (folded in lazily),
        ``received_all`` what would arrive without losses, ``lost_dst`` the local receiver of each lost message."""
        received = received_all - np.bincount(lost_dst, minlength=self.n_local)
        self.messages_received += received
        self.bytes_received += received * msg_bytes
        self._pending.append((sent, None, msg_bytes))
        self._round_messages.append(sent_total)
        self._round_bytes.append(sent_total * msg_bytes)
        self.round_index += 1

    def _lost_counter(self, msg_bytes: int) -> np.ndarray:
        """Per receiver, the messages of ``msg_bytes`` lost since the last :meth:`_flush`, which subtracts them
        from the received counts: a compiled fault round adds its losses here and counts the round with
        :meth:`_account` as if every message arrived (the counts then cost no array pass per round)."""
        lost = self._lost_nodes.get(msg_bytes)
        if lost is None:
            lost = self._lost_nodes[msg_bytes] = np.zeros(self.n_local, np.int64)
        return lost

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
        for msg_bytes, lost in self._lost_nodes.items():
            self.messages_received -= lost
            self.bytes_received -= lost * msg_bytes
            lost[:] = 0

    def _active_slices(self, active: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        if active is None:
            return self._real_out, self._real_in
        act = np.asarray(active, bool)
        if act.shape != (self.n_edges,):
            raise ExchangeError(f"active must be a mask over the {self.n_edges} directed edges, got {act.shape}")
        return act[self.out_edges] & self._real_out, act[self.in_edges] & self._real_in

    def _finish_round(
        self,
        values_in: np.ndarray,
        act_out: np.ndarray,
        act_in: np.ndarray,
        tail: tuple[int, ...],
        msg_bytes: int,
        owned: bool = False,
    ) -> Inbox:
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

    def _inbox(
        self, values_in: np.ndarray, delivered: np.ndarray, tail: tuple[int, ...], *, owned: bool = False
    ) -> Inbox:
        if not delivered.all():
            if owned:  # a fresh array of this round: zero the undelivered rows in place
                values_in[~delivered] = 0.0
            else:
                values_in = np.where(delivered[:, None], values_in, 0.0)
        return Inbox(
            values=values_in.reshape((values_in.shape[0], *tail)),
            delivered=delivered,
            dst=self.in_dst,
            src=self.in_src,
            edges=self.in_edges,
            n_local=self.n_local,
        )

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
        return self._finish_round(gathered, act_out, act_in, tail, flat.shape[1] * flat.itemsize, owned=True)

    def send(
        self, edge_values: np.ndarray, *, active: np.ndarray | None = None, message_bytes: np.ndarray | None = None
    ) -> Inbox:
        """Send one value per outgoing edge (rows in :attr:`out_edges` order); receive one per incoming edge.

        ``message_bytes`` (one integer per outgoing edge): the bytes each message really carries when the rows are
        a fixed-width container of variable-length content (a relay of observation records); they are counted
        instead of the row width. The sizes travel with the rows, so every backend counts the same bytes.
        """
        x = np.asarray(edge_values)
        if x.ndim == 0 or x.shape[0] != self.out_edges.size:
            raise ExchangeError(
                f"send needs one row per outgoing edge ({self.out_edges.size}), got array of shape {x.shape}"
            )
        flat, tail = _flat(x)
        act_out, act_in = self._active_slices(active)
        if message_bytes is not None:
            return self._send_sized(flat, tail, active, act_out, act_in, message_bytes)
        moved = self._move_edges(flat, active)
        return self._finish_round(
            moved, act_out, act_in, tail, flat.shape[1] * flat.itemsize, owned=not np.may_share_memory(moved, x)
        )

    def _send_sized(
        self,
        flat: np.ndarray,
        tail: tuple[int, ...],
        active: np.ndarray | None,
        act_out: np.ndarray,
        act_in: np.ndarray,
        message_bytes: np.ndarray,
    ) -> Inbox:
        """:meth:`send` with per-message byte counts: the size rides in an extra float64 column (exact for any
        count below 2⁵³); the round is counted with zero bytes, then each sent and delivered message's size added."""
        sizes = np.asarray(message_bytes)
        if sizes.shape != (self.out_edges.size,) or not np.issubdtype(sizes.dtype, np.integer) or (sizes < 0).any():
            raise ExchangeError(
                f"message_bytes must be one non-negative integer per outgoing edge ({self.out_edges.size}), "
                f"got {sizes.dtype} array of shape {sizes.shape}"
            )
        wide = np.concatenate([flat.astype(float), sizes.astype(float)[:, None]], axis=1)
        moved = self._move_edges(wide, active)
        inbox = self._finish_round(moved, act_out, act_in, (wide.shape[1],), 0, owned=True)
        sent = np.where(act_out, sizes, 0)
        if self.faults.silent_nodes:
            sent = np.where(self.faults.silent_mask(self.round_index - 1, self.nodes)[self.out_src], 0, sent)
        got = np.where(inbox.delivered, np.rint(inbox.values[:, -1]), 0.0).astype(np.int64)
        self.bytes_sent += np.bincount(self.out_src, weights=sent, minlength=self.n_local).astype(np.int64)
        self.bytes_received += np.bincount(self.in_dst, weights=got, minlength=self.n_local).astype(np.int64)
        self._round_bytes[-1] += int(sent.sum())
        values = inbox.values[:, :-1].astype(flat.dtype, copy=False).reshape((inbox.values.shape[0], *tail))
        return Inbox(values, inbox.delivered, inbox.dst, inbox.src, inbox.edges, inbox.n_local)

    def node_columns(self, node_values: np.ndarray) -> np.ndarray:
        """This block's node values followed by the values of the remote senders it reads (its halo), moved as a
        round moves them but **not counted**: for values a counted round has already delivered (read again instead
        of kept) and set-up values a family documents as uncounted. Algorithms use it, not the transport itself."""
        return self._columns(node_values, None)

    def part_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions of the in-edges and nodes in the arrays of :attr:`part` (exchanges built from a part)."""
        raise ExchangeError(f"the {self.backend} exchange is not built from a graph part")

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

    def local_totals(self) -> tuple[int, int]:
        """This block's own messages and bytes sent so far (its nodes' counters; no message moves): a mark that a
        family sums over the blocks once, at its end, where :meth:`comm_totals` at every mark would gather each
        node's counters and the per-round totals over the network each time (real traffic in the field)."""
        self._flush()
        return int(self.messages_sent.sum()), int(self.bytes_sent.sum())

    def reset_accounting(self) -> None:
        """Zero the counters and the round index (the fault schedule restarts at round 0)."""
        self.round_index = 0
        self._round_messages.clear()
        self._round_bytes.clear()
        self._init_accounting()
