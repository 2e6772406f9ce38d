"""Global operations of the field exchange routed over a spanning tree of the network's own links.

A field node talks only to its neighbours (the description lists no other addresses), so a reduction or a gather
that needs every node's contribution (a stopping rule's network totals, a rank check, a result gathered for the
record) travels along a breadth-first spanning tree of the communication graph, rooted at node 0 and built alike by
every node from the description (neighbours visited in ascending id order):

1. **up** — a node waits for its children's blocks (one message each, kind ``TREE_UP``), adds its own row and sends
   the block ``[[node id, values…], …]`` to its parent;
2. **down** — the root holds every node's row; it sends the whole block to its children (kind ``TREE_DOWN``), and
   each node forwards it to its own children.

Both directions use the same step (the messages of a step go child → parent and parent → child, never twice along
one direction of a link), so ``2 (n − 1)`` messages per global operation, ``2 × depth`` hops of latency. Every node
ends with the same rows and reduces them in node-id order, exactly as the all-to-all form does when every node is a
peer: the result is the same bit for bit.

A child that misses the deadline leaves its subtree out (as a lost node is left out of the all-to-all form); a
parent that misses it leaves this node without the network's answer, which is an :class:`ExchangeError` naming the
parent (a global operation cannot be finished without it; it is never replaced by a partial answer).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.field.transport import Transport
from distnav.exchange.field.wire import Kind
from distnav.network.graph import Graph

__all__ = ["SpanningTree", "tree_all"]


@dataclass(frozen=True, eq=False)
class SpanningTree:
    """The breadth-first spanning tree of ``graph`` rooted at node 0 (see the module docstring)."""

    graph: Graph

    @cached_property
    def parent(self) -> np.ndarray:
        """Parent of every node (−1 at the root); :class:`ExchangeError` when the graph is not connected."""
        g = self.graph
        parent = np.full(g.n_nodes, -2, np.int64)
        parent[0] = -1
        queue = deque([0])
        while queue:
            i = queue.popleft()
            for j in sorted(int(k) for k in g.neighbors(i)):
                if parent[j] == -2:
                    parent[j] = i
                    queue.append(j)
        unreached = np.flatnonzero(parent == -2)
        if unreached.size:
            raise ExchangeError(
                f"the network is not connected: nodes {unreached[:10].tolist()} cannot be reached from node 0, so "
                "no global operation (reduction, gather) can include them"
            )
        return parent

    def children(self, node: int) -> list[int]:
        return np.flatnonzero(self.parent == node).tolist()


def _block(rows: dict[int, np.ndarray]) -> np.ndarray:
    """``[[node id, values…], …]`` in node order, in the common dtype of the rows (float64 or int64)."""
    ids = sorted(rows)
    dtype = np.result_type(*(rows[i].dtype for i in ids))
    out = np.empty((len(ids), 1 + rows[ids[0]].size), dtype=dtype)
    out[:, 0] = ids
    for k, i in enumerate(ids):
        out[k, 1:] = rows[i].ravel()
    return out


def _rows(block: np.ndarray, shape: tuple[int, ...]) -> dict[int, np.ndarray]:
    return {int(r[0]): r[1:].reshape(shape) for r in block}


def tree_all(transport: Transport, tree: SpanningTree, me: int, step: int, array: np.ndarray) -> dict[int, np.ndarray]:
    """Every node's ``array`` (float64 or int64, the same shape at every node) on every node, routed over ``tree``
    in step ``step`` (see the module docstring)."""
    width = 1 + array.size
    rows = {me: array}
    children = tree.children(me)
    if children:
        got = transport.collect(Kind.TREE_UP, step, children)
        for child, block in got.items():
            if block.ndim != 2 or block.shape[1] != width or block.dtype.kind not in "fi":
                transport._refuse(
                    "malformed", f"node {child} sent a tree block {block.dtype}{block.shape} at step {step}"
                )
                continue
            rows.update(_rows(block, array.shape))
    parent = int(tree.parent[me])
    if parent >= 0:
        transport.post(parent, Kind.TREE_UP, step, _block(rows))
        got = transport.collect(Kind.TREE_DOWN, step, [parent])
        if parent not in got:
            lost = transport.lost.get(parent)
            when = f" (lost at step {lost})" if lost is not None else ""
            raise ExchangeError(
                f"node {me}: the global operation of step {step} needs the network's answer from node {parent}, its "
                f"parent in the spanning tree, which did not send it{when}"
            )
        full = got[parent]
        if full.ndim != 2 or full.shape[1] != width or full.dtype.kind not in "fi":
            raise ExchangeError(f"node {me}: node {parent} sent a malformed tree block {full.dtype}{full.shape}")
        rows = _rows(full, array.shape)
    down = _block(rows)
    for child in children:
        transport.post(child, Kind.TREE_DOWN, step, down)
    return rows
