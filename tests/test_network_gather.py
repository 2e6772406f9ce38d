"""network.gather: the fusion-centre yardstick, checked against networkx shortest paths and hand-counted cases."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from distnav.errors import GraphError
from distnav.network import builders
from distnav.network.gather import gather_cost


def test_path_graph_counted_by_hand():
    g = builders.path(4)  # 0 - 1 - 2 - 3, 10 bytes each, sink 0
    c = gather_cost(g, [10, 10, 10, 10], sink=0)
    assert c.total_hop_bytes == 10 * (0 + 1 + 2 + 3)
    assert c.messages == 6 and c.tree_messages == 3
    assert c.relay_bytes.tolist() == [0, 30, 20, 10]
    assert c.busiest_relay_bytes == 30 and c.busiest_relay == 1
    best = gather_cost(g, [10, 10, 10, 10])
    assert best.sink in (1, 2) and best.total_hop_bytes == 40  # the median of a path


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_against_networkx_shortest_paths(seed):
    rng = np.random.default_rng(seed)
    g = builders.connected_random_geometric(60, mean_degree=8, rng=rng)
    data = rng.integers(1, 500, size=60)
    G = nx.Graph()
    G.add_nodes_from(range(60))
    G.add_edges_from(map(tuple, np.asarray(g.links)))
    totals = {}
    for s in range(60):
        hops = nx.single_source_shortest_path_length(G, s)
        totals[s] = sum(int(data[v]) * h for v, h in hops.items())
    c = gather_cost(g, data)
    assert c.total_hop_bytes == min(totals.values())
    assert totals[c.sink] == c.total_hop_bytes
    # every node's relay load is its own data plus its subtree's: the sink's neighbours carry everything
    nbrs = g.neighbors(c.sink)
    assert c.relay_bytes[nbrs].sum() == data.sum() - data[c.sink]
    assert c.relay_bytes[c.sink] == 0


def test_disconnected_nodes_are_counted_not_gathered():
    g = builders.from_edges([(0, 1), (1, 2), (3, 4)], n_nodes=5)
    c = gather_cost(g, [1, 1, 1, 1, 1])
    assert c.unreachable == 2 and c.total_bytes == 3


@pytest.mark.parametrize("bad", [[1, 2], [1, -1, 1, 1], [1, np.nan, 1, 1], [1j, 1, 1, 1]])
def test_bad_bytes_are_refused(bad):
    with pytest.raises(GraphError):
        gather_cost(builders.path(4), bad)
