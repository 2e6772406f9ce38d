"""MPI exchange: each rank holds a block of nodes; one round = one neighbour collective on numpy buffers.

Launch with ``mpiexec -n N python -m mpi4py -m distnav ... --backend mpi`` (``-m mpi4py`` makes an exception on
one rank abort the whole job instead of deadlocking the others).

Partition (``partition=``): ``"rcm"`` (default), ``"block"``, ``"node"``, an owner array or a partition file — see
:func:`distnav.network.partition.partition_nodes` (re-exported here under its old name).

Every rank builds the same global graph (deterministic from the seed), or only its own part of it (a
:class:`~distnav.network.graph_part.GraphPart`, with the partition given as a file or an owner array), and derives,
without any negotiation, which boundary node values it sends to and receives from each neighbour rank. Messages
between nodes of the same rank never touch MPI; messages on cut edges travel in one ``Neighbor_alltoallv`` per
round over a distributed-graph communicator whose neighbours are the ranks that share cut edges. Accounting and
seeded faults are computed on global edge ids exactly as in-process, so a run with drops gives the same numbers on
both backends.
"""

from __future__ import annotations

import os
from typing import Any, cast

import numpy as np

from distnav._optional import require
from distnav.errors import ExchangeError
from distnav.exchange.base import Exchange
from distnav.exchange.core import ReduceOp, Reducible
from distnav.exchange.faults import FaultSchedule
from distnav.network.graph import Graph
from distnav.network.graph_part import GraphPart, incoming_positions
from distnav.network.partition import NodeRanges, locality_order, owner_map, partition_nodes

PartitionSpec = str | np.ndarray | NodeRanges | os.PathLike[str]

__all__ = ["MPIExchange", "partition_nodes", "world_rank", "world_size"]


def _mpi() -> Any:
    return require("mpi4py.MPI", "mpi")


def _part_order(part: GraphPart, order: str | np.ndarray) -> np.ndarray | None:
    """Local order of a part's nodes (positions in ``part.nodes``): reverse Cuthill–McKee of the links among them
    (``"auto"`` from :data:`~distnav.network.partition.LOCALITY_MIN_NODES` owned nodes on), or none."""
    from distnav.network.partition import LOCALITY_MIN_NODES

    if not isinstance(order, str) or order not in ("auto", "rcm", "none"):
        raise ExchangeError(f"a graph part takes order 'auto', 'rcm' or 'none', got {order!r}")
    if order == "none" or (order == "auto" and part.n_local < LOCALITY_MIN_NODES):
        return None
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    k, inner = part.owned_positions(part.src)
    # the links among owned nodes in CSR directly: the part's rows, the owned senders (ascending within a row)
    ptr = np.zeros(inner.size + 1, np.int64)
    np.cumsum(inner, out=ptr[1:])
    ptr = ptr[part.in_ptr]
    idx = np.int32 if max(part.n_local, int(ptr[-1])) < 2**31 - 1 else np.int64
    cols = k[inner].astype(idx)
    del k, inner
    adj = sp.csr_matrix((np.ones(cols.size), cols, ptr.astype(idx)), shape=(part.n_local, part.n_local))
    return np.asarray(reverse_cuthill_mckee(adj, symmetric_mode=True), dtype=np.int64)


def _order_of_distinct(ids: np.ndarray) -> np.ndarray:
    """The order that sorts distinct integer ids: one scatter over their span when it is at most twice their count
    (a range part's out-edge ids: its own in-edges and its halo's, a few id ranges), else a sort (distinct ids: any
    sort gives this order; quicksort is 2× faster than a stable one)."""
    if ids.size == 0:
        return np.zeros(0, np.int64)
    lo = int(ids.min())
    span = int(ids.max()) - lo + 1
    if span > 2 * ids.size:
        return np.asarray(np.argsort(ids))
    idx = np.int32 if ids.size < 2**31 - 1 else np.int64
    slot: np.ndarray = np.full(span, -1, idx)
    slot[ids - lo] = np.arange(ids.size, dtype=idx)
    return slot[slot >= 0]


