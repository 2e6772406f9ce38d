"""In-process exchange: the whole network is one block; a round is a vectorized gather or sparse product.

By default the block keeps the user's node order, at every size: ``ex.mixer(w).apply(x)`` takes and returns rows
in the user's ids. ``order=`` opts in to a locality order (``"auto"``: reverse Cuthill–McKee from 10⁴ nodes on; see
:func:`distnav.network.partition.locality_order`), chosen once at set-up; per-node arrays then follow ``ex.nodes``
and the caller converts at the boundary with :meth:`~distnav.exchange.core.ExchangeCore.local` and
:meth:`~distnav.exchange.base.Exchange.gather_nodes`. The front doors that make their own exchange
(``average_consensus``, ``admm``, ``ckf``) opt in and gather their results, so they return the user's order too.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.base import Exchange
from distnav.exchange.core import ReduceOp, Reducible, incoming_edges
from distnav.exchange.faults import FaultSchedule
from distnav.network.graph import Graph
from distnav.network.partition import locality_order

__all__ = ["InProcessExchange"]


class InProcessExchange(Exchange):
    """All nodes in one block. Edge orders: outgoing = incoming = grouped by receiver in the local node order (the
    graph's global edge order when the order is the user's)."""

    backend = "inprocess"
    _moves_rows_in_place = True

    def __init__(self, graph: Graph, faults: FaultSchedule | None = None, *, order: str | np.ndarray = "none") -> None:
        super().__init__(graph, faults)
        perm = locality_order(graph, order)
        self._identity = perm is None
        # edge-sized index arrays in 32 bits where they fit (half the exchange's memory at 10⁶ nodes); per-node ids
        # (``nodes``) stay int64, and in the user's order the receivers and senders are the graph's own arrays
        idx = np.int32 if max(graph.n_nodes, graph.n_edges) < 2**31 - 1 else np.int64
        if perm is None:
            e = np.arange(graph.n_edges, dtype=idx)
            self.nodes = np.arange(graph.n_nodes, dtype=np.int64)
            self.in_dst = graph.dst
            self.in_src_col = graph.src
            self.out_src = graph.src
        else:
            self.nodes = np.asarray(perm, dtype=np.int64)
            position = np.empty(graph.n_nodes, dtype=idx)
            position[self.nodes] = np.arange(graph.n_nodes, dtype=idx)
            e = incoming_edges(graph, self.nodes).astype(idx)
            # grouped by receiver in the local order: the k-th group's receiver is local row k (no gather needed)
            in_degree = np.diff(graph.in_ptr)[self.nodes]
            self.in_dst = np.repeat(np.arange(graph.n_nodes, dtype=idx), in_degree)
            self.in_src_col = position[graph.src[e]]
            self.out_src = self.in_src_col
            del position
        self.in_edges = e
        self.local_col = np.arange(graph.n_nodes, dtype=idx)
        self.out_edges = e
        self.n_columns = graph.n_nodes
        self._init_accounting()
        if np.array_equal(self._all_sent, self._all_recv):  # a symmetric graph: one array of both counts
            self._all_recv = self._all_sent

    # the senders' and receivers' global ids per edge are made only when asked for (consensus needs neither: two
    # edge-sized arrays less at 10⁶ nodes); the graph's own arrays in the user's order
    @cached_property
    def in_src(self) -> np.ndarray:  # type: ignore[override]
        return self.graph.src if self._identity else np.asarray(self.graph.src[self.in_edges])

    @cached_property
    def out_dst(self) -> np.ndarray:  # type: ignore[override]
        return self.graph.dst if self._identity else np.asarray(self.graph.dst[self.out_edges])

    def _real_edges(self) -> tuple[np.ndarray, np.ndarray]:
        # sender and receiver are the same node exactly when their local positions are
        real = self.in_src_col != self.in_dst
        return real, real  # the same edges in both orders (read only: one array)

    def _sender_below(self) -> np.ndarray:
        below = self.graph.src < self.graph.dst
        return below if self._identity else np.asarray(below[self.in_edges])

    def _columns(self, flat_local: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        return flat_local

    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        return flat_out

    def allreduce(self, value: Reducible, op: ReduceOp = "sum") -> Reducible:
        return value

    def gather_nodes(self, local: np.ndarray) -> np.ndarray:
        """Local order → the user's order: a gather of whole rows through the inverse of :attr:`nodes` (made once),
        3-4x faster than a scatter ``out[nodes] = local`` on ``(n, k)`` arrays."""
        arr = np.asarray(local)
        if self._identity:
            return arr
        if arr.ndim == 0 or arr.shape[0] != self.n_local:
            raise ExchangeError(f"expected a local array with {self.n_local} rows, got shape {arr.shape}")
        return np.take(arr, self._position, axis=0)

    @cached_property
    def _position(self) -> np.ndarray:
        """Local row of each node (the user's id → its row): the inverse of :attr:`nodes`."""
        position = np.empty(self.n_local, dtype=np.intp)
        position[self.nodes] = np.arange(self.n_local, dtype=np.intp)
        return position

    def barrier(self) -> None:
        return None
