"""MPI exchange: each rank holds a block of nodes; one round = one neighbour collective on numpy buffers.

Launch with ``mpiexec -n N python -m mpi4py -m distnav ... --backend mpi`` (``-m mpi4py`` makes an exception on
one rank abort the whole job instead of deadlocking the others).

Partition (``partition=``): ``"rcm"`` (default), ``"block"``, ``"node"``, an owner array or a partition file — see
:func:`distnav.network.partition.partition_nodes` (re-exported here under its old name).

Every rank builds the same global graph (deterministic from the seed) and derives, without any negotiation,
which boundary node values it sends to and receives from each neighbour rank. Messages between nodes of the same
rank never touch MPI; messages on cut edges travel in one ``Neighbor_alltoallv`` per round over a distributed-graph
communicator whose neighbours are the ranks that share cut edges. Accounting and seeded faults are computed on
global edge ids exactly as in-process, so a run with drops gives the same numbers on both backends.
"""

from __future__ import annotations

import os
from typing import Any, cast

import numpy as np

from distnav._optional import require
from distnav.errors import ExchangeError
from distnav.exchange.base import Exchange, ReduceOp, Reducible, incoming_edges
from distnav.exchange.faults import FaultSchedule
from distnav.network.graph import Graph
from distnav.network.partition import locality_order, partition_nodes

__all__ = ["MPIExchange", "partition_nodes", "world_rank", "world_size"]


def _mpi() -> Any:
    return require("mpi4py.MPI", "mpi")


def world_rank() -> int:
    return int(_mpi().COMM_WORLD.Get_rank())


def world_size() -> int:
    return int(_mpi().COMM_WORLD.Get_size())


