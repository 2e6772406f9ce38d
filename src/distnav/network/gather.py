"""What a fusion centre would cost on the same network: every node's data gathered at one node by multi-hop relaying.

The yardstick of the message economy (issue 27): a distributed run's bytes and messages are reported beside what
gathering the same data at one *sink* node would cost over the **same communication graph**, each node's data
travelling along a shortest (fewest-hops) path to the sink, relayed by the nodes on the way.

* ``total_hop_bytes`` ``= Σ_i bytes_i · hops_i``: every byte counted once per link it crosses.
* ``relay_bytes[v]``: the bytes node ``v`` transmits, its own data and everything it relays for the nodes behind it
  (its subtree of the shortest-path tree); the sink transmits nothing. ``busiest_relay_bytes`` is their maximum —
  the node whose radio a fusion centre loads most (a neighbour of the sink).
* ``messages`` ``= Σ_i hops_i`` (each node's data forwarded as its own message on every hop; relays that bundle
  would send fewer, larger messages: ``tree_messages`` = one message per tree link, ``n − 1`` for a connected graph).
* ``sink``: given, or the node that minimizes ``total_hop_bytes`` (a weighted graph median; all nodes are tried up
  to :data:`EXACT_SINK_LIMIT` nodes, above that the :data:`SINK_CANDIDATES` nodes nearest the graph's centre by
  hop count from a peripheral node plus the highest-degree nodes). The result gathers the data only: sending the
  solution back would add about as much again.

Only nodes connected to the sink can be gathered; :attr:`GatherCost.unreachable` counts the others (their data is
left out of every figure).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, shortest_path

from distnav._checks import whole_number
from distnav.errors import GraphError
from distnav.network.graph import Graph
from distnav.typing import ArrayLike

__all__ = ["GatherCost", "gather_cost", "EXACT_SINK_LIMIT", "SINK_CANDIDATES"]

EXACT_SINK_LIMIT = 2000
SINK_CANDIDATES = 64


@dataclass(frozen=True, eq=False)
class GatherCost:
    """The cost of gathering every node's data at ``sink`` over shortest paths (see the module docstring)."""

    sink: int
    total_bytes: int  # the data itself, Σ bytes_i (what one node would hold)
    total_hop_bytes: int
    messages: int
    tree_messages: int
    relay_bytes: np.ndarray  # per node: bytes it transmits (own + relayed)
    hops: np.ndarray  # per node: hops to the sink (-1: unreachable)
    unreachable: int

    @property
    def busiest_relay_bytes(self) -> int:
        return int(self.relay_bytes.max()) if self.relay_bytes.size else 0

    @property
    def busiest_relay(self) -> int:
        return int(np.argmax(self.relay_bytes)) if self.relay_bytes.size else -1

    @property
    def median_node_bytes(self) -> float:
        return float(np.median(self.relay_bytes)) if self.relay_bytes.size else 0.0

    def as_dict(self) -> dict[str, int | float]:
        return {
            "sink": self.sink,
            "data_bytes": self.total_bytes,
            "total_hop_bytes": self.total_hop_bytes,
            "messages": self.messages,
            "tree_messages": self.tree_messages,
            "busiest_relay": self.busiest_relay,
            "busiest_relay_bytes": self.busiest_relay_bytes,
            "median_node_bytes": self.median_node_bytes,
            "unreachable_nodes": self.unreachable,
        }


def _cost(adj: sp.csr_matrix, data: np.ndarray, sink: int) -> GatherCost:
    order, pred = breadth_first_order(adj, sink, directed=False, return_predecessors=True)
    hops = np.full(adj.shape[0], -1, dtype=np.int64)
    hops[order] = shortest_path(adj, unweighted=True, directed=False, indices=sink)[order].astype(np.int64)
    reach = hops >= 0
    relay = np.where(reach, data, 0).astype(np.int64)
    for v in order[:0:-1]:  # leaves first (reverse BFS order): a node passes on its subtree's bytes
        relay[pred[v]] += relay[v]
    relay[sink] = 0
    return GatherCost(
        sink=int(sink),
        total_bytes=int(data[reach].sum()),
        total_hop_bytes=int((data[reach] * hops[reach]).sum()),
        messages=int(hops[reach].sum()),
        tree_messages=int(reach.sum() - 1),
        relay_bytes=relay,
        hops=hops,
        unreachable=int((~reach).sum()),
    )


def _best_sink(adj: sp.csr_matrix, data: np.ndarray, degrees: np.ndarray) -> int:
    """The node with the fewest unreachable nodes, then the least Σ bytes_i·hops_i (all nodes up to
    :data:`EXACT_SINK_LIMIT`, else :data:`SINK_CANDIDATES` central and high-degree candidates)."""
    n = adj.shape[0]
    if n <= EXACT_SINK_LIMIT:
        cand = np.arange(n)
    else:
        h0 = shortest_path(adj, unweighted=True, directed=False, indices=int(np.argmax(degrees)))
        far = int(np.argmax(np.where(np.isfinite(h0), h0, -1)))  # a peripheral node: the centre is half-way
        h1 = shortest_path(adj, unweighted=True, directed=False, indices=far)
        ecc = np.nanmax(np.where(np.isfinite(h1), h1, np.nan))
        centre = np.flatnonzero(np.abs(h1 - ecc / 2) <= 1)[: SINK_CANDIDATES // 2]
        by_degree = np.argsort(-degrees, kind="stable")[: SINK_CANDIDATES // 2]
        cand = np.unique(np.concatenate([centre, by_degree]))
    dist = shortest_path(adj, unweighted=True, directed=False, indices=cand)
    unreachable = (~np.isfinite(dist)).sum(axis=1)
    total = np.where(np.isfinite(dist), dist, 0.0) @ data.astype(float)
    best = np.lexsort((total, unreachable))[0]
    return int(cand[best])


def gather_cost(graph: Graph, bytes_per_node: ArrayLike, *, sink: int | None = None) -> GatherCost:
    """The cost of gathering ``bytes_per_node[i]`` bytes from every node ``i`` at one sink over ``graph``
    (module docstring). ``sink=None`` picks the node with the least total hop-bytes.

    Examples
    --------
    Five nodes in a chain, 100 bytes each: the middle node is the best sink, its two neighbours relay 200 bytes each.

    >>> from distnav.network import builders
    >>> from distnav.network.gather import gather_cost
    >>> cost = gather_cost(builders.path(5), [100] * 5)
    >>> cost.sink, cost.total_hop_bytes, cost.busiest_relay_bytes, cost.relay_bytes.tolist()
    (2, 600, 200, [100, 200, 0, 200, 100])
    """
    data = np.asarray(bytes_per_node)
    if data.shape != (graph.n_nodes,):
        raise GraphError(f"bytes_per_node needs one entry per node ({graph.n_nodes}), got shape {data.shape}")
    if not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        raise GraphError(f"bytes_per_node must be real numbers of bytes, got dtype {data.dtype}")
    if not (np.isfinite(data).all() and (data >= 0).all()):
        raise GraphError("bytes_per_node must be finite and ≥ 0")
    data = np.rint(data).astype(np.int64)
    adj = graph.adjacency().tocsr()
    if sink is not None:
        sink = whole_number(sink, "sink", error=GraphError)
        if not 0 <= int(sink) < graph.n_nodes:
            raise GraphError(f"sink {sink} is not a node of this {graph.n_nodes}-node graph")
        return _cost(adj, data, int(sink))
    return _cost(adj, data, _best_sink(adj, data, np.asarray(graph.degrees)))
