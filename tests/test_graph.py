"""Communication graphs: construction, facts, builders, validation errors, networkx interop."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
import scipy.sparse.csgraph as csgraph

from distnav.errors import GraphError, UsageError
from distnav.network import Graph, SwitchingGraph, builders


def test_from_links_stores_both_directions_sorted_by_receiver():
    g = Graph.from_links(4, [(0, 1), (2, 1), (3, 2)])
    assert g.n_links == 3 and g.n_edges == 6
    assert list(zip(g.src.tolist(), g.dst.tolist(), strict=True)) == [(1, 0), (0, 1), (2, 1), (1, 2), (3, 2), (2, 3)]
    assert g.degrees.tolist() == [1, 2, 2, 1]
    assert g.links.tolist() == [[0, 1], [1, 2], [2, 3]]
    assert g.neighbors(1).tolist() == [0, 2]
    assert g.neighbors(1, include_self=True).tolist() == [0, 1, 2]
    assert g.in_ptr.tolist() == [0, 1, 3, 5, 6]


def test_reverse_edge_and_edge_index():
    g = builders.random_geometric(30, 0.3, rng=np.random.default_rng(1))
    rev = g.reverse_edge
    assert np.array_equal(g.src[rev], g.dst) and np.array_equal(g.dst[rev], g.src)
    e = g.edge_index(g.src, g.dst)
    assert np.array_equal(e, np.arange(g.n_edges))
    for h in (builders.random_geometric(3_000, 0.04, rng=np.random.default_rng(2)), builders.ring(7, self_loops=True)):
        rev = h.reverse_edge  # the transpose of the (dst, src) order: every edge's reverse, an involution
        assert np.array_equal(h.src[rev], h.dst) and np.array_equal(h.dst[rev], h.src)
        assert np.array_equal(rev[rev], np.arange(h.n_edges))


def test_self_loops():
    g = builders.ring(5, self_loops=True)
    assert g.n_edges == 15
    assert g.degrees.tolist() == [2] * 5  # self excluded
    assert g.with_self_loops(False).n_edges == 10


def test_adjacency_and_laplacian_match_networkx():
    g = builders.grid(4, 5, neighbourhood=8)
    ref = nx.to_scipy_sparse_array(g.to_networkx(), nodelist=range(g.n_nodes))
    assert (g.adjacency() != ref).nnz == 0
    lap = g.laplacian().toarray()
    assert np.allclose(lap, csgraph.laplacian(ref.toarray().astype(float)))
    assert np.allclose(lap.sum(axis=1), 0)


@pytest.mark.parametrize(
    ("builder", "n_links"),
    [
        (lambda: builders.ring(7), 7),
        (lambda: builders.path(7), 6),
        (lambda: builders.complete(6), 15),
        (lambda: builders.star(6), 5),
        (lambda: builders.grid(3, 4, neighbourhood=4), 3 * 3 + 2 * 4),
        (lambda: builders.grid(3, 4, neighbourhood=8), 3 * 3 + 2 * 4 + 2 * 2 * 3),
        (lambda: builders.ladder(10), 4 + 4 + 5 + 4),
    ],
)
def test_builders_link_counts(builder, n_links):
    g = builder()
    assert g.n_links == n_links
    assert g.is_connected


def test_ladder_degree_at_most_five():
    g = builders.ladder(100, spacing_m=10.0)
    assert g.degrees.max() <= 5
    assert g.positions is not None and g.positions.shape == (100, 2)


def test_random_geometric_matches_bruteforce():
    rng = np.random.default_rng(3)
    g = builders.random_geometric(60, 0.2, rng=rng)
    pos = g.positions
    d = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    i, j = np.nonzero(np.triu(d < 0.2, 1))
    assert g.links.tolist() == sorted([a, b] for a, b in zip(i.tolist(), j.tolist(), strict=True))


def test_connected_random_geometric_mean_degree():
    g = builders.connected_random_geometric(2000, mean_degree=8, rng=np.random.default_rng(0))
    assert g.is_connected
    assert 6.0 < g.degrees.mean() < 8.5  # boundary effects lower it slightly


def test_point_options_object_and_keywords_build_the_same_graph():
    """PointOptions in the house style (distnav._settings): the object, keyword changes or both give the same
    points; the points lie in [0, size]^dim (checked here, not by the builder); bad values are refused by name."""
    opts = builders.PointOptions(dim=3, size=50.0)
    a = builders.random_geometric(40, 15.0, rng=np.random.default_rng(4), dim=3, size=50.0)
    b = builders.random_geometric(40, 15.0, rng=np.random.default_rng(4), options=opts)
    c = builders.random_geometric(
        40, 15.0, rng=np.random.default_rng(4), options=builders.PointOptions(dim=3), size=50.0
    )
    for g in (b, c):
        np.testing.assert_array_equal(g.positions, a.positions)
        assert g.links.tolist() == a.links.tolist()
    assert a.positions is not None and a.positions.shape == (40, 3)
    assert a.positions.min() >= 0.0 and a.positions.max() <= 50.0 and a.positions.max() > 25.0
    with pytest.raises(UsageError, match="PointOptions has no option 'sise'.*did you mean 'size'"):
        builders.random_geometric(5, 0.5, rng=np.random.default_rng(0), sise=2.0)
    with pytest.raises(GraphError, match="size must be a finite number > 0"):
        builders.PointOptions(size=0.0)
    with pytest.raises(GraphError, match="dim"):
        builders.connected_random_geometric(10, mean_degree=3, rng=np.random.default_rng(0), dim=0)


def test_k_nearest_each_node_has_at_least_k():
    pos = np.random.default_rng(2).uniform(size=(40, 2))
    g = builders.k_nearest(pos, 4)
    assert g.degrees.min() >= 4


def test_networkx_roundtrip_keeps_names_and_positions():
    g = builders.grid(2, 3, spacing_m=10.0)
    h = Graph.from_networkx(g.to_networkx())
    assert h.links.tolist() == g.links.tolist()
    assert np.allclose(h.positions, g.positions)
    named = builders.from_edges([("a", "b"), ("b", "c")])
    assert named.names == ("a", "b", "c")
    assert Graph.from_networkx(named.to_networkx()).n_links == 2


def test_from_edges_refuses_what_is_not_pairs():
    with pytest.raises(GraphError, match=r"pairs \(shape \(n_edges, 2\)\), got shape \(4,\)"):
        builders.from_edges(np.array([0, 1, 1, 2]))
    with pytest.raises(GraphError, match=r"got shape \(2, 3\)"):
        builders.from_edges(np.array([(0, 1, 2), (1, 2, 3)]))
    with pytest.raises(GraphError, match=r"edge #1 is \(1, 2, 3\), not a pair"):
        builders.from_edges([(0, 1), (1, 2, 3)])  # type: ignore[list-item]
    with pytest.raises(GraphError, match="edge #0 is 0, not a pair"):
        builders.from_edges([0, 1, 1, 2])  # type: ignore[list-item]


def test_from_edges_with_names_and_ids():
    g = builders.from_edges([(0, 1), (1, 2)])
    assert g.n_nodes == 3
    assert g.node_id("2") == 2
    with pytest.raises(GraphError, match="no node named 'x'"):
        g.node_id("x")
    with pytest.raises(GraphError, match="'z'"):
        builders.from_edges([("a", "z")], names=["a", "b"])


@pytest.mark.parametrize(
    ("links", "n", "match"),
    [
        ([(0, 5)], 3, "outside 0..2"),
        ([(-1, 1)], 3, "outside 0..2"),
        ([(1, 1)], 3, "joins node 1 to itself"),
        ([(0, 1), (1, 0)], 3, r"link \(0, 1\) is listed 2 times"),
        ([(0, 1, 2)], 3, "shape"),
        ([(0.5, 1)], 3, "integer"),
    ],
)
def test_from_links_errors(links, n, match):
    with pytest.raises(GraphError, match=match):
        Graph.from_links(n, links)


def test_other_construction_errors():
    with pytest.raises(GraphError, match="at least one node"):
        Graph.from_links(0, [])
    with pytest.raises(GraphError, match="names"):
        Graph.from_links(2, [(0, 1)], names=["a"])
    with pytest.raises(GraphError, match="used twice"):
        Graph.from_links(2, [(0, 1)], names=["a", "a"])
    with pytest.raises(GraphError, match="positions"):
        Graph.from_links(2, [(0, 1)], positions=np.zeros((3, 2)))
    with pytest.raises(GraphError, match="not finite"):
        Graph.from_links(2, [(0, 1)], positions=np.array([[0.0, np.nan], [1, 1]]))
    with pytest.raises(GraphError, match="neighbourhood"):
        builders.grid(3, 3, neighbourhood=6)
    with pytest.raises(GraphError, match="even"):
        builders.ladder(7)
    with pytest.raises(GraphError, match="radius"):
        builders.random_geometric(5, 0.0, rng=np.random.default_rng(0))
    with pytest.raises(GraphError, match="k must be"):
        builders.k_nearest(np.zeros((4, 2)), 4)
    with pytest.raises(GraphError, match=r"\(0, 2\) is not an edge"):
        builders.path(3).edge_index(0, 2)
    with pytest.raises(GraphError, match="outside"):
        builders.path(3).neighbors(3)
    with pytest.raises(GraphError, match="at least 3"):
        builders.ring(2)


def test_require_connected_names_unreachable_nodes():
    g = Graph.from_links(5, [(0, 1), (1, 2), (3, 4)], names=list("abcde"))
    assert not g.is_connected
    with pytest.raises(GraphError, match="nodes d, e are unreachable from node a"):
        g.require_connected()


def test_switching_graph_union_and_masks():
    s1 = Graph.from_links(4, [(0, 1), (2, 3)])
    s2 = Graph.from_links(4, [(1, 2)])
    sw = SwitchingGraph((s1, s2))
    assert sw.union.n_links == 3
    m1, m2 = sw.session_edge_masks
    assert m1.sum() == 4 and m2.sum() == 2 and not (m1 & m2).any()
    assert sw.session(3) is s2
    with pytest.raises(GraphError, match="union of the sessions is not connected: nodes 3"):
        SwitchingGraph((Graph.from_links(4, [(0, 1)]), Graph.from_links(4, [(1, 2)])))
    with pytest.raises(GraphError, match="session 1 has 3 nodes"):
        SwitchingGraph((s1, Graph.from_links(3, [(0, 1), (1, 2)])))
    with pytest.raises(GraphError, match="at least one session"):
        SwitchingGraph(())


def test_partition_file_round_trip_and_errors(tmp_path):
    from distnav.errors import ExchangeError
    from distnav.formats.partition import write_partition
    from distnav.network.partition import partition_nodes, read_partition

    g = builders.path(8)
    owner = partition_nodes(g, 3, "rcm")
    for name in ("owner.npy", "owner.txt"):
        path = write_partition(tmp_path / name, owner)
        assert np.array_equal(partition_nodes(g, 3, path), owner)
        assert np.array_equal(partition_nodes(g, 3, str(path)), owner)
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n0\n1\nx\n")
    with pytest.raises(ExchangeError, match=r"bad.txt, line 4: 'x' is not an integer rank"):
        read_partition(bad, 8, 3)
    with pytest.raises(ExchangeError, match="gives ranks for 8 nodes, the graph has 9"):
        read_partition(tmp_path / "owner.txt", 9, 3)
    with pytest.raises(ExchangeError, match=r"node 0 is given rank 2, outside 0..1 \(2 ranks launched\)"):
        read_partition(write_partition(tmp_path / "o2.npy", np.full(8, 2)), 8, 2)
    with pytest.raises(ExchangeError, match="does not exist"):
        partition_nodes(g, 3, tmp_path / "missing.npy")
    flat_2d = tmp_path / "owner2d.npy"
    np.save(flat_2d, np.zeros((2, 4), dtype=np.int64))  # 8 ranks, but not one per node: refused, not flattened
    with pytest.raises(ExchangeError, match=r"a 1-D array\), got shape \(2, 4\)"):
        read_partition(flat_2d, 8, 3)


@pytest.mark.parametrize("self_loops", [False, True])
@pytest.mark.parametrize("n_nodes, n_links", [(1, 0), (2, 1), (7, 0), (30, 60), (200, 900)])
def test_from_links_edge_order_matches_a_sorted_list(n_nodes: int, n_links: int, self_loops: bool) -> None:
    # the counting placement against the definition: both directions of every link (and i→i), sorted by (dst, src)
    rng = np.random.default_rng(n_nodes + n_links)
    pairs = (
        {tuple(sorted(map(int, rng.choice(n_nodes, 2, replace=False)))) for _ in range(n_links)}
        if n_nodes > 1
        else set()
    )
    links = [(j, i) if rng.random() < 0.5 else (i, j) for i, j in pairs]  # either order, as given
    g = Graph.from_links(n_nodes, np.array(links, dtype=np.int64).reshape(-1, 2), self_loops=self_loops)
    want = sorted(
        {(d, s) for i, j in pairs for s, d in ((i, j), (j, i))}
        | ({(i, i) for i in range(n_nodes)} if self_loops else set())
    )
    assert g.dst.tolist() == [d for d, _ in want]
    assert g.src.tolist() == [s for _, s in want]
    assert g.src.dtype == g.dst.dtype == np.int64


def test_from_links_merges_repeats_only_when_asked() -> None:
    links = np.array([[0, 1], [2, 1], [1, 0], [1, 2], [1, 2], [3, 0]])
    with pytest.raises(GraphError, match=r"link \(0, 1\) is listed 2 times"):
        Graph.from_links(4, links)
    g = Graph.from_links(4, links, allow_duplicates=True)
    assert g.links.tolist() == [[0, 1], [0, 3], [1, 2]]
    assert g.names == ("0", "1", "2", "3")
