"""ADMM (aggregated messages) on graph parts under MPI (issue 30 item 2); every rank writes its own rows.

mpiexec -n R python -m mpi4py tests/mpi/admm_parts.py N_NODES SMALL ITERATIONS OUT_PREFIX [SEED]

Rank 0 owns ``SMALL`` nodes (0: equal ranges for every rank), the others equal ranges of the rest
(:class:`~distnav.network.partition.NodeRanges`). Each rank builds its part of a tiled random geometric graph, its
nodes' rows of the problem (:func:`problem_rows`: a generator per block of ids, so any range is drawn alone) and runs
:func:`~distnav.algorithms.lsq.on_part.iterate_admm_on_part` under ``tracemalloc`` (started after every import), then
writes ``OUT_PREFIX.<rank>.npz``: its node ids and final ``x`` (local order), the residual trace, its messages sent
per node and the traced peak. ``tests/test_admm_parts.py`` compares them with the in-process run on the whole graph.
"""

from __future__ import annotations

import sys
import tracemalloc

import numpy as np

P, M, SEED, BLOCK = 3, 2, 11, 4096
TILE_NODES = 64
MEAN_DEGREE, GRAPH_SEED = 14, 4  # a connected graph at the tests' sizes (checked there)


def problem_rows(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """``A`` ``(hi − lo, M, P)`` and ``y`` of nodes ``lo:hi``: block ``b`` of :data:`BLOCK` ids from its own
    generator ``default_rng([SEED, b])``, so a rank draws only the blocks its range meets."""
    A = np.empty((hi - lo, M, P))
    y = np.empty((hi - lo, M))
    for b in range(lo // BLOCK, (hi - 1) // BLOCK + 1 if hi > lo else lo // BLOCK):
        rng = np.random.default_rng([SEED, b])
        Ab = rng.normal(size=(BLOCK, M, P))
        yb = np.einsum("nmp,p->nm", Ab, np.arange(1.0, P + 1)) + 0.1 * rng.normal(size=(BLOCK, M))
        a, c = max(lo, b * BLOCK), min(hi, (b + 1) * BLOCK)
        A[a - lo : c - lo], y[a - lo : c - lo] = Ab[a - b * BLOCK : c - b * BLOCK], yb[a - b * BLOCK : c - b * BLOCK]
    return A, y


def bounds_for(n: int, ranks: int, small: int) -> list[int]:
    if small == 0:
        return [(n * r) // ranks for r in range(ranks + 1)]
    rest = n - small
    return [0, small] + [small + (rest * (r + 1)) // (ranks - 1) for r in range(ranks - 1)]


def main() -> None:
    import scipy.sparse  # noqa: F401  (imported before tracing: imports are not the set-up's memory)
    import scipy.sparse.csgraph  # noqa: F401
    import scipy.spatial  # noqa: F401
    from mpi4py import MPI

    import distnav.exchange.mpi  # noqa: F401
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.lsq.on_part import iterate_admm_on_part
    from distnav.exchange import make_exchange
    from distnav.network.part_builders import radius_for_mean_degree, tiled_random_geometric_part
    from distnav.network.partition import NodeRanges

    n, small, iterations, out = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    seed = int(sys.argv[5]) if len(sys.argv) > 5 else GRAPH_SEED
    comm = MPI.COMM_WORLD
    rank, size = comm.Get_rank(), comm.Get_size()
    ranges = NodeRanges(bounds_for(n, size, small))
    comm.Barrier()
    tracemalloc.start()
    nodes = ranges.nodes_of(rank)
    radius = radius_for_mean_degree(n, MEAN_DEGREE)
    part = tiled_random_geometric_part(n, radius, seed=seed, nodes=nodes, tile_nodes=TILE_NODES, comm=comm)
    ex = make_exchange(part, backend="mpi", partition=ranges)
    A, y = problem_rows(int(nodes[0]), int(nodes[-1]) + 1)
    states = iterate_admm_on_part(LinearProblem.from_stacked(A, y), ex, W=2.0, messages="aggregated")
    primal, dual = [], []
    for _ in range(iterations + 1):
        st = next(states)
        primal.append(st.primal_residual)
        dual.append(st.dual_residual)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.savez(
        f"{out}.{rank}.npz",
        nodes=ex.nodes,
        x=st.x,
        primal=np.asarray(primal),
        dual=np.asarray(dual),
        sent=np.asarray(ex.messages_sent),
        peak=np.asarray(peak),
        owned=np.asarray(part.n_local),
    )


if __name__ == "__main__":
    main()
