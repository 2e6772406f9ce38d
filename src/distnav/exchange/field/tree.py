"""Global operations of the field exchange routed over a spanning tree of the network's own links.

A field node talks only to its neighbours (the description lists no other addresses), so a reduction or a gather
that needs every node's contribution (a stopping rule's network totals, a rank check, a result gathered for the
record) travels along a breadth-first spanning tree of the communication graph, rooted at node 0 and built alike by
every node from the description (neighbours visited in ascending id order):

1. **up** — a node waits for its children's blocks (one message each, kind ``TREE_UP``), adds its own row and sends
   the block ``[[node id, values…], …]`` to its parent;
2. **down** — the root holds every node's row; it sends the whole block to its children (kind ``TREE_DOWN``), and
   each node forwards it to its own children.

A node waits for its children up to one deadline per level below it, and for its parent's answer up to one deadline
per hop up to the root and back (a late node delays every level above it, and no node gives up on a slow but live
subtree). Both directions use the same step (the messages of a step go child → parent and parent → child, never
twice along one direction of a link), so ``2 (n − 1)`` messages per global operation, ``2 × depth`` hops of
latency. Every node ends with the same rows and reduces them in node-id order, exactly as the all-to-all form does
when every node is a peer: the result is the same bit for bit.

A child that misses the deadline leaves its subtree out; the root still sends the rows it has down the tree (so every
node learns of the gap in the same step), and every node then raises :class:`ExchangeError` naming the missing nodes.
A parent that misses the deadline leaves this node without the network's answer: it sends its own subtree's rows on
to its children (who then raise at once instead of waiting out their own deadlines) and raises :class:`ExchangeError`
naming the parent. A global operation without every node is never replaced by a partial answer.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.field.transport import StepTransport
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

    @cached_property
    def depth(self) -> np.ndarray:
        """Hops from the root of every node."""
        depth = np.zeros(self.graph.n_nodes, np.int64)
        for i in np.argsort(self._bfs_order):  # parents come first in BFS order
            if self.parent[i] >= 0:
                depth[i] = depth[self.parent[i]] + 1
        return depth

    @cached_property
    def _bfs_order(self) -> np.ndarray:
        order = np.empty(self.graph.n_nodes, np.int64)
        queue, k = deque([0]), 0
        while queue:
            i = queue.popleft()
            order[i] = k
            k += 1
            queue.extend(self.children(i))
        return order

    def below(self, node: int) -> int:
        """Levels of the subtree under ``node`` (0 for a leaf)."""
        sub = [node]
        levels = 0
        while True:
            sub = [c for i in sub for c in self.children(i)]
            if not sub:
                return levels
            levels += 1


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


def tree_all(
    transport: StepTransport, tree: SpanningTree, me: int, step: int, array: np.ndarray
) -> dict[int, np.ndarray]:
    """Every node's ``array`` (float64 or int64, the same shape at every node) on every node, routed over ``tree``
    in step ``step`` (see the module docstring)."""
    width = 1 + array.size
    rows = {me: array}
    children = tree.children(me)
    deadline = transport.options.deadline_s  # a late leaf delays every level above it by up to one deadline
    if children:
        got = transport.collect(Kind.TREE_UP, step, children, deadline_s=deadline * tree.below(me))
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
        wait = deadline * (tree.below(0) + int(tree.depth[me]) + 1)  # up to the root and back down to here
        got = transport.collect(Kind.TREE_DOWN, step, [parent], deadline_s=wait)
        if parent not in got:
            for child in children:  # what this subtree holds, so the nodes below learn of the gap now, not later
                transport.post(child, Kind.TREE_DOWN, step, _block(rows))
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
    missing = sorted(set(range(tree.graph.n_nodes)) - rows.keys())
    if missing:
        raise ExchangeError(
            f"node {me}: the global operation of step {step} lacks the contributions of nodes {missing[:10]} "
            "(lost, or cut off behind a lost node)"
        )
    return rows
