"""The reduction tree of benchmarks/bench_uwb_economy.py (issue 27): the balanced BFS tree is a spanning tree of the
graph as deep as scipy's BFS tree from the same root, with every anchor's parent one level nearer the root, and its
busiest anchor sends no more messages per all-reduction."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import shortest_path

from distnav.network.graph import Graph
from test_benchmark_runner import _load


def test_balanced_tree_sends_2_n_minus_1_messages_and_unloads_the_hub():
    """A hub joined to 12 anchors, each joined to its ring neighbours and to 4 of 24 outer anchors (each outer
    anchor to two inner ones): every tree sends 2(n − 1) messages per all-reduction (n − 1 up, n − 1 down). From
    the centre (the hub) scipy's BFS tree makes the hub send one message to each of its 12 neighbours; the balanced
    tree roots at an anchor of the lowest degree near the hub and spreads the children: its busiest anchor (the
    hub still, the only parent of the inner anchors two ring steps from the root) sends 7."""
    bench = _load("bench_uwb_economy")
    inner = np.arange(1, 13)
    outer = np.arange(13, 37)
    links = [(0, i) for i in inner] + [(i, i % 12 + 1) for i in inner]
    links += [(inner[k // 2], o) for k, o in enumerate(outer)]
    links += [(inner[(k // 2 + 1) % 12], o) for k, o in enumerate(outer)]
    g = Graph.from_links(37, np.array(links))
    n = g.n_nodes
    hops = shortest_path(g.adjacency(), unweighted=True, directed=False, indices=0)
    assert hops.max() == 2
    bal, bfs = bench._tree_sends(g), bench._tree_sends(g, balanced=False)
    for sends in (bal, bfs):
        assert sends.sum() == 2 * (n - 1)
    assert bfs[0] == bfs.max() == 12  # the root: no message up, one down to each neighbour
    assert bal.max() == bal[0] == 7
