"""Average consensus in flow form: the average of the nodes that remain, whatever nodes die.

Each node ``i`` keeps, per neighbour ``j``, the net flow ``φ_ij`` of value it has taken from ``j``, and its value is
its initial value plus its flows (after Jesus, Baquero & Almeida's *flow updating*, 2009):

    x_i(k) = x_i(0) + Σ_j φ_ij(k)                                                        (F1)

Per round every node sends ``(x_i, φ_ij)`` to each neighbour. The lower id of a link owns its flow: on receiving
``(x_j, φ_ji)``, the owner ``i < j`` updates ``φ_ij ← φ_ij + w_ij (x_j − x_i)`` (the consensus step of paper 003
eq. (31) written on the link), and the other end sets ``φ_ji ← −(φ_ij + w_ij (x_j − x_i))`` from the operands it
received — the same floating-point expression, so ``φ_ji = −φ_ij`` exactly when both messages of the link arrived.

Why the result is exact: with antisymmetric flows the flows cancel in the sum over any set of nodes that holds both
ends of every link it keeps, so ``Σ_{i alive} x_i(k) = Σ_{i alive} x_i(0)`` once every node has dropped its flows
with the dead (F1). The survivors' weights are the original symmetric ones with a dead neighbour's weight moved to the
self-weight (still doubly stochastic), so on a connected surviving graph the values converge to the mean of the
survivors' initial values. A neighbour silent for ``patience`` rounds is dropped (its flow set to 0); if it comes
back (a restarted node with its initial value and no flows), the owner's flow restarts from 0 — the rejoined node's
value joins the average. A lost message leaves the flow at its last value; the mismatch it may cause lasts until the
link's next round in which both messages arrive (the owner's value is authoritative), so the average is exact in the
limit. Without any loss the iteration equals eq. (31) with the same weights (in exact arithmetic).

Needs symmetric weights (``w_ij = w_ji``: MH, P1–P4 on undirected graphs) and the whole graph on the exchange
(in-process or field; not an MPI graph part).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from distnav._checks import whole_number
from distnav.algorithms.consensus.averaging import ConsensusState, _as_node_array, consensus_schedule
from distnav.errors import WeightsError
from distnav.exchange import Exchange, make_exchange
from distnav.network.graph import Graph

__all__ = ["iterate_flow_consensus"]


def iterate_flow_consensus(
    values: np.ndarray,
    *,
    graph: Graph,
    protocol: str = "MH",
    rounds: int,
    exchange: Exchange | None = None,
    patience: int = 20,
) -> Iterator[ConsensusState]:
    """Yield this block's values after rounds 0 (initial), 1, …, ``rounds`` of flow consensus (module docstring).

    ``values``: a leading node axis (``n_nodes``); only this block's rows are read. ``patience``: rounds without a
    message after which a neighbour's flow is dropped (long
    enough that random losses do not reach it: dropping a live link's flow undoes its history and restarts its
    mixing; a lost link's flow is a node that is gone).
    """
    rounds = whole_number(rounds, "rounds", error=WeightsError)
    patience = whole_number(patience, "patience", minimum=1, error=WeightsError)
    sched = consensus_schedule(graph, protocol)
    if sched.n_sessions != 1:
        raise WeightsError("flow consensus runs on a static graph (one session)")
    w_all = sched.weights[0].edge_weight
    if not np.array_equal(w_all, w_all[graph.reverse_edge]):
        raise WeightsError(f"flow consensus needs symmetric weights (w_ij = w_ji); {protocol!r} is not on this graph")
    ex = exchange if exchange is not None else make_exchange(graph)
    x0 = ex.local(_as_node_array(values, graph.n_nodes))
    n_local, tail = x0.shape[0], x0.shape[1:]
    d = int(np.prod(tail, dtype=np.int64))
    x0f = x0.reshape(n_local, d)
    # per in-edge (j → i): the flow φ_ij, its weight, whether i owns it; per out-edge (i → j): the in-edge of φ_ij
    w = np.asarray(w_all[ex.in_edges], float)[:, None]
    receiver = ex.nodes[ex.in_dst]
    owner = receiver < ex.in_src
    real = ex.in_src != receiver
    order = np.argsort(ex.in_edges, kind="stable")
    flow_row = order[np.searchsorted(ex.in_edges[order], graph.reverse_edge[ex.out_edges])]
    phi = np.zeros((ex.in_edges.size, d))
    silent = np.zeros(ex.in_edges.size, np.int64)
    x = x0f.copy()
    yield ConsensusState(0, x.reshape(x0.shape))
    for k in range(rounds):
        inbox = ex.send(np.concatenate([x[ex.out_src], phi[flow_row]], axis=1))
        got = inbox.delivered & real
        xj, phi_j = inbox.values[:, :d], inbox.values[:, d:]
        step = w * (xj - x[ex.in_dst])
        own, other = got & owner, got & ~owner
        phi[own] += step[own]
        phi[other] = -(phi_j[other] - step[other])  # the owner's φ + w(x_i − x_j), negated: bit for bit
        silent[got] = 0
        silent[~got & real] += 1
        phi[silent >= patience] = 0.0
        x = x0f + np.asarray(inbox_sum(ex.in_dst, phi, n_local))
        yield ConsensusState(k + 1, x.reshape(x0.shape))


def inbox_sum(dst: np.ndarray, per_edge: np.ndarray, n_local: int) -> np.ndarray:
    """``Σ_e per_edge[e]`` per receiver, adding each receiver's terms in in-edge order (the same order on every
    backend: senders ascending)."""
    out = np.zeros((n_local, per_edge.shape[1]))
    np.add.at(out, dst, per_edge)
    return out
