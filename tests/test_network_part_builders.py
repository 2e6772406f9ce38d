"""Part builders that hold no array over the whole network (network/part_builders.py) and node ranges
(network/partition.py ``NodeRanges``): parts equal to the whole graph's, and under MPI a rank's traced memory."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from distnav.errors import ExchangeError, GraphError
from distnav.network import builders
from distnav.network.graph_part import GraphPart
from distnav.network.part_builders import (
    grid_part,
    radius_for_mean_degree,
    ring_part,
    tiled_random_geometric,
    tiled_random_geometric_part,
)
from distnav.network.partition import NodeRanges, block_ranges, partition_nodes

FIELDS = ("nodes", "in_ptr", "src", "edge_ids", "out_edge_ids", "degree", "halo", "halo_degree")
HERE = Path(__file__).resolve().parent


def assert_same_part(p: GraphPart, q: GraphPart) -> None:
    assert (p.n_nodes, p.n_edges, p.self_loops) == (q.n_nodes, q.n_edges, q.self_loops)
    for f in FIELDS:
        assert np.array_equal(getattr(p, f), getattr(q, f)), f


def _ranges(n: int) -> list[np.ndarray]:
    return [np.arange(0, n // 3), np.arange(n // 3, n), np.arange(n // 2, n // 2 + 1), np.arange(n)]


@pytest.mark.parametrize("self_loops", [False, True])
def test_ring_part_equals_the_part_of_the_whole_ring(self_loops: bool) -> None:
    g = builders.ring(50, self_loops=self_loops)
    for own in [*_ranges(50), np.array([0, 49, 7])]:
        assert_same_part(ring_part(50, own, self_loops=self_loops), GraphPart.from_graph(g, own))


@pytest.mark.parametrize("neighbourhood", [4, 8])
@pytest.mark.parametrize("shape", [(7, 9), (1, 5), (5, 1), (6, 6)])
def test_grid_part_equals_the_part_of_the_whole_grid(shape: tuple[int, int], neighbourhood: int) -> None:
    for self_loops in (False, True):
        g = builders.grid(*shape, neighbourhood=neighbourhood, self_loops=self_loops)
        for own in _ranges(g.n_nodes):
            part = grid_part(*shape, own, neighbourhood=neighbourhood, self_loops=self_loops)
            assert_same_part(part, GraphPart.from_graph(g, own))


@pytest.mark.parametrize(("n", "tile_nodes"), [(1, 4096), (500, 4096), (3000, 64), (20_000, 256)])
def test_tiled_part_equals_the_part_of_the_whole_tiled_graph(n: int, tile_nodes: int) -> None:
    """Every rank's part (its tiles and two rings of tiles around them, the tile offsets counted tile by tile
    without a communicator) is exactly the part of the whole graph drawn tile by tile."""
    radius = radius_for_mean_degree(max(n, 2), 8)
    for self_loops in (False, True):
        g = tiled_random_geometric(n, radius, seed=5, tile_nodes=tile_nodes, self_loops=self_loops)
        for own in _ranges(n) if n > 1 else [np.arange(1)]:
            part = tiled_random_geometric_part(
                n, radius, seed=5, nodes=own, tile_nodes=tile_nodes, self_loops=self_loops
            )
            assert_same_part(part, GraphPart.from_graph(g, own))
    if n >= 3000:  # an honest random geometric graph: mean degree near the requested 8, points in the unit square
        assert 7.0 < g.n_edges / n - 1 < 8.5
        assert g.positions is not None and 0 <= g.positions.min() and g.positions.max() <= 1


def test_tiled_graph_links_exactly_the_pairs_within_the_radius() -> None:
    """A second reference: the links are the point pairs at most ``radius`` apart (brute force)."""
    n, radius = 400, 0.09
    g = tiled_random_geometric(n, radius, seed=2, tile_nodes=16)
    pos = g.positions
    assert pos is not None
    d = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1))
    i, j = np.nonzero(np.triu(d <= radius, 1))
    assert np.array_equal(g.links, np.stack([i, j], 1))


class _Gather:
    """A communicator stand-in: what every rank of a run would contribute to ``allgather``."""

    def __init__(self, contributions: list[object]) -> None:
        self.contributions = contributions

    def allgather(self, sendobj: object) -> list[object]:
        return [sendobj, *self.contributions]


def test_tiled_part_errors_are_clear() -> None:
    with pytest.raises(GraphError, match="radius must be positive"):
        tiled_random_geometric_part(100, -0.5, seed=0, nodes=np.arange(10))
    with pytest.raises(GraphError, match="owned nodes must lie in 0..99"):
        tiled_random_geometric_part(100, 0.1, seed=0, nodes=np.array([100]))
    n = 4000
    r = radius_for_mean_degree(n, 8)
    with pytest.raises(GraphError, match="do not cover the graph"):  # the other ranks sent nothing
        tiled_random_geometric_part(n, r, seed=0, nodes=np.arange(100), tile_nodes=64, comm=_Gather([]))


def test_node_ranges_are_the_block_partition() -> None:
    g = builders.path(10)
    for ranks in (1, 3, 4, 10):
        ranges = block_ranges(10, ranks)
        owner = partition_nodes(g, ranks, "block")
        assert np.array_equal(ranges[np.arange(10)], owner)
        assert np.array_equal(partition_nodes(g, ranks, ranges), owner)
        for r in range(ranks):
            assert np.array_equal(ranges.nodes_of(r), np.flatnonzero(owner == r))
    with pytest.raises(ExchangeError, match="ascending bounds"):
        NodeRanges([0, 5, 5, 10])
    with pytest.raises(ExchangeError, match="some ranks would hold no node"):
        block_ranges(3, 4)
    with pytest.raises(ExchangeError, match="node ranges for 10 nodes on 2 ranks; the run has 10 nodes on 3"):
        partition_nodes(g, 3, NodeRanges([0, 4, 10]))


def _launch(args: list[str], timeout: float) -> subprocess.CompletedProcess[str]:
    local = Path(sys.executable).parent / "mpiexec"
    exe = str(local) if local.exists() else shutil.which("mpiexec")
    if exe is None:
        pytest.fail("mpi4py is installed but no mpiexec was found (pip install mpich)")
    return subprocess.run(
        [exe, "-n", "4", sys.executable, "-m", "mpi4py", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


@pytest.mark.parametrize(("kind", "n_nodes", "per_node_limit"), [("ring", 1_000_000, 1), ("tiled", 600_000, 8)])
def test_no_rank_allocates_an_array_of_the_whole_network(kind: str, n_nodes: int, per_node_limit: int) -> None:
    """Under ``mpiexec -n 4``: rank 0 owns 2,000 nodes, ranks 1–3 a third of the rest each. Each builds its part,
    weights, exchange and mixer and runs three rounds under tracemalloc. Rank 0's traced peak stays below
    ``per_node_limit`` byte(s) per node of the whole network — one boolean (ring) or int64 (tiled graph) array over
    the network would exceed it on its own — and every rank's peak is proportional to the nodes and links it owns
    (the same bytes per owned link on ranks 1–3)."""
    pytest.importorskip("mpi4py.MPI", reason="the mpi extra is not installed")
    proc = _launch([str(HERE / "mpi" / "part_memory.py"), kind, str(n_nodes), "2000"], timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["sum"] > 0
    ranks = out["ranks"]
    assert ranks[0]["owned"] == 2000 and sum(r["owned"] for r in ranks) == n_nodes
    assert ranks[0]["peak_bytes"] < per_node_limit * n_nodes, ranks[0]
    per_edge = [r["peak_bytes"] / r["in_edges"] for r in ranks[1:]]
    assert max(per_edge) < 1.1 * min(per_edge), per_edge
    assert max(per_edge) < 400, per_edge  # bytes per owned in-edge: the part, exchange, weights and mixer
