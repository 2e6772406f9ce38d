"""The reduction tree of benchmarks/bench_uwb_economy.py (issue 27): the balanced BFS tree is a spanning tree of the
graph as deep as scipy's BFS tree from the same root, with every anchor's parent one level nearer the root, and its
busiest anchor sends no more messages per all-reduction."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import shortest_path

from distnav.network.graph import Graph
from test_benchmark_runner import _load


def _hub() -> Graph:
    inner = np.arange(1, 13)
    outer = np.arange(13, 37)
    links = [(0, i) for i in inner] + [(i, i % 12 + 1) for i in inner]
    links += [(inner[k // 2], o) for k, o in enumerate(outer)]
    links += [(inner[(k // 2 + 1) % 12], o) for k, o in enumerate(outer)]
    return Graph.from_links(37, np.array(links))


def test_balanced_tree_sends_2_n_minus_1_messages_and_unloads_the_hub():
    """A hub joined to 12 anchors, each joined to its ring neighbours and to 4 of 24 outer anchors (each outer
    anchor to two inner ones): every tree sends 2(n − 1) messages per all-reduction (n − 1 up, n − 1 down). From
    the centre (the hub) scipy's BFS tree makes the hub send one message to each of its 12 neighbours; the balanced
    tree roots at an anchor of the lowest degree near the hub and spreads the children: its busiest anchor (the
    hub still, the only parent of the inner anchors two ring steps from the root) sends 7."""
    bench = _load("bench_uwb_economy")
    g = _hub()
    n = g.n_nodes
    hops = shortest_path(g.adjacency(), unweighted=True, directed=False, indices=0)
    assert hops.max() == 2
    bal, bfs = bench._tree_sends(g, "balanced"), bench._tree_sends(g, "bfs")
    for sends in (bal, bfs):
        assert sends.sum() == 2 * (n - 1)
    assert bfs[0] == bfs.max() == 12  # the root: no message up, one down to each neighbour
    assert bal.max() == bal[0] == 7


def test_capped_tree_is_a_spanning_tree_whose_anchors_send_at_most_three_messages():
    """The capped tree (fifth session) on the hub graph above and on a 400-anchor geometric graph: every anchor's
    parent is a neighbour, following parents reaches the root (no cycle), 2(n − 1) messages per all-reduction, and
    its busiest anchor sends fewer than the balanced tree's, and on the geometric graph no more than 3 (2 children
    and one up)."""
    bench = _load("bench_uwb_economy")
    rng = np.random.default_rng(5)
    pts = rng.uniform(0.0, 100.0, (400, 2))
    a, b = np.triu_indices(400, 1)
    close = np.linalg.norm(pts[a] - pts[b], axis=1) < 12.0
    geo = Graph.from_links(400, np.stack([a[close], b[close]], 1))
    assert geo.is_connected
    for g in (_hub(), geo):
        n = g.n_nodes
        parent, root = bench._tree_parents(g, "capped")
        adj = g.adjacency().toarray() > 0
        others = np.flatnonzero(np.arange(n) != root)
        assert parent[root] == -1 and np.all(adj[others, parent[others]])
        for v in others:  # the parents lead to the root within n steps
            steps = 0
            while v != root and steps <= n:
                v, steps = parent[v], steps + 1
            assert v == root
        sends = bench._tree_sends(g, "capped")
        assert sends.sum() == 2 * (n - 1)
        assert sends.max() < bench._tree_sends(g, "balanced").max()
    assert sends.max() <= 3  # the geometric graph: 24 outer hub anchors on 12 inner ones force 4 above


def test_per_anchor_bytes_spread_each_lm_phase_s_reductions_over_its_tree():
    """``_per_anchor_bytes`` (review of item 37, finding 5): an LM phase's reductions (30 B) go to the anchors of its
    reduction tree (the 3 that take part: 10 B each), the rest of the total beyond the counted messages (8 B: a
    central σ's reductions) to all 4 — by hand: 12, 22, 22, 22 B (spread over all 4 they read 19.5 B each)."""
    from types import SimpleNamespace

    bench = _load("bench_uwb_economy")
    bench._SENT.append(np.full(4, 10.0))
    bench._TREES.append((np.array([False, True, True, True]), 30.0))
    per = bench._per_anchor_bytes(SimpleNamespace(n_anchors=4), SimpleNamespace(bytes=40 + 30 + 8))
    assert per.tolist() == [12.0, 22.0, 22.0, 22.0]
    assert not bench._TREES and not bench._SENT
