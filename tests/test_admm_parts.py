"""ADMM on graph parts (issue 30 item 2): the part rule's constraint nodes cover the whole graph; under MPI each rank
builds only its part and the run is bitwise the in-process run on the whole graph with the same constraint nodes; a
rank that owns few nodes allocates nothing of the whole network's size."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from distnav.algorithms.lsq.admm import iterate_admm
from distnav.algorithms.lsq.blue import LinearProblem
from distnav.algorithms.lsq.on_part import iterate_admm_on_part
from distnav.errors import ExchangeError, ModelError
from distnav.exchange import make_exchange
from distnav.network import builders
from distnav.network.constraint_nodes import part_cover
from distnav.network.graph_part import GraphPart
from distnav.network.part_builders import radius_for_mean_degree, tiled_random_geometric

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "mpi"))
from admm_parts import GRAPH_SEED, MEAN_DEGREE, TILE_NODES, bounds_for, problem_rows  # noqa: E402


def _union_cover(graph, bounds):
    return np.concatenate(
        [
            part_cover(GraphPart.from_graph(graph, np.arange(lo, hi)))
            for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)
        ]
    )


@pytest.mark.parametrize("ranks", [1, 2, 3, 7])
@pytest.mark.parametrize("kind", ["path", "grid", "tiled"])
def test_part_rule_covers_every_link(kind, ranks):
    if kind == "path":
        g = builders.path(50)
    elif kind == "grid":
        g = builders.grid(9, 7)
    else:
        g = tiled_random_geometric(1_500, radius_for_mean_degree(1_500, 8), seed=2, tile_nodes=64)
    inC = _union_cover(g, bounds_for(g.n_nodes, ranks, 0))
    a, b = g.links[:, 0], g.links[:, 1]
    assert (inC[a] | inC[b]).all()
    assert inC.sum() < g.n_nodes  # a cover, not every node


@pytest.mark.parametrize("ranks", [2, 3, 7])
def test_part_rule_does_not_depend_on_the_split(ranks):
    """The rule reads only ids: the ranks' parts together choose what one part holding every node chooses."""
    g = builders.connected_random_geometric(400, mean_degree=8, rng=np.random.default_rng(3))
    whole = part_cover(GraphPart.from_graph(g, np.arange(g.n_nodes)))
    assert np.array_equal(_union_cover(g, bounds_for(g.n_nodes, ranks, 0)), whole)
    # the nodes left out are exactly the local minima of the hash (an independent set, checked by brute force)
    h = np.array([hash_of(i) for i in range(g.n_nodes)])
    minima = np.array([all(h[i] < h[j] for j in g.neighbors(i, include_self=False)) for i in range(g.n_nodes)])
    assert np.array_equal(~whole, minima)


def hash_of(i: int) -> int:
    """SplitMix64's finalizer in Python integers (an independent implementation of the rule's hash)."""
    mask = (1 << 64) - 1
    z = (i + 0x9E3779B97F4A7C15) & mask
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & mask
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & mask
    return z ^ (z >> 31)


def _one_rank_part(n_side: int = 12):
    """An MPI exchange of one rank (mpi4py's singleton) on the part holding a whole 8-neighbour grid."""
    pytest.importorskip("mpi4py", reason="the mpi extra is not installed")
    from distnav.network.part_builders import grid_part
    from distnav.network.partition import block_ranges

    n = n_side * n_side
    part = grid_part(n_side, n_side, np.arange(n), neighbourhood=8)
    return part, make_exchange(part, backend="mpi", partition=block_ranges(n, 1))


def test_one_part_holding_every_node_is_the_inprocess_run():
    part, ex = _one_rank_part()
    g = builders.grid(12, 12, neighbourhood=8)
    A, y = problem_rows(0, g.n_nodes)
    prob = LinearProblem.from_stacked(A, y)
    ours = iterate_admm_on_part(prob, ex, W=2.0)
    C = np.flatnonzero(part_cover(part))
    ref = iterate_admm(prob, g, constraint_nodes=C, W=2.0, messages="aggregated", exchange=make_exchange(g))
    for _ in range(20):
        a, b = next(ours), next(ref)
    assert np.array_equal(a.x, b.x[ex.nodes])
    assert a.primal_residual == pytest.approx(b.primal_residual, rel=1e-12)


