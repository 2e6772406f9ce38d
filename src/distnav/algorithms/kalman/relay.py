"""The CKF's consensus by relaying observation records (issue 27: ``iterate_ckf(..., transport="relay")``).

``k_n`` consensus rounds give node ``i`` the combination ``N_i^(k_n) = Σ_j l_ij N_j`` of the normals of the nodes
within ``k_n`` hops (paper 003 eq. (35), ``L = W_(k_n)⋯W_(1)``; ``l_ij = 0`` beyond ``k_n`` hops). Instead of
sending the mixed packed matrices ``(N_i^(k), r_i^(k))`` every round (``p(p+1)/2 + p`` float64 per message), the
relay sends each node's **raw observation records** of the epoch — per observation its value, its weight and the
index of its slot (the satellite): 20 B, the yardstick of :mod:`distnav.algorithms.kalman.gather_data` — hop by
hop, ``k_n`` rounds deep, and every node evaluates the same ``L`` row on the normals it rebuilds from them
(the mapping from a record to its design row follows from the orbits and the sender's position, static
knowledge every station holds, like ``L``'s row, which follows from the graph and the weights). Same consensus
operator, same filter (up to the summation order of the floating-point sums), far fewer bytes when a node has
fewer observations than its normals have entries.

Routing (static, :class:`RelayPlan`): origin ``o``'s records reach node ``v`` in round ``d(o, v)`` (hop distance)
from exactly one neighbour, its parent for ``o``: the lowest-numbered neighbour at distance ``d(o, v) − 1``. So each
record crosses one link into each node within ``k_n`` hops of its origin, never more. A message carries, per
origin it relays, a 2-byte record count and the records (``RECORD_BYTES`` each).

Needs a static graph, no faults (a lost record would be missing for good: use the matrix transport) and a series
that gives its records (:meth:`MeasurementSeries.records`). Set-up cost O(n · E) booleans (hop distances of every
pair within ``k_n``): meant for networks of up to a few thousand nodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from distnav.algorithms.consensus.averaging import ConsensusSchedule, consensus_product
from distnav.algorithms.kalman.measurements import MeasurementSeries
from distnav.errors import ModelError
from distnav.exchange import Exchange
from distnav.network.graph import Graph
from distnav.typing import FloatArray, IntArray

__all__ = [
    "COUNT_BYTES",
    "MAX_RELAY_NODES",
    "RECORD_BYTES",
    "RelayPlan",
    "matrix_bytes",
    "relay_bytes",
    "relay_plan",
    "relay_records",
    "relay_setup",
    "relayed_payload",
]

#: One observation record on the wire: value and weight (float64) and slot index (int32).
RECORD_BYTES = 20
#: The record count of one origin in a message (uint16).
COUNT_BYTES = 2


@dataclass(frozen=True, eq=False)
class RelayPlan:
    """Which origins' records each directed edge carries in each round (module docstring).

    hops : (n, n) int32 hop distance ``d(o, v)`` (``rounds + 1`` beyond ``rounds`` hops).
    carried : per round ``k`` (0-based, round ``k + 1``), a list of ``(edge, origin)`` pairs (global ids),
        sorted by edge then origin.
    """

    rounds: int
    hops: np.ndarray
    carried: tuple[tuple[tuple[int, int], ...], ...]


#: The largest network :func:`relay_plan` takes (its set-up holds n × n hop counts and an n × E mask).
MAX_RELAY_NODES = 4096


def relay_plan(graph: Graph, rounds: int) -> RelayPlan:
    """The static routing of :mod:`this module <distnav.algorithms.kalman.relay>` on ``graph`` for ``rounds`` hops."""
    n = graph.n_nodes
    if n > MAX_RELAY_NODES:
        raise ModelError(
            f"the relay transport plans routes for up to {MAX_RELAY_NODES} nodes (O(n·E) set-up), the graph has {n}: "
            f"use transport='matrices'"
        )
    far = rounds + 1
    hops = np.full((n, n), far, np.int32)
    reached = np.eye(n, dtype=bool)
    np.fill_diagonal(hops, 0)
    src, dst = np.asarray(graph.src), np.asarray(graph.dst)
    real = src != dst
    src, dst = src[real], dst[real]
    for k in range(1, rounds + 1):
        grown = reached.copy()
        np.logical_or.at(grown.T, dst, reached.T[src])  # v is reached if a neighbour was
        hops[grown & ~reached] = k
        reached = grown
    # parent of (o, v): the first in-edge of v (edges sorted by (dst, src): the lowest sender) one hop nearer o
    d_dst = hops[:, dst]
    cand = (hops[:, src] == d_dst - 1) & (d_dst >= 1) & (d_dst <= rounds)
    o_idx, e_idx = np.nonzero(cand)  # o ascending, then e ascending
    _, first = np.unique(o_idx * n + dst[e_idx], return_index=True)
    o_sel, e_sel = o_idx[first], e_idx[first]
    edge_ids = np.flatnonzero(real)[e_sel]
    k_sel = hops[o_sel, dst[e_sel]]
    carried = []
    for k in range(1, rounds + 1):
        m = k_sel == k
        pairs = sorted(zip(edge_ids[m].tolist(), o_sel[m].tolist(), strict=True))
        carried.append(tuple(pairs))
    return RelayPlan(rounds, hops, tuple(carried))


def relay_setup(sched: ConsensusSchedule, ex: Exchange, kn: int) -> tuple[RelayPlan, FloatArray]:
    """The plan of ``kn`` hops and this block's rows of ``L = W^(kn)``, or a :class:`ModelError` naming what the relay
    cannot do (a switching graph, a fault schedule)."""
    if len(sched.weights) != 1 or any(a is not None for a in sched.active):
        raise ModelError("transport='relay' needs a static graph (one session); use transport='matrices'")
    if ex.faults.active:
        raise ModelError("transport='relay' needs every message (no fault schedule); use transport='matrices'")
    return relay_plan(sched.graph, kn), consensus_product(sched, kn)[ex.nodes]


def relay_bytes(plan: RelayPlan, records: IntArray) -> int:
    """Bytes the relay sends for ``records`` (epochs × nodes: each node's record count per epoch): every origin's
    count and records cross each edge that carries it (:data:`COUNT_BYTES` + :data:`RECORD_BYTES` per record)."""
    counts = np.asarray(records, np.int64)
    crossings = np.zeros(counts.shape[1], np.int64)
    for pairs in plan.carried:
        for _, o in pairs:
            crossings[o] += 1
    return int((crossings * (COUNT_BYTES * counts.shape[0] + RECORD_BYTES * counts.sum(axis=0))).sum())


def matrix_bytes(graph: Graph, rounds: int, n_states: int, epochs: int) -> int:
    """Bytes the matrix transport sends: every round one message per directed link with the packed ``N`` and ``r``
    (``p(p+1)/2 + p`` float64)."""
    links = int((np.asarray(graph.src) != np.asarray(graph.dst)).sum())
    return epochs * rounds * links * 8 * (n_states * (n_states + 1) // 2 + n_states)


def relay_records(
    ex: Exchange, plan: RelayPlan, values: FloatArray, weights: FloatArray
) -> list[dict[int, tuple[FloatArray, FloatArray]]]:
    """Relay every local node's records ``(values, weights)`` (k_local × slots; weight 0 = no observation)
    ``plan.rounds`` hops deep; returns per local node ``{origin: (values, weights)}`` of what it received, its own
    records included. Every message is counted at its real size (:data:`COUNT_BYTES` per origin plus
    :data:`RECORD_BYTES` per record)."""
    if ex.faults.active:
        raise ModelError("the relay transport needs every message: no fault schedule (use transport='matrices')")
    nodes = ex.nodes
    slots = values.shape[1]
    known: list[dict[int, tuple[FloatArray, FloatArray]]] = [
        {int(g): (values[a], weights[a])} for a, g in enumerate(nodes.tolist())
    ]
    out_row = {int(e): r for r, e in enumerate(ex.out_edges.tolist())}
    in_row = {int(e): r for r, e in enumerate(ex.in_edges.tolist())}
    out_src, in_dst = ex.out_src, ex.in_dst
    for pairs in plan.carried:
        if not pairs:  # every origin is known within fewer hops: an empty round (counted, nothing carried)
            ex.send(np.zeros((ex.out_edges.size, 1)), active=np.zeros(ex.n_edges, bool))
            continue
        per_edge: dict[int, list[int]] = {}
        for e, o in pairs:
            per_edge.setdefault(e, []).append(o)
        width = max((len(v) for v in per_edge.values()), default=0) * (1 + 3 * slots)
        buf = np.zeros((ex.out_edges.size, max(width, 1)))
        sizes = np.zeros(ex.out_edges.size, np.int64)
        active = np.zeros(ex.n_edges, bool)
        active[list(per_edge)] = True
        for e, origins in per_edge.items():
            r = out_row.get(e)
            if r is None:
                continue
            sender = known[int(out_src[r])]
            sizes[r] = _pack(buf[r], [sender[o] for o in origins], slots)
        inbox = ex.send(buf, active=active, message_bytes=sizes)
        for e, origins in per_edge.items():
            r_in = in_row.get(e)
            if r_in is None:
                continue
            receiver = known[int(in_dst[r_in])]
            for o, rec in zip(origins, _unpack(inbox.values[r_in], len(origins), slots), strict=True):
                receiver[o] = rec
    return known


def relayed_payload(
    ex: Exchange,
    plan: RelayPlan,
    L_rows: FloatArray,
    measurements: MeasurementSeries,
    t: int,
    values: FloatArray,
    weights: FloatArray,
    up: IntArray,
    *,
    with_rows: bool,
    tagged: bool,
) -> FloatArray:
    """Relay this block's records of epoch ``t`` and return the CKF's payload after ``k_n`` rounds as the matrix
    transport would hold it: ``[tri(N_i^(k_n)), r_i^(k_n)]`` = ``Σ_j l_ij (N_j, r_j)`` over the origins each node
    received (every origin with ``l_ij ≠ 0`` must be among them; ``up``: flat indices of the upper triangle), then
    with ``with_rows`` the row ``l_i`` (static knowledge here, sent nowhere) and with ``tagged`` the blocks
    ``l_ij tri(N_j)`` the tagged matrices of the exact node-local precision would have carried."""
    known = relay_records(ex, plan, values, weights)
    n, p, n_tri = measurements.n_nodes, measurements.n_states, up.size
    blocks = np.zeros((ex.n_local, n, n_tri)) if tagged else None
    out = np.zeros((ex.n_local, n_tri + p))
    first: dict[int, tuple[FloatArray, FloatArray]] = {}  # each origin's records (every copy is the same)
    needs = []
    for a, got in enumerate(known):
        need = np.flatnonzero(L_rows[a])
        missing = set(need.tolist()) - set(got)
        if missing:
            raise ModelError(f"relay: node {int(ex.nodes[a])} lacks the records of nodes {sorted(missing)}")
        for j in need.tolist():
            first.setdefault(j, got[j])
        needs.append(need)
    origins = np.array(sorted(first), np.int64)
    decoded = np.zeros((n, n_tri + p))  # one batched rebuild of every origin's normals
    if origins.size:
        N, r = measurements.normals_from_records_of(
            t, origins, np.stack([first[j][0] for j in origins.tolist()]), np.stack([first[j][1] for j in origins])
        )
        decoded[origins] = np.concatenate([N.reshape(origins.size, p * p)[:, up], r], axis=1)
    for a, need in enumerate(needs):
        stacked = decoded if need.size == n else decoded[need]  # every node's row: the same array, no gather
        out[a] = L_rows[a, need] @ stacked
        if blocks is not None:
            blocks[a, need] = L_rows[a, need][:, None] * stacked[:, :n_tri]
    if not with_rows and blocks is None:
        return out
    parts = [out]
    if with_rows:
        parts.append(L_rows)
    if blocks is not None:
        parts.append(blocks.reshape(ex.n_local, n * n_tri))
    return np.concatenate(parts, axis=1)


def _pack(row: FloatArray, records: list[tuple[FloatArray, FloatArray]], slots: int) -> int:
    """Write origin after origin ``[count, (slot, value, weight) × count]`` into ``row``; return the wire bytes."""
    pos, size = 0, 0
    for vals, wts in records:
        idx = np.flatnonzero(wts > 0)
        m = idx.size
        row[pos] = m
        body = row[pos + 1 : pos + 1 + 3 * m].reshape(m, 3)
        body[:, 0], body[:, 1], body[:, 2] = idx, vals[idx], wts[idx]
        pos += 1 + 3 * slots
        size += COUNT_BYTES + RECORD_BYTES * m
    return size


def _unpack(row: FloatArray, n_origins: int, slots: int) -> list[tuple[FloatArray, FloatArray]]:
    """The dense ``(values, weights)`` over the slots of each origin packed in ``row`` by :func:`_pack`."""
    out = []
    for k in range(n_origins):
        pos = k * (1 + 3 * slots)
        m = int(row[pos])
        body = row[pos + 1 : pos + 1 + 3 * m].reshape(m, 3)
        vals, wts = np.zeros(slots), np.zeros(slots)
        idx = body[:, 0].astype(np.int64)
        vals[idx], wts[idx] = body[:, 1], body[:, 2]
        out.append((vals, wts))
    return out
