"""Graph parts: what one MPI rank builds of a graph it never holds whole (network/graph_part.py)."""

from __future__ import annotations

import numpy as np
import pytest

from distnav.errors import ExchangeError, GraphError, WeightsError
from distnav.exchange import make_exchange
from distnav.network import builders, consensus_weights
from distnav.network.graph_part import GraphPart, edge_starts_from_degrees, owned_rows
from distnav.network.partition import partition_nodes
from distnav.network.weights import part_weights

FIELDS = ("nodes", "in_ptr", "src", "edge_ids", "out_edge_ids", "degree", "halo", "halo_degree")


@pytest.mark.parametrize("self_loops", [False, True])
@pytest.mark.parametrize("n", [1, 40, 3000])
def test_geometric_part_equals_the_part_of_the_whole_graph(n: int, self_loops: bool) -> None:
    """random_geometric_part (links found around the owned nodes and halo only) holds exactly the part that
    GraphPart.from_graph cuts out of random_geometric's whole graph: the same links and global edge ids."""
    radius = float(np.sqrt(8 / (np.pi * n)))
    g = builders.random_geometric(n, radius, rng=np.random.default_rng(3), self_loops=self_loops)
    for own in (np.arange(n // 3, (2 * n) // 3 + 1), np.random.default_rng(1).permutation(n)[: max(1, n // 4)]):
        p = builders.random_geometric_part(n, radius, rng=np.random.default_rng(3), nodes=own, self_loops=self_loops)
        q = GraphPart.from_graph(g, own)
        assert p.n_edges == g.n_edges and p.n_nodes == n
        for f in FIELDS:
            assert np.array_equal(getattr(p, f), getattr(q, f)), f


def test_from_graph_against_the_graph_itself() -> None:
    """Independent of the part code: each in-edge is (src → dst) of the graph and its reverse id is (dst → src)."""
    g = builders.connected_random_geometric(300, mean_degree=9, rng=np.random.default_rng(2))
    own = np.array([5, 17, 18, 200, 299])
    p = GraphPart.from_graph(g, own[::-1])
    assert np.array_equal(p.nodes, own)
    assert np.array_equal(g.src[p.edge_ids], p.src) and np.array_equal(g.dst[p.edge_ids], p.dst)
    assert np.array_equal(g.src[p.out_edge_ids], p.dst) and np.array_equal(g.dst[p.out_edge_ids], p.src)
    assert np.array_equal(p.degree, g.degrees[own])
    expected_halo = sorted({int(s) for s in p.src} - set(own.tolist()))
    assert p.halo.tolist() == expected_halo
    assert np.array_equal(p.sender_degree(), g.degrees[p.src])


@pytest.mark.parametrize("protocol", ["MH", "P3", "P2"])
def test_part_weights_equal_the_whole_graphs_bit_for_bit(protocol: str) -> None:
    g = builders.connected_random_geometric(500, mean_degree=7, rng=np.random.default_rng(5))
    p = GraphPart.from_graph(g, np.arange(100, 260))
    w, wp = consensus_weights(g, protocol), part_weights(p, protocol)
    assert np.array_equal(wp.edge_weight, w.edge_weight[p.edge_ids])
    assert np.array_equal(wp.self_weight, w.self_weight[p.nodes])
    with pytest.raises(WeightsError, match="needs the whole graph"):
        part_weights(p, "Koppanyi")


def test_part_errors_are_clear() -> None:
    g = builders.path(5)
    with pytest.raises(GraphError, match="node ids must lie in 0..4"):
        GraphPart.from_graph(g, np.array([7]))
    start = edge_starts_from_degrees(g.degrees)
    # node 2's list is short: its degree says 2 neighbours
    with pytest.raises(GraphError, match="node 2 has 1 entries"):
        GraphPart.from_neighbours(5, np.array([2]), np.array([2, 1, 1, 3]), np.array([1, 2, 0, 4]), start)
    with pytest.raises(GraphError, match="listed twice"):
        GraphPart.from_neighbours(5, np.array([2]), np.array([2, 2, 2]), np.array([1, 1, 3]), start)
    with pytest.raises(GraphError, match="halo node's neighbour list is missing"):
        GraphPart.from_neighbours(5, np.array([2]), np.array([2, 2]), np.array([1, 3]), start)
    with pytest.raises(ExchangeError, match="needs the whole graph, not a graph part"):
        make_exchange(GraphPart.from_graph(g, np.arange(5)))
    with pytest.raises(ExchangeError, match="'rcm' needs the whole graph"):
        partition_nodes(GraphPart.from_graph(g, np.arange(5)), 2, "rcm")
    assert partition_nodes(GraphPart.from_graph(g, np.arange(5)), 2, "block").tolist() == [0, 0, 0, 1, 1]


def test_single_rank_exchange_on_a_part_equals_the_whole_graph() -> None:
    """An MPI exchange on one rank (COMM_SELF) built from a part holding every node gives the in-process numbers;
    it has no whole graph, and a part that does not match the partition is refused."""
    mpi = pytest.importorskip("mpi4py.MPI", reason="the mpi extra is not installed")
    from distnav.exchange import FaultSchedule

    n = 400
    g = builders.random_geometric(n, 0.09, rng=np.random.default_rng(8))
    part = builders.random_geometric_part(n, 0.09, rng=np.random.default_rng(8), nodes=np.arange(n))
    faults = FaultSchedule(drop_probability=0.2, seed=3)
    ex = make_exchange(part, backend="mpi", faults=faults, partition=np.zeros(n, int), comm=mpi.COMM_SELF)
    ref = make_exchange(g, faults=faults)
    x0 = np.random.default_rng(2).normal(size=(n, 2))
    x, y = ex.local(x0), ref.local(x0)
    m, mr = ex.mixer(part_weights(part, "MH")), ref.mixer(consensus_weights(g, "MH"))
    for _ in range(8):
        x, y = m.apply(x), mr.apply(y)
    assert np.array_equal(ex.gather_nodes(x), ref.gather_nodes(y))
    assert np.array_equal(ex.comm_totals().messages_received, ref.comm_totals().messages_received)
    assert ex.part is part
    with pytest.raises(ExchangeError, match="built from a graph part"):
        _ = ex.graph
    with pytest.raises(ExchangeError, match="holds other nodes than the partition"):
        make_exchange(
            GraphPart.from_graph(g, np.arange(n // 2)), backend="mpi", partition=np.zeros(n, int), comm=mpi.COMM_SELF
        )
    with pytest.raises(ExchangeError, match="needs the partition the parts were built from"):
        make_exchange(part, backend="mpi", comm=mpi.COMM_SELF)
    ex.free()


@pytest.mark.parametrize("own", [np.arange(40, 90), np.array([3, 7, 8, 20, 41, 42, 43, 99]), np.zeros(0, np.int64)])
def test_owned_rows_is_a_binary_search_over_the_owned_ids(own) -> None:
    """The range fast path (a subtraction) and the general one give what a binary search gives: the position of every
    owned id and whether each id is owned."""
    ids = np.random.default_rng(2).integers(0, 120, size=500).astype(np.int32)
    k, mine = owned_rows(own, ids)
    assert np.array_equal(mine, np.isin(ids, own))
    assert np.array_equal(own[k[mine]], ids[mine])
    assert k.dtype == np.int64 and (k >= 0).all() and (own.size == 0 or (k < own.size).all())