@pytest.mark.parametrize("order", ["none", "rcm"])
def test_exchange_on_a_part_holds_no_copy_of_its_edge_arrays_in_the_parts_order(order):
    """In the part's own order the exchange's in-edge arrays *are* the part's (no permuted copy), the rows a send
    moves inside the block are made at the first edge send only, and every message still arrives on its edge (a
    value equal to its edge id, in both orders)."""
    part, _ = _one_rank_part()
    from distnav.network.partition import block_ranges

    ex = make_exchange(part, backend="mpi", partition=block_ranges(part.n_nodes, 1), order=order)
    shared = ex.in_src is part.src and ex.in_edges is part.edge_ids and ex.nodes is part.nodes
    assert shared == (order == "none")
    assert ex.in_src.dtype == part.src.dtype == np.int32 and ex.out_dst.dtype == np.int32
    assert ex._local_move_rows is None
    inbox = ex.send(ex.out_edges.astype(float))
    assert ex._local_move_rows is not None
    assert inbox.delivered.all() and np.array_equal(inbox.values, ex.in_edges.astype(float))
    rows = ex.part_rows()[0]
    assert np.array_equal(part.edge_ids[rows], ex.in_edges)  # the part position of every local in-edge


@pytest.mark.parametrize("self_loops", [False, True])
def test_exchange_on_a_part_makes_its_out_edge_tables_when_read(self_loops):
    """An exchange built from a part holds no out-edge tables after its set-up (made from the in-edges: every link
    is stored both ways), nor after the aggregated ADMM's set-up and iterations; read, they are the block's
    out-edges as the whole graph's own arrays list them, and its counts are the graph's. The real-edge masks are a
    broadcast True only without self-loops."""
    pytest.importorskip("mpi4py", reason="the mpi extra is not installed")
    from distnav.exchange.mixer import Mixer
    from distnav.network.partition import block_ranges

    g = builders.connected_random_geometric(40, mean_degree=5, rng=np.random.default_rng(4), self_loops=self_loops)
    part = GraphPart.from_graph(g, np.arange(40))  # (mpi4py's singleton: one rank holds every node)
    ex = make_exchange(part, backend="mpi", partition=block_ranges(40, 1), order="none")
    assert ex._out is None and ex._edge_send is None
    real = g.src != g.dst
    assert ex._all_sent is ex._all_recv and np.array_equal(ex._all_sent, np.bincount(g.dst[real], minlength=40))
    assert (ex._real_in.strides == (0,)) != self_loops and np.array_equal(ex._real_in, real[ex.in_edges])
    A, y = np.ones((40, 2, 1)), np.arange(80.0).reshape(40, 2)
    prob = LinearProblem.from_stacked(A, y)
    states = iterate_admm_on_part(prob, ex, W=1.0)
    C = np.flatnonzero(part_cover(part))
    g_ex = make_exchange(g)
    ref = iterate_admm(prob, g, constraint_nodes=C, W=1.0, messages="aggregated", exchange=g_ex)
    for _ in range(3):
        a, b = next(states), next(ref)
    assert np.array_equal(a.x, b.x) and ex._out is None
    # the rounds' counts come from the in-edges: the same messages as the in-process run counts
    ours, theirs = ex.comm_totals(), g_ex.comm_totals()
    assert np.array_equal(ours.messages_sent, theirs.messages_sent) and ours.messages > 0
    assert np.array_equal(ours.messages_received, theirs.messages_received)
    assert np.array_equal(ex.out_edges, np.arange(g.n_edges))  # the whole graph's edges, global order
    assert np.array_equal(ex.out_src, g.src) and np.array_equal(ex.out_dst, g.dst)
    with pytest.raises(ExchangeError, match="without its out-edge mask needs its counts"):
        Mixer(ex, np.ones(part.n_local_edges), np.ones(10), (np.ones(part.n_local_edges, bool), None))


