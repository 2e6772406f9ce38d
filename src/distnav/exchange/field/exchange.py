"""The field exchange: one node per OS process, message rounds over ZeroMQ (:mod:`.transport`) in lock-step.

:class:`FieldExchange` is the third backend of :class:`~distnav.exchange.base.Exchange` beside in-process and MPI,
and the algorithms run on it unchanged. Its block is one node; its columns are ``[own value | each neighbour's value,
neighbours ascending]``, and the consensus round is the same CSR product as in-process (each row's terms summed in
global sender order, :class:`~distnav.exchange.mixer.Mixer`), so a run in which every message arrives is bitwise
equal to the in-process run.

A message that misses a step's deadline is *lost*: the in-edge shows ``delivered = False`` in an
:class:`~distnav.exchange.base.Inbox`, in a :class:`~distnav.exchange.route.Route` round, and in a consensus round
its weight moves to the receiver's self-weight (as for a dropped message in-process). A seeded
:class:`~distnav.exchange.faults.FaultSchedule` drops the same messages as in-process (decided by the receiver).

Global operations (:meth:`allreduce`, :meth:`gather_nodes`, :meth:`barrier`) are implemented honestly over the
network: when every other node is a peer of the transport (threads of one test, the demo's UWB nodes), each node
sends its contribution to every other node (``n − 1`` messages per node per call); when the transport knows only the
neighbours, and always for a field node run from a description (``direct=False``: every node must choose alike, and
a node that neighbours every other one cannot tell the two cases apart), the contributions travel up and down a
spanning tree of the network's own links (:mod:`.tree`, ``2 (n − 1)`` messages per call). Both forms give every
node every contribution and reduce them in node-id order, so they agree bit for bit; the messages are counted in the
wire bytes. Node code that should scale avoids global operations.
"""

from __future__ import annotations

import functools
from functools import cached_property
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from distnav._sparse import csr_times
from distnav.errors import ExchangeError
from distnav.exchange.base import Exchange
from distnav.exchange.core import ExchangeCore, ReduceOp, Reducible
from distnav.exchange.faults import FaultPlan, FaultSchedule
from distnav.exchange.field.transport import StepTransport
from distnav.exchange.field.tree import SpanningTree, tree_all
from distnav.exchange.field.wire import Kind
from distnav.exchange.mixer import Mixer
from distnav.exchange.route import Route
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart

if TYPE_CHECKING:
    import scipy.sparse as sp

    from distnav.network.weights import ConsensusWeights, PartWeights

__all__ = ["FieldExchange"]

_REDUCERS = {"sum": np.add, "max": np.maximum, "min": np.minimum}


