"""Per-rank traced memory of a consensus set-up on graph parts (issue 30 item 1); rank 0 prints one JSON line.

mpiexec -n R python -m mpi4py tests/mpi/part_memory.py {ring,tiled} N_NODES SMALL_RANK_NODES

Rank 0 owns only ``SMALL_RANK_NODES`` nodes, the other ranks equal ranges of the rest
(:class:`~distnav.network.partition.NodeRanges`). Each rank builds its part (:mod:`distnav.network.part_builders`),
its weights, the MPI exchange and the mixer and runs three consensus rounds on its own values, under ``tracemalloc``
started after every import: the traced peak of a rank that owns few nodes shows whether anything the size of the
whole network was allocated on the way (``tests/test_network_part_builders.py`` checks it).
"""

from __future__ import annotations

import json
import sys
import tracemalloc

import scipy.sparse  # noqa: F401  (imported before tracing: imports are not the set-up's memory)
import scipy.sparse.csgraph  # noqa: F401
import scipy.spatial  # noqa: F401
from mpi4py import MPI

import distnav.exchange.mpi  # noqa: F401
from distnav.exchange import make_exchange
from distnav.network.part_builders import radius_for_mean_degree, ring_part, tiled_random_geometric_part
from distnav.network.partition import NodeRanges
from distnav.network.weights import part_weights

kind, n, small = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
comm = MPI.COMM_WORLD
rank, size = comm.Get_rank(), comm.Get_size()
rest = n - small
bounds = [0, small] + [small + (rest * (r + 1)) // (size - 1) for r in range(size - 1)]
ranges = NodeRanges(bounds)
comm.Barrier()
tracemalloc.start()
nodes = ranges.nodes_of(rank)
if kind == "ring":
    part = ring_part(n, nodes)
else:
    part = tiled_random_geometric_part(n, radius_for_mean_degree(n, 8), seed=3, nodes=nodes, tile_nodes=64, comm=comm)
ex = make_exchange(part, backend="mpi", partition=ranges)
mixer = ex.mixer(part_weights(part, "MH"))
x = ex.nodes.astype(float)  # this rank's own values (global ids as values): no whole-size input
for _ in range(3):
    x = mixer.apply(x)
total = ex.allreduce(float(x.sum()))
_, peak = tracemalloc.get_traced_memory()
tracemalloc.stop()
rows = comm.gather({"rank": rank, "owned": part.n_local, "in_edges": part.n_local_edges, "peak_bytes": peak})
if rank == 0:
    print(json.dumps({"n_nodes": n, "n_edges": part.n_edges, "sum": total, "ranks": rows}))
