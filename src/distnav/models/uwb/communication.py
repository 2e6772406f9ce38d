"""What gathering every range at one anchor would cost instead of the distributed solve (``uwb solve``'s
communication comparison, issue 13 item 8): split out of :mod:`distnav.models.uwb.field`."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path

from distnav.algorithms.ranging.wire import RANGE_RECORD_BYTES  # two int32 anchor ids + one float64 range
from distnav.errors import ModelError
from distnav.models.uwb.problems import RangingProblem
from distnav.network import gather as network_gather
from distnav.network.graph import Graph

__all__ = [
    "VALUE_BYTES",
    "gathered_up",
    "RANGE_RECORD_BYTES",
    "RANGES_DATA",
    "POSITION_BYTES",
    "gather_cost",
    "range_bytes_per_anchor",
]

#: What :func:`range_bytes_per_anchor` counts, in words (for reports).
RANGES_DATA = f"the ranges ({RANGE_RECORD_BYTES} B each)"
POSITION_BYTES = 8


def gather_cost(problem: RangingProblem) -> dict[str, Any]:
    """Messages and bytes to gather every range at one anchor over the range graph and send the positions back.

    Convergecast along a shortest-path tree to the anchor that minimizes the bytes: every link's record
    (:data:`RANGE_RECORD_BYTES`) travels from the nearer of its two anchors one hop per tree edge, one message
    per tree edge carries a subtree's records; the estimated positions (``dim × 8`` B each) go back the same way.
    """
    lk = problem.links
    n = problem.n_anchors
    g = csr_matrix(
        (np.ones(2 * lk.shape[0]), (np.concatenate([lk[:, 0], lk[:, 1]]), np.concatenate([lk[:, 1], lk[:, 0]]))),
        shape=(n, n),
    )
    hops = shortest_path(g, directed=False, unweighted=True)
    if not np.all(np.isfinite(hops)):
        raise ModelError("the range graph is not connected: no single anchor can gather every range")
    own = np.minimum(hops[:, lk[:, 0]], hops[:, lk[:, 1]])  # sink × link: hops of the link's record
    up = own.sum(axis=1) * RANGE_RECORD_BYTES
    down = hops[:, problem.estimated].sum(axis=1) * problem.dim * POSITION_BYTES
    total = up + down
    sink = int(np.argmin(total))
    return {
        "sink": problem.ids[sink],
        "messages": int(2 * (n - 1)),
        "bytes": int(total[sink]),
        "bytes_ranges": int(up[sink]),
        "bytes_positions": int(down[sink]),
        "record_bytes": RANGE_RECORD_BYTES,
        "links": int(lk.shape[0]),
        "max_hops": int(hops[sink].max()),
    }


def range_bytes_per_anchor(problem: RangingProblem) -> np.ndarray:
    """Bytes of the range records each anchor holds for a fusion centre: every measured pair once, held by its
    lower-numbered anchor (the per-node data of :func:`distnav.network.gather.gather_cost`, issue 27)."""
    held: np.ndarray = np.bincount(problem.links[:, 0], minlength=problem.n_anchors) * RANGE_RECORD_BYTES
    return held


VALUE_BYTES = 8  # one float64 on the wire (an estimate, an offset, a covariance entry)


def gathered_up(
    problem: RangingProblem, *, per_anchor_offsets: bool = False
) -> tuple[Graph, network_gather.GatherCost]:
    """The range graph and the gather of ``models.uwb.field_precision.gathered_precision`` (every anchor's range
    records and estimate, and offset, up a shortest-path tree to the anchor with the fewest hop-bytes): its ``sink``
    is the anchor that computes the σ, and the reliability numbers with it (``models.uwb.reliability``)."""
    graph = Graph.from_links(problem.n_anchors, problem.links)
    up_bytes = range_bytes_per_anchor(problem) + VALUE_BYTES * (problem.dim + (1 if per_anchor_offsets else 0))
    return graph, network_gather.gather_cost(graph, up_bytes)