def test_refusals_name_the_problem():
    g = builders.ring(12)
    prob = LinearProblem.from_stacked(np.ones((12, 1, 1)), np.ones((12, 1)))
    with pytest.raises(ModelError, match="built from a graph part"):
        iterate_admm_on_part(prob, make_exchange(g))
    part, ex = _one_rank_part()
    A, y = problem_rows(0, part.n_local)
    prob = LinearProblem.from_stacked(A, y)
    with pytest.raises(ModelError, match="the problem has 143 nodes, this rank's part 144"):
        iterate_admm_on_part(LinearProblem.from_stacked(A[1:], y[1:]), ex)
    with pytest.raises(ModelError, match="only messages='aggregated'"):
        iterate_admm_on_part(prob, ex, messages="pairs")
    with pytest.raises(ModelError, match="boolean mask over the part's 144 nodes"):
        iterate_admm_on_part(prob, ex, constraint_nodes=[1, 2])
    with pytest.raises(ModelError, match="init on a graph part"):
        iterate_admm_on_part(prob, ex, init=np.ones((144, 3)))


def _launch(tmp_path: Path, n: int, small: int, iterations: int, seed: int = GRAPH_SEED) -> list[dict]:
    """Run ``tests/mpi/admm_parts.py`` on 2 ranks; each rank's arrays."""
    pytest.importorskip("mpi4py", reason="the mpi extra is not installed")
    local = Path(sys.executable).parent / "mpiexec"
    exe = str(local) if local.exists() else (shutil.which("mpiexec") or pytest.skip("no mpiexec"))
    out = tmp_path / f"parts{n}"
    script = [sys.executable, "-m", "mpi4py", str(HERE / "mpi" / "admm_parts.py")]
    cmd = [exe, "-n", "2", *script, str(n), str(small), str(iterations), str(out), str(seed)]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=240, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = []
    for r in range(2):
        with np.load(f"{out}.{r}.npz") as data:
            rows.append({k: data[k] for k in data.files})
    return rows


@pytest.mark.mpi
def test_admm_on_parts_equals_the_inprocess_run(tmp_path):
    n, iterations = 3_000, 30
    ranks = _launch(tmp_path, n, 0, iterations)
    g = tiled_random_geometric(n, radius_for_mean_degree(n, MEAN_DEGREE), seed=GRAPH_SEED, tile_nodes=TILE_NODES)
    assert g.is_connected
    A, y = problem_rows(0, n)
    inC = _union_cover(g, bounds_for(n, 2, 0))
    ex = make_exchange(g)
    states = iterate_admm(
        LinearProblem.from_stacked(A, y),
        g,
        constraint_nodes=np.flatnonzero(inC),
        W=2.0,
        messages="aggregated",
        exchange=ex,
    )
    trace = [next(states) for _ in range(iterations + 1)]
    last = trace[-1]
    for r in ranks:
        assert np.array_equal(r["x"], last.x[r["nodes"]]), "the part run's x differs from the in-process run's"
        assert np.array_equal(r["sent"], ex.messages_sent[r["nodes"]])
        np.testing.assert_allclose(r["primal"], [s.primal_residual for s in trace], rtol=1e-11)
        np.testing.assert_allclose(r["dual"], [s.dual_residual for s in trace], rtol=1e-11)
    assert last.primal_residual < 0.1 * trace[1].primal_residual  # it is converging, not standing still


@pytest.mark.mpi
def test_a_rank_with_few_nodes_allocates_nothing_of_the_whole_network(tmp_path):
    """Rank 0 owns 400 nodes of a tiled graph of 10⁵ and then 3·10⁵ nodes: its traced peak (part, exchange,
    constraint nodes, x-update, 5 iterations) does not grow with the network — a whole-network array of even one
    boolean would add 2·10⁵ bytes — and stays below one float per node of the larger one. The other rank's peak per
    owned node is the same at both sizes (memory ∝ n/ranks)."""
    small = _launch(tmp_path, 100_000, 400, 5, seed=5)  # seeds whose graphs have no isolated node
    big = _launch(tmp_path, 300_000, 400, 5, seed=7)
    assert int(small[0]["owned"]) == int(big[0]["owned"]) == 400
    peak_small, peak_big = int(small[0]["peak"]), int(big[0]["peak"])
    assert peak_big - peak_small < 50_000, (peak_small, peak_big)
    assert peak_big < 8 * 300_000, peak_big
    per_node = [int(r[1]["peak"]) / int(r[1]["owned"]) for r in (small, big)]
    assert per_node[1] == pytest.approx(per_node[0], rel=0.05), per_node
