"""Launched by bench_mpi.py under mpiexec: ADMM (paper 000 Fig. 6) on a large network partitioned over ranks.

    mpiexec -n R python -m mpi4py benchmarks/mpi_admm.py N_NODES ITERATIONS
Prints one JSON line on rank 0 (ms per iteration, aggregated messages, p = 10, 5 rows per node, 8-neighbour grid).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from mpi4py import MPI

from distnav.algorithms.lsq.admm import admm
from distnav.algorithms.lsq.blue import LinearProblem
from distnav.exchange.mpi import MPIExchange
from distnav.network import builders

n, iterations = int(sys.argv[1]), int(sys.argv[2])
comm = MPI.COMM_WORLD
rng = np.random.default_rng(0)
side = int(round(np.sqrt(n)))
g = builders.grid(side, side, neighbourhood=8)  # connected, mean degree ≈ 8
n = g.n_nodes
A = rng.standard_normal((n, 5, 10))
y = A @ rng.standard_normal(10) + 0.1 * rng.standard_normal((n, 5))
problem = LinearProblem.from_stacked(A, y)
ex = MPIExchange(g)
comm.Barrier()
t0 = time.perf_counter()
res = admm(
    problem,
    g,
    constraint_nodes="min_cover",
    W=5.0,
    messages="aggregated",
    max_iterations=iterations,
    tol=0.0,
    record_nodes=False,
    exchange=ex,
)
comm.Barrier()
elapsed = time.perf_counter() - t0
if comm.Get_rank() == 0:
    print(
        json.dumps(
            {
                "name": "ADMM (aggregated) under MPI",
                "ranks": comm.Get_size(),
                "n_nodes": n,
                "iterations": iterations,
                "ms_per_iteration": elapsed / iterations * 1e3,
                "messages": res.comm.messages,
            }
        )
    )
