"""Going on without a dead node: the nodes that remain agree on who they are, then run on their own sub-network.

A node program whose algorithm cannot finish without every node (a global operation that lacks one raises
:class:`ExchangeError` at every node, :mod:`.tree`) calls :func:`agree_on_survivors` and continues on the nodes it
returns, through a :class:`SubnetTransport` (the same sockets, the remaining nodes renumbered ``0..m − 1`` in
ascending id order) and a new :class:`~distnav.exchange.field.FieldExchange` on the graph they induce.

**Agreement by flooding.** Each node holds a mark per node, at first its own. In each of ``n`` rounds (``n`` nodes
in the description: more than the diameter of any connected surviving network) it sends its marks to the neighbours
it still counts as alive and ORs in theirs. A dead node sends nothing, so no mark of it is ever made; after the
rounds every node of a connected surviving network holds the marks of exactly the nodes of that network.

**Timing.** The nodes do not enter the agreement together: a global operation that lost a node ends at each node
when its own deadline for the missing message passes, and a node below the dead one in the spanning tree waits
longest — at most ``deadline × (2·height + 1)`` later than the first (:mod:`.tree`). A dying process may also take
its last queued messages with it, so some nodes can fail a step or two before the others. The rounds therefore run
in steps that do not depend on where a node failed (the caller passes the same base at every node), and round ``k``
ends at the latest ``(k + 1)·window_s`` after the node entered the agreement, with ``window_s`` more than that skew
(:func:`agreement_window_s`). A neighbour is taken for dead only when nothing at all came from it during a round (no
marks, and no message of another step or kind either): a live neighbour still busy with the failed computation is
waited for in the next round. A dead neighbour costs one window, once; the rounds' deadlines are absolute, so waits
do not add up along a path of nodes. The marks also carry the earliest step at which a node saw the operation fail,
so every node reports the same step.

The result is checked afterwards by the caller (every node's marks gathered over the new sub-network must be equal);
a disagreement is an error, never a guess. (Found by the test that kills the tree's inner node: with step-numbered
rounds and "no marks = dead", the two children of the dead node, which had failed two steps earlier, and the other
nodes each took the others for dead and solved apart, two answers that looked right.)
"""

from __future__ import annotations

import time

import numpy as np

from distnav.errors import ExchangeError
from distnav.exchange.field.transport import Like, Peer, Senders, StepTransport, TransportOptions
from distnav.exchange.field.tree import SpanningTree
from distnav.exchange.field.wire import Kind, Message
from distnav.network.graph import Graph

__all__ = ["SubnetTransport", "agree_on_survivors", "agreement_window_s", "beyond_reach", "subnetwork"]


def agreement_window_s(graph: Graph, deadline_s: float) -> float:
    """The longest a round of :func:`agree_on_survivors` may have to wait for a live neighbour: more than the skew
    with which the nodes leave a global operation that lost a node (module docstring)."""
    height = SpanningTree(graph).below(0)
    return deadline_s * (2 * height + 3)


def agree_on_survivors(
    transport: StepTransport,
    graph: Graph,
    step: int,
    *,
    window_s: float,
    failed_step: int,
    dead: set[int] | None = None,
) -> tuple[np.ndarray, int, int]:
    """The nodes that are still running (a boolean mask over the graph's nodes), agreed by flooding in steps
    ``step .. step + n − 1`` (module docstring), the earliest ``failed_step`` among them (the step of the failed
    operation, as every node saw it) and the next step. ``step`` must not depend on where a node noticed the loss
    (the caller passes a fixed base per attempt), so nodes that failed in different steps still flood in the same
    ones. ``dead``: nodes already known dead."""
    me, n = transport.me, graph.n_nodes
    gone = set(dead or ())
    nbrs = [int(j) for j in sorted(graph.neighbors(me)) if int(j) not in gone]
    marks = np.zeros(n + 1, np.int64)  # [earliest failed step, a mark per node]
    marks[0], marks[1 + me] = failed_step, 1
    t0 = time.monotonic()
    for k in range(n):
        live = [j for j in nbrs if j not in gone]
        heard = {j: transport.heard.get(j, 0) for j in live}
        transport.post_many(live, Kind.COLUMN, step + k, marks)
        wait = max(0.0, t0 + (k + 1) * window_s - time.monotonic())
        got = transport.collect(Kind.COLUMN, step + k, live, deadline_s=wait)
        for j in live:
            theirs = got.get(j)
            if theirs is None:
                if transport.heard.get(j, 0) == heard[j]:  # not a sign of life in the whole round: dead
                    gone.add(j)
            elif theirs.shape != (n + 1,) or theirs.dtype != np.int64:
                transport._refuse("malformed", f"node {j} sent marks {theirs.dtype}{theirs.shape} at step {step + k}")
            else:
                marks[0] = min(marks[0], theirs[0])
                marks[1:] |= theirs[1:]
    return marks[1:].astype(bool), int(marks[0]), step + n