def _out_edge_tables(
    part: GraphPart, local_of_part: np.ndarray | None, idx: type[np.signedinteger[Any]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The block's out-edges — the reverse of every in-edge of the part — in global edge order: their ids, local
    senders and receivers' global ids (``local_of_part``: the local index of each part position; None: the same)."""
    recv = np.repeat(np.arange(part.n_local, dtype=idx), np.diff(part.in_ptr))
    by_id = _order_of_distinct(part.out_edge_ids)
    out_src = recv[by_id] if local_of_part is None else local_of_part[recv[by_id]]
    del recv
    return part.out_edge_ids[by_id], out_src, part.src[by_id]


def world_rank() -> int:
    return int(_mpi().COMM_WORLD.Get_rank())


def world_size() -> int:
    return int(_mpi().COMM_WORLD.Get_size())


class MPIExchange(Exchange):
    """This rank's block of the network; see the module docstring."""

    backend = "mpi"
    _out_reverses_in = True  # the out-edges are the reverses of the part's in-edges (_out_edge_tables)
    owner: np.ndarray | NodeRanges
    """Owner rank of every node: an array, or node ranges (an exchange built from a part with ``"block"``)."""

    def __init__(
        self,
        graph: Graph | GraphPart,
        faults: FaultSchedule | None = None,
        *,
        comm: Any = None,
        partition: PartitionSpec | None = None,
        order: str | np.ndarray = "auto",
        persistent: bool = True,
    ) -> None:
        super().__init__(graph, faults)
        MPI = _mpi()
        self._MPI = MPI
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.rank = int(self.comm.Get_rank())
        self.size = int(self.comm.Get_size())
        if isinstance(graph, GraphPart):  # this rank's part only: the partition must be given, not computed
            part, perm = self._own_part(graph, partition, order)
        else:
            owner = partition_nodes(graph, self.size, "rcm" if partition is None else partition)
            self.owner = owner
            part = GraphPart.from_graph(graph, np.flatnonzero(owner == self.rank))
            full = locality_order(graph, order)  # the shared locality order (as in-process) restricted to the rank
            perm = None if full is None else np.searchsorted(part.nodes, full[owner[full] == self.rank])
        self._setup_from_part(part, perm, persistent)

    def _own_part(
        self,
        part: GraphPart,
        partition: str | np.ndarray | NodeRanges | os.PathLike[str] | None,
        order: str | np.ndarray,
    ) -> tuple[GraphPart, np.ndarray | None]:
        """Check a rank's graph part against the partition; its local order. ``"block"`` and node ranges are held
        as ``ranks + 1`` bounds (:class:`~distnav.network.partition.NodeRanges`): nothing over the whole network."""
        if partition is None or (isinstance(partition, str) and partition == "rcm"):
            raise ExchangeError(
                "an exchange on a graph part needs the partition the parts were built from "
                "(node ranges, 'block', an owner array or a partition file): 'rcm' needs the whole graph"
            )
        owner = self.owner = owner_map(part, self.size, partition)
        me = self.rank
        if isinstance(owner, NodeRanges):
            lo, hi = int(owner.bounds[me]), int(owner.bounds[me + 1])
            same = part.n_local == hi - lo and (part.n_local == 0 or (part.nodes[0] == lo and part.nodes[-1] == hi - 1))
            expected = hi - lo
        else:
            same = np.array_equal(part.nodes, np.flatnonzero(owner == me))
            expected = int(np.count_nonzero(owner == me))
        if not same:
            raise ExchangeError(
                f"rank {me}: the graph part holds other nodes than the partition gives this "
                f"rank ({part.n_local} nodes in the part, {expected} in the partition)"
            )
        # a locality order of the part's own links (results do not depend on it: every row sums its terms in
        # global sender order)
        return part, _part_order(part, order)

    def _owner_of(self, ids: np.ndarray) -> np.ndarray:
        """Owner rank of each id, int32 (per-edge lookups: half the bytes)."""
        return np.asarray(self.owner[ids]).astype(np.int32, copy=False)

    def _setup_from_part(self, part: GraphPart, perm: np.ndarray | None, persistent: bool) -> None:
        """Every index array of the block from its part: no array over the whole graph's edges."""
        # edge-sized index arrays in 32 bits where every index fits (as in-process); global ids stay 64-bit
        idx = np.int32 if max(self.n_nodes, self.n_edges) < 2**31 - 1 else np.int64
        local_of_part = self._local_edges(part, perm, idx)
        own_in_src = self._owner_of(self.in_src)
        me = self.rank
        # every link is stored both ways: the ranks this block sends to are those it receives from, and what it
        # sends to rank r leaves the receivers of its in-edges from r (the out-edge tables are not read)
        cut_in_rows = np.flatnonzero(own_in_src != me)
        cut_in_rows = cut_in_rows[np.argsort(self.in_edges[cut_in_rows], kind="stable")]  # global edge order
        self.neighbour_ranks = np.unique(own_in_src[cut_in_rows]).astype(np.int64)
        recv_rows = [cut_in_rows[own_in_src[cut_in_rows] == r] for r in self.neighbour_ranks]
        del cut_in_rows
        self._node_halo(part, local_of_part, recv_rows, own_in_src == me, idx)
        del own_in_src
        self._edge_transport(recv_rows, idx)
        self._layouts: dict[tuple[int, int, int], Any] = {}
        self._column_buffers: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, Any]] = {}
        self._edge_buffers: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, Any]] = {}
        self._requests: list[Any] = []
        nbr = self.neighbour_ranks.tolist()
        self.dist_comm = self.comm.Create_dist_graph_adjacent(sources=nbr, destinations=nbr, reorder=False)
        self.persistent = bool(persistent and hasattr(self.dist_comm, "Neighbor_alltoallv_init"))
        self._init_accounting()
        if np.array_equal(self._all_sent, self._all_recv):  # every link both ways: one array of both counts
            self._all_recv = self._all_sent
        self.release_out_edges()  # (a part's: made again when read)

    def _local_edges(self, part: GraphPart, perm: np.ndarray | None, idx: type[np.signedinteger[Any]]) -> np.ndarray:
        """The block's nodes in local order and its in- and out-edges; returns part position → local index.
        ``perm[k]`` is the position in ``part.nodes`` of local node k (None: the part's order)."""
        n_local = part.n_local
        rows = np.arange(n_local, dtype=np.int64) if perm is None else np.asarray(perm, np.int64)
        local_of_part = np.empty(n_local, idx)
        local_of_part[rows] = np.arange(n_local, dtype=idx)
        # the part's own order (no locality order): the in-edge arrays are the part's, shared, not copied
        pos_in = None if perm is None else incoming_positions(part.in_ptr, rows)  # grouped by local receiver
        self.nodes = part.nodes if perm is None else part.nodes[rows]
        if self.part is not None:  # where the part's weights sit (PartWeights); not needed with the whole graph
            self._in_part_pos = None if pos_in is None else pos_in.astype(idx)  # None: the identity (part_rows)
            self._node_part_pos = None if perm is None else rows  # None: the identity (part_rows)
        # global ids in the part's dtype (int32 where every id fits, as the part holds them): indices and
        # comparisons only
        self.in_edges = part.edge_ids if pos_in is None else part.edge_ids[pos_in]
        self.in_src = part.src if pos_in is None else part.src[pos_in]
        self.in_dst = np.repeat(np.arange(n_local, dtype=idx), np.diff(part.in_ptr)[rows])
        # the out-edge tables: made when read from a part (_out_edges_made); kept from the whole graph
        self._out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if self.part is None:
            self._out = _out_edge_tables(part, None if perm is None else local_of_part, idx)
        return local_of_part

    def _node_halo(
        self,
        part: GraphPart,
        local_of_part: np.ndarray,
        recv_rows: list[np.ndarray],
        sender_is_mine: np.ndarray,
        idx: type[np.signedinteger[Any]],
    ) -> None:
        """For each neighbour rank, the sorted boundary nodes sent to / received from it, and the column of every
        in-edge's sender: ``[local nodes in local order | halo as received]``, the halo in one contiguous slice.
        Each row of the mixer's product still sums its terms in global sender order (Mixer), so results agree
        bitwise with in-process whatever the column numbering."""

        def local_index(glob: np.ndarray) -> np.ndarray:  # owned global ids → local index
            return np.asarray(local_of_part[part.owned_positions(glob)[0]])

        has_nbr = bool(self.neighbour_ranks.size)
        send_nodes = [np.unique(self.nodes[self.in_dst[rr]]) for rr in recv_rows]  # (links both ways)
        recv_nodes = [np.unique(self.in_src[rr]) for rr in recv_rows]
        self._send_node_idx = local_index(np.concatenate(send_nodes)) if has_nbr else np.zeros(0, np.int64)
        self._node_send_counts = np.array([s.size for s in send_nodes], dtype=np.int64)
        self._node_recv_counts = np.array([s.size for s in recv_nodes], dtype=np.int64)
        halo = np.concatenate(recv_nodes) if has_nbr else np.zeros(0, np.int64)
        self.n_halo = int(halo.size)
        self.n_columns = self.n_local + self.n_halo
        self.local_col = np.arange(self.n_local, dtype=idx)
        col = np.empty(self.in_src.size, idx)
        col[sender_is_mine] = local_index(self.in_src[sender_is_mine])
        if self.n_halo:
            halo_order = np.argsort(halo, kind="stable")
            foreign = ~sender_is_mine
            col[foreign] = self.n_local + halo_order[np.searchsorted(halo[halo_order], self.in_src[foreign])]
        self.in_src_col = col

    def _edge_transport(self, recv_rows: list[np.ndarray], idx: type[np.signedinteger[Any]]) -> None:
        """Edge messages: per neighbour rank the cut edges in global edge order on both sides — the received ones
        now, the sent ones (rows of the out-edge tables) at the first edge send (:meth:`_edge_sends`), with the rows
        moved inside the block (:meth:`_local_moves`): a job that sends only node values (consensus, aggregated
        ADMM) never makes them."""
        self._local_move_rows: tuple[np.ndarray, np.ndarray] | None = None
        self._edge_send: tuple[np.ndarray, np.ndarray] | None = None
        has_nbr = bool(self.neighbour_ranks.size)
        self._edge_recv_pos: np.ndarray = (np.concatenate(recv_rows) if has_nbr else np.zeros(0, np.int64)).astype(idx)
        self._edge_recv_counts = np.array([e.size for e in recv_rows], dtype=np.int64)

    def _edge_sends(self) -> tuple[np.ndarray, np.ndarray]:
        """The out-edge rows of the cut edges per neighbour rank, in global edge order, and their counts (made at
        the first edge send and kept)."""
        if self._edge_send is None:
            own_out_dst = self._owner_of(self.out_dst)
            cut_out_rows = np.flatnonzero(own_out_dst != self.rank)  # out rows, global edge order
            send_rows = [cut_out_rows[own_out_dst[cut_out_rows] == r] for r in self.neighbour_ranks]
            pos = np.concatenate(send_rows) if send_rows else np.zeros(0, np.int64)
            counts = np.array([e.size for e in send_rows], dtype=np.int64)
            self._edge_send = (pos.astype(self.in_dst.dtype), counts)
        return self._edge_send

    def _real_edges(self) -> tuple[np.ndarray, np.ndarray]:
        # an out-edge is a self-loop exactly when the in-edge it reverses is: without one among the in-edges there
        # is none among the out-edges (their tables are not read)
        real_in = self.in_src != self.nodes[self.in_dst]
        if bool(real_in.all()):
            return np.broadcast_to(np.True_, (self.in_edges.size,)), real_in
        return super()._real_edges()

    def part_rows(self) -> tuple[np.ndarray, np.ndarray]:
        if self.part is None:
            return super().part_rows()
        # the part's own order: the identities, made when asked (not held)
        nodes = np.arange(self.n_local, dtype=np.int64) if self._node_part_pos is None else self._node_part_pos
        if self._in_part_pos is None:
            n_in = self.in_edges.size
            return np.arange(n_in, dtype=np.int32 if n_in < 2**31 - 1 else np.int64), nodes
        return self._in_part_pos, nodes

    # the out-edge tables (``out_edges``, ``out_src``, ``out_dst``: three edge-sized arrays) of an exchange built from
    # a part are made from the part when read and kept until :meth:`release_out_edges`; the set-up lets them go
    # (consensus rounds and the aggregated ADMM iterations never read them)
    def _out_edges_made(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._out is None:
            rows = self._node_part_pos
            local_of_part = None
            if rows is not None:
                local_of_part = np.empty(rows.size, self.in_dst.dtype)
                local_of_part[rows] = np.arange(rows.size, dtype=self.in_dst.dtype)
            assert self.part is not None  # (released only on a part)
            self._out = _out_edge_tables(self.part, local_of_part, self.in_dst.dtype.type)
        return self._out

    @property
    def out_edges(self) -> np.ndarray:  # type: ignore[override]
        return self._out_edges_made()[0]

    @property
    def out_src(self) -> np.ndarray:  # type: ignore[override]
        return self._out_edges_made()[1]

    @property
    def out_dst(self) -> np.ndarray:  # type: ignore[override]
        return self._out_edges_made()[2]

    def release_out_edges(self) -> None:
        """Let go of the out-edge tables (made again from the part when next read): on an exchange built from a
        graph part; a no-op on one built from the whole graph (nothing to make them from)."""
        if self.part is not None:
            self._out = None

    def _local_moves(self) -> tuple[np.ndarray, np.ndarray]:
        """The in-edge rows and out-edge rows of the messages that stay in the block (receiver owned here), made
        at the first edge send and kept: an out-edge's message arrives on the in-edge with its id."""
        if self._local_move_rows is None:
            idx = self.in_dst.dtype.type
            local_out_rows = np.flatnonzero(self._owner_of(self.out_dst) == self.rank)
            ids = self.in_edges
            in_by_id = _order_of_distinct(ids)  # a range part's ids: one scatter, no sort
            local_in = in_by_id[np.searchsorted(ids[in_by_id], self.out_edges[local_out_rows])]
            del in_by_id
            self._local_move_rows = (local_in.astype(idx), local_out_rows.astype(idx))
        return self._local_move_rows

    # ------------------------------------------------------------- transport
    @staticmethod
    def _displs(counts: np.ndarray) -> np.ndarray:
        d = np.zeros(counts.size, dtype=np.int64)
        if counts.size > 1:
            np.cumsum(counts[:-1], out=d[1:])
        return d

    def _alltoallv(
        self, send: np.ndarray, send_counts: np.ndarray, recv_counts: np.ndarray, width: int, dtype: np.dtype
    ) -> np.ndarray:
        recv = np.empty((int(recv_counts.sum()), width), dtype=dtype)
        if self.neighbour_ranks.size == 0:
            return recv
        send = np.ascontiguousarray(send, dtype=dtype)
        key = (id(send_counts), id(recv_counts), width)
        layout = self._layouts.get(key)
        if layout is None:  # counts and displacements per payload width, computed once
            sc, rc = send_counts * width, recv_counts * width
            layout = self._layouts[key] = (
                (sc.tolist(), self._displs(sc).tolist()),
                (rc.tolist(), self._displs(rc).tolist()),
            )
        self.dist_comm.Neighbor_alltoallv([send, layout[0]], [recv, layout[1]])
        return recv

    def _persistent_request(
        self, send: np.ndarray, send_counts: np.ndarray, recv: np.ndarray, recv_counts: np.ndarray
    ) -> Any:
        """A persistent ``Neighbor_alltoallv`` on fixed buffers (MPI-4), or None where the library lacks it."""
        if not self.persistent:
            return None
        width = send.shape[1] if send.ndim == 2 else recv.shape[1]
        sc, rc = send_counts * width, recv_counts * width
        req = self.dist_comm.Neighbor_alltoallv_init(
            [send, (sc.tolist(), self._displs(sc).tolist())], [recv, (rc.tolist(), self._displs(rc).tolist())]
        )
        self._requests.append(req)
        return req

    def _columns(self, flat_local: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        """Local values (local order) followed by the halo (per neighbour rank, ascending global ids).

        The halo arrives straight into the tail of a preallocated column buffer through a persistent neighbour
        collective started once per round; the local values are copied while it is in flight. The returned array
        is that buffer, reused by the next round (callers consume it within the round)."""
        if self.n_halo == 0:
            return flat_local
        cols, req = self._start_halo(flat_local)
        cols[: self.n_local] = flat_local
        if req is not None:
            req.Wait()
        return cols

    def halo(self, flat_local: np.ndarray) -> np.ndarray:
        """The transport alone: the values of the remote senders this block needs, ``(n_halo, width)`` (a view of
        the reused column buffer)."""
        if self.n_halo == 0:
            return flat_local[:0]
        cols, req = self._start_halo(flat_local)
        if req is not None:
            req.Wait()
        return cols[self.n_local :]

    def _start_halo(self, flat_local: np.ndarray) -> tuple[np.ndarray, Any]:
        """Send this block's boundary values and start receiving the halo into the column buffer's tail; returns
        the buffer and the request to wait for (None when the plain collective has already completed)."""
        width = flat_local.shape[1]
        key = (width, flat_local.dtype.str)
        bufs = self._column_buffers.get(key)
        if bufs is None:
            send = np.empty((self._send_node_idx.size, width), dtype=flat_local.dtype)
            cols = np.empty((self.n_columns, width), dtype=flat_local.dtype)
            req = self._persistent_request(send, self._node_send_counts, cols[self.n_local :], self._node_recv_counts)
            bufs = self._column_buffers[key] = (send, cols, req)
        send, cols, req = bufs
        np.take(flat_local, self._send_node_idx, axis=0, out=send)
        if req is not None:
            req.Start()
            return cols, req
        cols[self.n_local :] = self._alltoallv(
            send, self._node_send_counts, self._node_recv_counts, width, flat_local.dtype
        )
        return cols, None

    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        width = flat_out.shape[1]
        out = np.zeros((self.in_edges.size, width), dtype=flat_out.dtype)
        key = (width, flat_out.dtype.str)
        bufs = self._edge_buffers.get(key)
        send_pos, send_counts = self._edge_sends()
        if bufs is None and self.neighbour_ranks.size:
            send = np.empty((send_pos.size, width), dtype=flat_out.dtype)
            recv = np.empty((self._edge_recv_pos.size, width), dtype=flat_out.dtype)
            req = self._persistent_request(send, send_counts, recv, self._edge_recv_counts)
            bufs = self._edge_buffers[key] = (send, recv, req)
        if bufs is not None and bufs[2] is not None:
            send, recv, req = bufs
            np.take(flat_out, send_pos, axis=0, out=send)
            req.Start()
            local_in, local_out = self._local_moves()
            out[local_in] = flat_out[local_out]
            req.Wait()
            out[self._edge_recv_pos] = recv
            return out
        local_in, local_out = self._local_moves()
        out[local_in] = flat_out[local_out]
        recv = self._alltoallv(flat_out[send_pos], send_counts, self._edge_recv_counts, width, flat_out.dtype)
        out[self._edge_recv_pos] = recv
        return out

    def free(self) -> None:
        """Release the persistent requests (also done at exit by MPI); the exchange stays usable."""
        for req in self._requests:
            if req:
                req.Free()
        self._requests.clear()
        self._column_buffers.clear()
        self._edge_buffers.clear()

    # ------------------------------------------------------------- global operations
    def allreduce(self, value: Reducible, op: ReduceOp = "sum") -> Reducible:
        MPI = self._MPI
        mpi_op = {"sum": MPI.SUM, "max": MPI.MAX, "min": MPI.MIN}[op]
        if isinstance(value, np.ndarray):
            if value.size == 0:
                return value
            out = np.empty_like(value)
            self.comm.Allreduce(np.ascontiguousarray(value), out, op=mpi_op)
            return cast(Reducible, out)
        return cast(Reducible, self.comm.allreduce(value, op=mpi_op))

    def gather_nodes(self, local: np.ndarray) -> np.ndarray:
        arr = np.asarray(local)
        if arr.shape[0] != self.n_local:
            raise ExchangeError(f"gather_nodes needs {self.n_local} local rows, got shape {arr.shape}")
        parts = self.comm.allgather((self.nodes, arr))
        out = np.empty((self.n_nodes, *arr.shape[1:]), dtype=arr.dtype)
        for nodes, values in parts:
            out[nodes] = values
        return out

    def barrier(self) -> None:
        self.comm.Barrier()

    @property
    def is_root(self) -> bool:
        return self.rank == 0

    @property
    def n_cut_edges(self) -> int:
        """Directed edges leaving this rank's block."""
        return int(self._edge_recv_pos.size)  # (every link both ways: as many leave as arrive)
