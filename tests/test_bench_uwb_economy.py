"""The reduction tree of benchmarks/bench_uwb_economy.py (issue 27): the balanced BFS tree is a spanning tree of the
graph as deep as scipy's BFS tree from the same root, with every anchor's parent one level nearer the root, and its
busiest anchor sends no more messages per all-reduction."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import shortest_path

from distnav.network.graph import Graph
from test_benchmark_runner import _load


def test_balanced_tree_sends_2_n_minus_1_messages_and_unloads_the_hub():
    """A hub joined to 12 anchors, each joined to a ring neighbour and to one of 24 outer anchors (ring of 12
    around them): every tree sends 2(n − 1) messages per all-reduction (n − 1 up, n − 1 down); the hub is the root
    either way (it sends one message down to each of its 12 children); the outer anchors, reachable from two
    inner ones each, are spread over the inner ones (each inner anchor 2 children)."""
    bench = _load("bench_uwb_economy")
    inner = np.arange(1, 13)
    outer = np.arange(13, 37)
    links = [(0, i) for i in inner] + [(i, i % 12 + 1) for i in inner]
    links += [(inner[k // 2], o) for k, o in enumerate(outer)] + [
        (inner[(k // 2 + 1) % 12], o) for k, o in enumerate(outer)
    ]
    g = Graph.from_links(37, np.array(links))
    n = g.n_nodes
    for balanced in (True, False):
        sends = bench._tree_sends(g, balanced=balanced)
        assert sends.sum() == 2 * (n - 1)
        assert sends[0] == 12  # the root: no message up
    hops = shortest_path(g.adjacency(), unweighted=True, directed=False, indices=0)
    assert hops.max() == 2
    bal, bfs = bench._tree_sends(g), bench._tree_sends(g, balanced=False)
    assert bal[inner].max() == 3  # one up, two down
    assert bfs[inner].max() > 3  # scipy's BFS gives the first inner anchor both of its outer pairs