def beyond_reach(graph: Graph, alive: np.ndarray, missing: list[int]) -> list[int]:
    """The nodes of ``missing`` that no node of ``alive`` neighbours. The agreement cannot tell a dead node from a
    live one cut off behind the dead (a path ``0 – … – 7`` without node 5: nodes ``0..4`` never hear of 6 and 7),
    so only a missing node that a remaining neighbour saw silent counts as lost; one beyond reach may be alive on
    the other side of a cut, and a caller that went on without it would solve apart from it.

    Examples
    --------
    >>> import numpy as np
    >>> from distnav.exchange.field.survivors import beyond_reach
    >>> from distnav.network import builders
    >>> alive = np.array([True] * 5 + [False] * 3)
    >>> beyond_reach(builders.path(8), alive, [5, 6, 7])
    [6, 7]
    """
    return [k for k in missing if not np.any(alive[np.asarray(graph.neighbors(k), np.int64)])]


def subnetwork(graph: Graph, alive: np.ndarray) -> Graph:
    """The graph the nodes of ``alive`` induce, renumbered ``0..m − 1`` in ascending id order."""
    keep = np.flatnonzero(alive)
    new = np.full(graph.n_nodes, -1, np.int64)
    new[keep] = np.arange(keep.size)
    links = np.asarray(graph.links, np.int64).reshape(-1, 2)
    both = alive[links[:, 0]] & alive[links[:, 1]]
    return Graph.from_links(int(keep.size), new[links[both]])


class SubnetTransport:
    """A node's transport seen on the remaining nodes, renumbered ``0..m − 1`` in ascending id order: the same
    sockets, step counts, checks and refusals (see the module docstring)."""

    def __init__(self, base: StepTransport, alive: np.ndarray) -> None:
        keep = np.flatnonzero(alive).tolist()
        if base.me not in keep:
            raise ExchangeError(f"node {base.me} is not among the remaining nodes {keep}")
        self.base = base
        self._old = keep
        self._new = {old: k for k, old in enumerate(keep)}
        self.me = self._new[base.me]
        self.peers: dict[int, Peer] = {self._new[p]: peer for p, peer in base.peers.items() if p in self._new}
        self.options: TransportOptions = base.options

    @property
    def lost(self) -> dict[int, int]:
        return {self._new[k]: v for k, v in self.base.lost.items() if k in self._new}

    def readmit(self, peer: int, step: int) -> None:
        self.base.readmit(self._old[peer], step)

    @property
    def greeted(self) -> dict[int, int]:
        return {self._new[k]: v for k, v in self.base.greeted.items() if k in self._new}

    @property
    def heard(self) -> dict[int, int]:
        return {self._new[k]: v for k, v in self.base.heard.items() if k in self._new}

    def post(self, peer: int, kind: Kind, step: int, array: np.ndarray) -> None:
        self.base.post(self._old[peer], kind, step, array)

    def post_many(self, peers: list[int], kind: Kind, step: int, array: np.ndarray) -> None:
        self.base.post_many([self._old[p] for p in peers], kind, step, array)

    def collect(
        self, kind: Kind, step: int, senders: Senders, *, deadline_s: float | None = None, like: Like = None
    ) -> dict[int, np.ndarray]:
        got = self.base.collect(kind, step, [self._old[int(s)] for s in senders], deadline_s=deadline_s, like=like)
        return {self._new[s]: a for s, a in got.items() if s in self._new}

    def _refuse(self, reason: str, text: str) -> Message | None:
        return self.base._refuse(reason, text)
