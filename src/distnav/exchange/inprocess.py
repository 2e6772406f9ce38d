"""In-process exchange: the whole network is one block; a round is a vectorized gather or sparse product."""

from __future__ import annotations

from typing import Any

import numpy as np

from distnav.exchange.base import Exchange, ReduceOp
from distnav.exchange.faults import FaultSchedule
from distnav.network.graph import Graph

__all__ = ["InProcessExchange"]


class InProcessExchange(Exchange):
    """All nodes in one block. Edge orders: outgoing = incoming = the graph's global edge order."""

    backend = "inprocess"

    def __init__(self, graph: Graph, faults: FaultSchedule | None = None) -> None:
        super().__init__(graph, faults)
        e = np.arange(graph.n_edges, dtype=np.int64)
        self.nodes = np.arange(graph.n_nodes, dtype=np.int64)
        self.in_edges = e
        self.in_dst = graph.dst
        self.in_src = graph.src
        self.in_src_col = graph.src
        self.local_col = self.nodes
        self.out_edges = e
        self.out_src = graph.src
        self.out_dst = graph.dst
        self.n_columns = graph.n_nodes
        self._init_accounting()

    def _columns(self, flat_local: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        return flat_local

    def _move_edges(self, flat_out: np.ndarray, active: np.ndarray | None) -> np.ndarray:
        return flat_out

    def allreduce(self, value: Any, op: ReduceOp = "sum") -> Any:
        return value

    def gather_nodes(self, local: np.ndarray) -> np.ndarray:
        return np.asarray(local)

    def barrier(self) -> None:
        return None