class FieldExchange(Exchange):
    """Node ``node``'s view of the network, talking through ``transport`` (see the module docstring)."""

    backend = "field"

    def __init__(
        self,
        graph: Graph,
        node: int,
        transport: StepTransport,
        faults: FaultSchedule | None = None,
        *,
        direct: bool | None = None,
    ) -> None:
        super().__init__(graph, faults)
        self._direct = direct
        me = int(node)
        if not 0 <= me < graph.n_nodes:
            raise ExchangeError(f"node {me} is not in the graph (0..{graph.n_nodes - 1})")
        self.me = me
        self.transport = transport
        self.nodes = np.array([me], np.int64)
        e = np.arange(graph.in_ptr[me], graph.in_ptr[me + 1], dtype=np.int64)
        self.in_edges = e
        self.in_src = graph.src[e].astype(np.int64)
        self.in_dst = np.zeros(e.size, np.int64)
        self.out_edges = np.sort(graph.reverse_edge[e]).astype(np.int64)
        self.out_src = np.zeros(self.out_edges.size, np.int64)
        self.out_dst = graph.dst[self.out_edges].astype(np.int64)
        others = self.in_src != me
        self.neighbours = np.unique(self.in_src[others])
        missing = sorted(set(self.neighbours.tolist()) - set(transport.peers))
        if missing:
            raise ExchangeError(f"node {me}: the transport has no address for neighbours {missing}")
        col = np.zeros(e.size, np.int64)
        col[others] = 1 + np.searchsorted(self.neighbours, self.in_src[others])
        self.in_src_col = col
        self.local_col = np.zeros(1, np.int64)
        self.n_columns = 1 + int(self.neighbours.size)
        self._self_in = np.flatnonzero(~others)
        self._self_out = np.flatnonzero(self.out_dst == me)
        self._init_accounting()
        self.step = 0
        self._no_loss = np.zeros(e.size, bool)
        self._no_loss.setflags(write=False)
        self._lost_in = self._no_loss
        others_idx = np.flatnonzero(others)
        self._in_edge_of = {int(self.in_src[k]): int(k) for k in others_idx}
        self._column_of = {int(self.in_src[k]): int(col[k]) for k in others_idx}
        self._peer_cache: dict[int | None, tuple[list[int], list[int], np.ndarray, np.ndarray | None]] = {}

    # ------------------------------------------------------------- transport
    def _next_step(self) -> int:
        step = self.step
        self.step += 1
        return step

    def _received_rows(
        self, got: dict[int, np.ndarray], shape: tuple[int, ...], dtype: np.dtype | None
    ) -> dict[int, np.ndarray]:
        """The arrays of ``got`` that have the expected shape and dtype (any dtype: None); others refused as
        malformed."""
        ok: dict[int, np.ndarray] = {}
        for s, arr in got.items():
            if arr.shape != shape or (dtype is not None and arr.dtype != dtype):
                self.transport._refuse(
                    "malformed", f"node {s} sent {arr.dtype}{arr.shape}, expected {dtype}{shape} at step {self.step}"
                )
                continue
            ok[s] = arr
        return ok

    def _peers_of(self, active: np.ndarray | None) -> tuple[list[int], list[int], np.ndarray]:
        """(receivers of this block's active out-edges, senders of its active in-edges, the in-edge mask), cached
        per mask (a run uses a handful: all edges, a session, ADMM's pair edges)."""
        key = None if active is None else id(active)
        hit = self._peer_cache.get(key)
        if hit is None or (active is not None and hit[3] is not active):
            act_out, act_in = self._active_slices(active)
            targets = np.unique(self.out_dst[act_out]).tolist()
            senders = np.unique(self.in_src[act_in]).tolist()
            hit = (targets, senders, act_in, active)
            self._peer_cache[key] = hit  # the mask is kept alive with its entry, so its id stays unique
        return hit[0], hit[1], hit[2]

    def _lost_mask(self, act_in: np.ndarray, got: dict[int, np.ndarray]) -> np.ndarray:
        if len(got) == len(self._in_edge_of):
            return self._no_loss
        arrived = np.zeros(self.in_edges.size, bool)
        arrived[[self._in_edge_of[s] for s in got]] = True
        return act_in & ~arrived

    def _columns(self, flat_local: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        targets, senders, act_in = self._peers_of(active)
        step = self._next_step()
        row = np.ascontiguousarray(flat_local[0])
        self.transport.post_many(targets, Kind.COLUMN, step, row)
        got = self._received_rows(self.transport.collect(Kind.COLUMN, step, senders, like=row), row.shape, row.dtype)
        cols = np.zeros((self.n_columns, row.size), dtype=flat_local.dtype)
        cols[0] = row
        for s, arr in got.items():
            cols[self._column_of[s]] = arr
        self._lost_in = self._lost_mask(act_in, got)
        return cols

    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        act_out, act_in = self._active_slices(active)
        step = self._next_step()
        for r in np.flatnonzero(act_out).tolist():
            self.transport.post(int(self.out_dst[r]), Kind.EDGE, step, flat_out[r])
        senders = np.unique(self.in_src[act_in])
        width = flat_out.shape[1]
        like = flat_out[0] if len(flat_out) else None
        arrived = self.transport.collect(Kind.EDGE, step, senders, like=like)
        got = self._received_rows(arrived, (width,), flat_out.dtype)
        out = np.zeros((self.in_edges.size, width), dtype=flat_out.dtype)
        if self._self_in.size and self._self_out.size:
            out[self._self_in] = flat_out[self._self_out]
        for s, arr in got.items():
            out[self._in_edge_of[s]] = arr
        self._lost_in = self._lost_mask(act_in, got)
        return out

    def _finish_round(self, values_in, act_out, act_in, tail, msg_bytes, owned=False):  # type: ignore[no-untyped-def]
        lost = self._lost_in & act_in
        # lost on the network: not delivered, counted from the masks (under a schedule the plan already says so)
        if lost.any() and not self.faults.active:
            act_in = act_in & ~lost
            act_out = act_out.copy()
        return super()._finish_round(values_in, act_out, act_in, tail, msg_bytes, owned)

    # ------------------------------------------------------------- prepared rounds
    def mixer(self, weights: ConsensusWeights | PartWeights, *, active: np.ndarray | None = None) -> Mixer:
        if weights.graph.n_edges != self.n_edges or weights.graph.n_nodes != self.n_nodes:
            raise ExchangeError("weights are defined on a different graph than this exchange")
        if isinstance(weights.graph, GraphPart):
            raise ExchangeError("the field exchange takes weights on the whole graph")
        return _FieldMixer(self, weights.edge_weight, weights.self_weight, active)

    def route(
        self, active: np.ndarray, *, in_rows: np.ndarray | None = None, out_rows: np.ndarray | None = None
    ) -> Route:
        return _FieldRoute(self, active, in_rows=in_rows, out_rows=out_rows)

    # ------------------------------------------------------------- global operations (over the network)
    def _all_to_all(self, kind: Kind, array: np.ndarray, *, any_number: bool = False) -> dict[int, np.ndarray]:
        """Send ``array`` to every other node and receive theirs (same shape; with ``any_number`` float64 or int64,
        else the same dtype)."""
        step = self._next_step()
        others = [n for n in range(self.n_nodes) if n != self.me]
        if not self._all_peers:  # neighbours only: over the spanning tree
            return tree_all(self.transport, self._tree, self.me, step, array)
        for t in others:
            if t not in self.transport.lost:
                self.transport.post(t, kind, step, array)
        arrived = self.transport.collect(kind, step, others)
        if any_number:
            arrived = {s: a for s, a in arrived.items() if a.dtype.kind in "fi" or self._refuse_number(s, a)}
            got = self._received_rows(arrived, array.shape, None)
        else:
            got = self._received_rows(arrived, array.shape, array.dtype)
        got[self.me] = array
        return got

    @cached_property
    def _all_peers(self) -> bool:
        """Whether global operations go to every node directly instead of over the tree, a choice every node of a
        run must make alike: ``direct`` when given (a node run from a description passes False: a node that
        happens to neighbour every other node still uses the tree, as the others do), else whether every other
        node is a peer (threads or processes given every node's address)."""
        if self._direct is not None:
            return self._direct
        return all(n in self.transport.peers for n in range(self.n_nodes) if n != self.me)

    @cached_property
    def _tree(self) -> SpanningTree:
        return SpanningTree(self.graph)

    def _refuse_number(self, sender: int, arr: np.ndarray) -> bool:
        self.transport._refuse("malformed", f"node {sender} sent {arr.dtype} to a reduction at step {self.step}")
        return False

    def allreduce(self, value: Reducible, op: ReduceOp = "sum") -> Reducible:
        """Every node's contribution to every node, reduced in node-id order (nodes declared lost left out); the
        result has the type every node computes alike (float when any contribution is)."""
        arr = np.asarray(value)
        wire = arr.astype(np.float64) if arr.dtype.kind in "fb" else arr.astype(np.int64)
        got = self._all_to_all(Kind.REDUCE, np.array(wire, order="C"), any_number=True)
        parts = [got[n] for n in sorted(got)]
        dtype = np.result_type(*parts)
        total = functools.reduce(_REDUCERS[op], [p.astype(dtype, copy=False) for p in parts])
        if isinstance(value, np.ndarray):
            return cast(Reducible, total.astype(np.result_type(value.dtype, dtype), copy=False))
        return cast(Reducible, float(total) if dtype.kind == "f" else int(total))

    def gather_nodes(self, local: np.ndarray) -> np.ndarray:
        """Every node's rows on every node, in this node's dtype (as the MPI exchange casts); rows of nodes that did
        not answer hold NaN (integers: -1). Float or integer rows only (bools travel as floats)."""
        arr = np.asarray(local)
        if arr.shape[0] != 1:
            raise ExchangeError(f"gather_nodes needs 1 local row, got shape {arr.shape}")
        wire = arr.astype(np.float64) if arr.dtype.kind in "fb" else arr.astype(np.int64)
        got = self._all_to_all(Kind.GATHER, np.ascontiguousarray(wire), any_number=True)  # cast as MPI's does
        fill = np.nan if arr.dtype.kind == "f" else -1
        out = np.full((self.n_nodes, *arr.shape[1:]), fill, dtype=arr.dtype)
        for n, rows in got.items():
            out[n] = rows[0]
        return out

    def barrier(self) -> None:
        self.allreduce(0.0)

    @property
    def is_root(self) -> bool:
        return self.me == 0

    @cached_property
    def _fault_plan(self) -> FaultPlan:
        """The fault schedule's plan, with the messages lost on the network in this step also not delivered: every
        round under a schedule then runs the in-process code (bitwise as in-process when the network lost nothing)."""
        base = cast(Any, ExchangeCore.__dict__["_fault_plan"]).func(self)  # the core's plan, built as in-process
        return cast(FaultPlan, _NetworkPlan(base, self))

    def start_at(self, step: int) -> None:
        """Continue a running network from ``step`` (a rejoining node, after :func:`.startup.rejoin`): for node code
        with one message round per step (consensus), round ``step`` is the next (the fault schedule follows)."""
        self.step = self.round_index = int(step)

    @property
    def lost_nodes(self) -> dict[int, int]:
        """Peers declared lost and the step at which they were."""
        return dict(self.transport.lost)


class _NetworkPlan:
    """A :class:`FaultPlan` whose ``delivered`` also leaves out this step's messages lost on the network."""

    def __init__(self, plan: FaultPlan, exchange: FieldExchange) -> None:
        self._plan, self._ex = plan, exchange

    def delivered(self, round_index: int) -> np.ndarray:
        return np.asarray(self._plan.delivered(round_index) & ~self._ex._lost_in)

    def __getattr__(self, name: str) -> object:
        return getattr(self._plan, name)


class _FieldMixer(Mixer):
    """The consensus round on the field. Under a fault schedule: the in-process fault round (its plan also drops what
    the network lost). Without one: the fused product when every message arrived (bitwise as in-process); when some
    missed the deadline, their columns are zeroed in this round's fresh column array and their weight is added to
    the self-weight, ``x_i ← Σ_{j delivered} w_ij x_j + (w_ii + Σ_{j lost} w_ij) x_i`` (row sums stay 1)."""

    _fused: sp.csr_matrix | None = None
    _no_edges = np.zeros(0, np.int64)

    def __init__(
        self, exchange: FieldExchange, edge_weight: np.ndarray, self_weight: np.ndarray, active: np.ndarray | None
    ) -> None:
        super().__init__(exchange, edge_weight, self_weight, active)
        self._self_w_global = self_weight

    def apply(self, x_local: np.ndarray) -> np.ndarray:
        ex, x = self.exchange, np.asarray(x_local, dtype=float)
        assert isinstance(ex, FieldExchange)
        if ex.faults.active:
            return super().apply(x)
        if x.shape[0] != 1:
            raise ExchangeError(f"mixer needs 1 local row, got array of shape {x.shape}")
        flat = x.reshape(1, -1)
        cols, msg_bytes = ex._columns(flat, self._active_global), flat.shape[1] * flat.itemsize
        lost_e = self._no_edges if ex._lost_in is ex._no_loss else np.flatnonzero(self._act_in & ex._lost_in)
        if lost_e.size == 0:
            ex._account(self._sent_counts, self._recv_counts, msg_bytes, self._sent_total)
            return csr_times(self._fused_block(), cols.ravel() if x.ndim == 1 else cols).reshape(x.shape)
        lost_dst = ex.in_dst[lost_e]
        ex._account_dropped(self._sent_counts, self._sent_total, self._recv_counts, lost_dst, msg_bytes)
        cols[ex.in_src_col[lost_e]] = 0.0  # a one-node block: one column per neighbour
        moved = np.bincount(lost_dst, weights=self._in_edge_weights()[lost_e], minlength=ex.n_local)
        out: np.ndarray = np.asarray(csr_times(self._fused_block(), cols)) + moved[:, None] * flat
        return out.reshape(x.shape)

    def _fused_block(self) -> sp.csr_matrix:
        if self._w_full is not None:
            return self._w_full
        if self._fused is None:  # the base class holds only the edge part under a fault schedule: the fused block
            ex = self.exchange  # of the same weights, made by the base class with the schedule set aside
            schedule, ex.faults = ex.faults, FaultSchedule()
            try:
                twin = Mixer(ex, self._edge_weight, self._self_w_global, self._active_global)
            finally:
                ex.faults = schedule
            self._fused = twin._w_full
        assert self._fused is not None
        return self._fused


class _FieldRoute(Route):
    """A route whose rounds also show the messages lost on the network."""

    def _count(self, msg_bytes: int) -> np.ndarray:
        ex = self.exchange
        assert isinstance(ex, FieldExchange)
        lost = ex._lost_in & self._act_in
        if ex.faults.active or not lost.any():  # under a schedule the plan includes the network's losses
            return super()._count(msg_bytes)
        ok = self._act_in & ~lost
        ex._account_faulty(self._sent, self._sent_total, ok, msg_bytes)
        return np.asarray(ok[self.in_rows])