class MPIExchange(Exchange):
    """This rank's block of the network; see the module docstring."""

    backend = "mpi"

    def __init__(self, graph: Graph, faults: FaultSchedule | None = None, *, comm: Any = None,
                 partition: str | np.ndarray | os.PathLike[str] = "rcm", order: str | np.ndarray = "auto",
                 persistent: bool = True) -> None:
        super().__init__(graph, faults)
        MPI = _mpi()
        self._MPI = MPI
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.rank = int(self.comm.Get_rank())
        self.size = int(self.comm.Get_size())
        self.owner = partition_nodes(graph, self.size, partition)
        me = self.rank
        src, dst = graph.src, graph.dst
        own_src, own_dst = self.owner[src], self.owner[dst]

        # local order: the shared locality order (the same as in-process) restricted to this rank
        perm = locality_order(graph, order)
        mine = self.owner == me
        self.nodes = (np.flatnonzero(mine) if perm is None else perm[mine[perm]]).astype(np.int64)
        local_index = np.full(graph.n_nodes, -1, dtype=np.int64)
        local_index[self.nodes] = np.arange(self.nodes.size)

        in_sel = incoming_edges(graph, self.nodes)
        out_sel = np.flatnonzero(own_src == me)
        self.in_edges = in_sel
        self.in_dst = local_index[dst[in_sel]]
        self.in_src = src[in_sel]
        self.out_edges = out_sel
        self.out_src = local_index[src[out_sel]]
        self.out_dst = dst[out_sel]

        # neighbour ranks: those sharing cut edges (symmetric: every link is stored both ways)
        cut_out = out_sel[own_dst[out_sel] != me]
        cut_in = np.sort(in_sel[own_src[in_sel] != me])
        self.neighbour_ranks = np.unique(own_dst[cut_out]).astype(np.int64)
        nbr = self.neighbour_ranks

        # node halo: for each neighbour rank r, the sorted boundary nodes sent to / received from r
        send_nodes = [np.unique(src[cut_out[own_dst[cut_out] == r]]) for r in nbr]
        recv_nodes = [np.unique(src[cut_in[own_src[cut_in] == r]]) for r in nbr]
        self._send_node_idx = local_index[np.concatenate(send_nodes)] if nbr.size else np.zeros(0, np.int64)
        self._node_send_counts = np.array([s.size for s in send_nodes], dtype=np.int64)
        self._node_recv_counts = np.array([s.size for s in recv_nodes], dtype=np.int64)
        halo = np.concatenate(recv_nodes) if nbr.size else np.zeros(0, np.int64)
        self.n_halo = int(halo.size)
        # columns = [local nodes in local order | halo as received]: the halo lands in one contiguous slice. Each
        # row of the mixer's product still sums its terms in global sender order (Mixer), so results agree
        # bitwise with in-process whatever the column numbering.
        self.n_columns = self.n_local + self.n_halo
        column_of = local_index.copy()
        column_of[halo] = self.n_local + np.arange(self.n_halo)
        self.local_col = np.arange(self.n_local, dtype=np.int64)
        self.in_src_col = column_of[self.in_src]

        # edge messages: per neighbour rank, cut edges in global edge order on both sides
        out_pos = np.full(graph.n_edges, -1, dtype=np.int64)
        out_pos[out_sel] = np.arange(out_sel.size)
        in_pos = np.full(graph.n_edges, -1, dtype=np.int64)
        in_pos[in_sel] = np.arange(in_sel.size)
        local_edges = out_sel[own_dst[out_sel] == me]
        self._local_out_pos = out_pos[local_edges]
        self._local_in_pos = in_pos[local_edges]
        send_edges = [cut_out[own_dst[cut_out] == r] for r in nbr]
        recv_edges = [cut_in[own_src[cut_in] == r] for r in nbr]
        self._edge_send_pos = out_pos[np.concatenate(send_edges)] if nbr.size else np.zeros(0, np.int64)
        self._edge_recv_pos = in_pos[np.concatenate(recv_edges)] if nbr.size else np.zeros(0, np.int64)
        self._edge_send_counts = np.array([e.size for e in send_edges], dtype=np.int64)
        self._edge_recv_counts = np.array([e.size for e in recv_edges], dtype=np.int64)

        self._layouts: dict[tuple[int, int, int], Any] = {}
        self._column_buffers: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, Any]] = {}
        self._edge_buffers: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, Any]] = {}
        self._requests: list[Any] = []
        self.dist_comm = self.comm.Create_dist_graph_adjacent(
            sources=nbr.tolist(), destinations=nbr.tolist(), reorder=False
        )
        self.persistent = bool(persistent and hasattr(self.dist_comm, "Neighbor_alltoallv_init"))
        self._init_accounting()

    # ------------------------------------------------------------- transport
    @staticmethod
    def _displs(counts: np.ndarray) -> np.ndarray:
        d = np.zeros(counts.size, dtype=np.int64)
        if counts.size > 1:
            np.cumsum(counts[:-1], out=d[1:])
        return d

    def _alltoallv(self, send: np.ndarray, send_counts: np.ndarray, recv_counts: np.ndarray,
                   width: int, dtype: np.dtype) -> np.ndarray:
        recv = np.empty((int(recv_counts.sum()), width), dtype=dtype)
        if self.neighbour_ranks.size == 0:
            return recv
        send = np.ascontiguousarray(send, dtype=dtype)
        key = (id(send_counts), id(recv_counts), width)
        layout = self._layouts.get(key)
        if layout is None:  # counts and displacements per payload width, computed once
            sc, rc = send_counts * width, recv_counts * width
            layout = self._layouts[key] = ((sc.tolist(), self._displs(sc).tolist()),
                                           (rc.tolist(), self._displs(rc).tolist()))
        self.dist_comm.Neighbor_alltoallv([send, layout[0]], [recv, layout[1]])
        return recv

    def _persistent_request(self, send: np.ndarray, send_counts: np.ndarray, recv: np.ndarray,
                            recv_counts: np.ndarray) -> Any:
        """A persistent ``Neighbor_alltoallv`` on fixed buffers (MPI-4), or None where the library lacks it."""
        if not self.persistent:
            return None
        width = send.shape[1] if send.ndim == 2 else recv.shape[1]
        sc, rc = send_counts * width, recv_counts * width
        req = self.dist_comm.Neighbor_alltoallv_init([send, (sc.tolist(), self._displs(sc).tolist())],
                                                     [recv, (rc.tolist(), self._displs(rc).tolist())])
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
        cols[:self.n_local] = flat_local
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
        return cols[self.n_local:]

    def _start_halo(self, flat_local: np.ndarray) -> tuple[np.ndarray, Any]:
        """Send this block's boundary values and start receiving the halo into the column buffer's tail; returns
        the buffer and the request to wait for (None when the plain collective has already completed)."""
        width = flat_local.shape[1]
        key = (width, flat_local.dtype.str)
        bufs = self._column_buffers.get(key)
        if bufs is None:
            send = np.empty((self._send_node_idx.size, width), dtype=flat_local.dtype)
            cols = np.empty((self.n_columns, width), dtype=flat_local.dtype)
            req = self._persistent_request(send, self._node_send_counts, cols[self.n_local:], self._node_recv_counts)
            bufs = self._column_buffers[key] = (send, cols, req)
        send, cols, req = bufs
        np.take(flat_local, self._send_node_idx, axis=0, out=send)
        if req is not None:
            req.Start()
            return cols, req
        cols[self.n_local:] = self._alltoallv(send, self._node_send_counts, self._node_recv_counts, width,
                                              flat_local.dtype)
        return cols, None

    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        width = flat_out.shape[1]
        out = np.zeros((self.in_edges.size, width), dtype=flat_out.dtype)
        key = (width, flat_out.dtype.str)
        bufs = self._edge_buffers.get(key)
        if bufs is None and self.neighbour_ranks.size:
            send = np.empty((self._edge_send_pos.size, width), dtype=flat_out.dtype)
            recv = np.empty((self._edge_recv_pos.size, width), dtype=flat_out.dtype)
            req = self._persistent_request(send, self._edge_send_counts, recv, self._edge_recv_counts)
            bufs = self._edge_buffers[key] = (send, recv, req)
        if bufs is not None and bufs[2] is not None:
            send, recv, req = bufs
            np.take(flat_out, self._edge_send_pos, axis=0, out=send)
            req.Start()
            out[self._local_in_pos] = flat_out[self._local_out_pos]
            req.Wait()
            out[self._edge_recv_pos] = recv
            return out
        out[self._local_in_pos] = flat_out[self._local_out_pos]
        recv = self._alltoallv(flat_out[self._edge_send_pos], self._edge_send_counts,
                               self._edge_recv_counts, width, flat_out.dtype)
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
        out = np.empty((self.graph.n_nodes, *arr.shape[1:]), dtype=arr.dtype)
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
        return int(self._edge_send_pos.size)
